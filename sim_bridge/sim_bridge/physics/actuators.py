"""The 2F-85's single actuator as Drake LeafSystems, two ways of driving it.

`GripForceController` (the grasp simulation, datagen): close at a set speed with a torque
limit. `FingerServoSystem` (the simulated cell): a position servo whose reference moves at
the commanded speed, torque clipped at the value that squeezes the commanded force.
Both take their torque limit from `driver_torque_nm` (the squeeze calibration).
"""

from __future__ import annotations

import weakref

import numpy as np
from pydrake.systems.framework import BasicVector, LeafSystem

from . import hand_model


class GripForceController(LeafSystem):
    """The 2F-85's single actuator: close at a set speed with a torque limit.

    tau = clip(kd (v_close - v), 0, tau_max) on both driver joints (the coupler
    constraint splits it). Free fingers close at ~v_close; once the object stops them,
    the torque saturates at tau_max, which sets the grip force (calibrated so the pads
    squeeze `grip_force_n`). Input: plant state; output: actuation (left, right).
    """

    def __init__(self, plant, hand, tau_max_nm, closing_speed_rad_s):
        super().__init__()
        nq = plant.num_positions()
        self._iv = nq + hand.driver_joints[0].velocity_start()
        self._tau = float(tau_max_nm)
        self._v = float(closing_speed_rad_s)
        self._kd = 4.0 * self._tau / self._v
        self.DeclareVectorInputPort("state", plant.num_multibody_states())
        self.DeclareVectorOutputPort("actuation", 2, self._calc)

    def _calc(self, context, output):
        v = self.get_input_port().Eval(context)[self._iv]
        tau = float(np.clip(self._kd * (self._v - v), 0.0, self._tau))
        output.SetFromVector([tau, tau])


def driver_torque_nm(grip_force_n: float) -> float:
    """Driver torque that squeezes `grip_force_n` between parallel pads 50 mm apart
    (`measure_squeeze_force_n`; -8%..+17% over 10-80 mm, README)."""
    return grip_force_n * hand_model.DRIVER_TORQUE_PER_NEWTON_NM


class FingerServoSystem(LeafSystem):
    """The 2F-85's motor on both driver joints (the coupler constraint ties them); the
    Panda's on its two finger joints likewise (world.finger_drives has its gain).

    Discrete state: the reference angle, which moves towards the target angle at the
    commanded rate every time step. Numeric parameters: [target angle rad, rate
    rad/s, torque limit N m]. Output: tau = clip(kp (ref - q), ±limit): the full
    torque (the grip force) is reached 2 mm short of the reference at 40 N. The damping
    is the driver joints' own (world.finger_drives' `joint_damping`, set in
    build_world_diagram): SAP treats joint damping implicitly, whereas a damping term
    here is explicit and made the light linkage chatter at ±14 rad/s every step.
    """

    KP_NM_PER_RAD = 100.0  # 200 overshoots, 400 chatters (dt 2 ms)

    def __init__(self, plant, hand, time_step_s, kp=KP_NM_PER_RAD, initial_reference=0.0):
        """`kp`, `initial_reference`: the 2F-85's by default; the Panda's fingers are
        prismatic (N/m, m; world.finger_drives)."""
        super().__init__()
        self._iq = hand.driver_joints[0].position_start()
        self._dt = time_step_s
        self._kp = float(kp)
        self._state = self.DeclareVectorInputPort("state", plant.num_multibody_states())
        self._ref = self.DeclareDiscreteState([float(initial_reference)])
        self._params = self.DeclareNumericParameter(BasicVector([0.0, 1.0, 1.0]))
        # Callbacks through a weak reference: a bound method held by the C++ side would
        # keep this object (and the C++ system it owns once its diagram is gone) alive.
        me = weakref.ref(self)
        self.DeclarePeriodicDiscreteUpdateEvent(time_step_s, 0.0, lambda c, s: me()._update(c, s))
        self.DeclareVectorOutputPort("actuation", 2, lambda c, out: me()._calc(c, out))

    def set_command(self, context, target_rad, rate_rad_s, torque_limit_nm):
        context.get_mutable_numeric_parameter(self._params).SetFromVector(
            [target_rad, rate_rad_s, torque_limit_nm])

    def set_reference(self, context, angle_rad):
        context.get_mutable_discrete_state(self._ref).SetFromVector([angle_rad])

    def reference(self, context) -> float:
        return context.get_discrete_state(self._ref).GetAtIndex(0)

    def command(self, context):
        return context.get_numeric_parameter(self._params).CopyToVector()

    def _update(self, context, discrete_state):
        target, rate, _ = context.get_numeric_parameter(self._params).CopyToVector()
        ref = context.get_discrete_state(self._ref).GetAtIndex(0)
        step = rate * self._dt
        discrete_state.get_mutable_vector(self._ref).SetAtIndex(
            0, ref + float(np.clip(target - ref, -step, step)))

    def _calc(self, context, output):
        x = self._state.Eval(context)
        ref = context.get_discrete_state(self._ref).GetAtIndex(0)
        limit = context.get_numeric_parameter(self._params).GetAtIndex(2)
        tau = self._kp * (ref - x[self._iq])
        tau = float(np.clip(tau, -limit, limit))
        output.SetFromVector([tau, tau])
