"""The 2F-85's transmission: a screw and nut that self-locks once the fingers stall.

The real gripper closes force-limited (the motor current limit sets the grip force);
when the fingers stop on an object the motor stops and "the grip force will be
maintained by the Gripper's auto-locking mechanism" (Robotiq). A load that pulls the
fingers open then meets the locked transmission and the linkage's compliance, not the
motor's current limit. The motor models of `actuators` alone back-drive at the grip
force; `TransmissionLock` adds the lock beside them:

    tau_lock = k_p (q_lock - q) - k_d v    on both driver joints, once engaged,

with q_lock a ratchet (it follows the fingers closed, never open), so at rest the torque
is the motor's grip torque and opening costs k_p per radian. Both drivers' total effort
(motor + lock) is clipped at `LOCK_EFFORT_LIMIT_FACTOR` x the grip torque.

It is Drake's implicit PD actuator under SAP (`JointActuator.set_controller_gains` and
the plant's desired-state input): an explicit stiff torque is unstable with the light
linkage at a 1 ms step. The gains are the plant's (not the context's), so `engage` and
`release` switch them for every context of that plant: one lock per plant, owned by
the simulation that built it (a GraspSimulator, a SimWorld).

Drives (`SimSettings.drive`): "self_locking" (the real 2F-85) and "backdrivable" (the
motor alone, the labels and cells before the lock; kept so old and new results can be
compared, never pooled).
"""

from __future__ import annotations

import weakref

from pydrake.multibody.tree import PdControllerGains
from pydrake.systems.framework import LeafSystem

DRIVES = ("self_locking", "backdrivable")

# Lock stiffness at the driver joint [N m/rad] and its damping [N m s/rad]; calibrated in
# doc/grasp-simulation.md (transmission): friction-limited scores within +15 % of the
# back-drivable hand's, enclosing grasps >= 2x their pinches.
LOCK_STIFFNESS_NM_PER_RAD = 64.0
LOCK_DAMPING_NM_S_PER_RAD = 0.5
# Total driver effort limit, as a multiple of the grip torque: a numerical cap far above
# the grip (the screw does not slip), so the lock never saturates in a 200 N ramp.
LOCK_EFFORT_LIMIT_FACTOR = 20.0


class TransmissionLock(LeafSystem):
    """The self-locking transmission on the 2F-85's two driver joints.

    Discrete state: [engaged (0/1), q_lock rad]. While engaged, a periodic update
    ratchets q_lock up to the driver angle (closing is free, opening is resisted).
    Input: plant state. Output: the hand's desired state [q_d, q_d, 0, 0] for the
    plant's desired-state input (ignored while the gains are off)."""

    def __init__(self, plant, hand, time_step_s, stiffness_nm_per_rad=LOCK_STIFFNESS_NM_PER_RAD,
                 damping_nm_s_per_rad=LOCK_DAMPING_NM_S_PER_RAD):
        super().__init__()
        self._plant, self._hand = plant, hand
        self._iq = hand.driver_joints[0].position_start()
        self.stiffness_nm_per_rad = float(stiffness_nm_per_rad)
        self.damping_nm_s_per_rad = float(damping_nm_s_per_rad)
        self._state = self.DeclareVectorInputPort("state", plant.num_multibody_states())
        self._lock = self.DeclareDiscreteState([0.0, 0.0])
        me = weakref.ref(self)  # see actuators.FingerServoSystem: no strong cycle through C++
        self.DeclarePeriodicDiscreteUpdateEvent(time_step_s, 0.0, lambda c, s: me()._ratchet(c, s))
        self.DeclareVectorOutputPort("desired_state", 4, lambda c, out: me()._desired(c, out))

    def _ratchet(self, context, discrete_state):
        engaged, q_lock = context.get_discrete_state(self._lock).CopyToVector()
        if engaged:
            q = self._state.Eval(context)[self._iq]
            discrete_state.get_mutable_vector(self._lock).SetAtIndex(1, max(q_lock, float(q)))

    def _desired(self, context, output):
        engaged, q_lock = context.get_discrete_state(self._lock).CopyToVector()
        q = q_lock if engaged else self._state.Eval(context)[self._iq]
        output.SetFromVector([q, q, 0.0, 0.0])

    def _set_gains(self, on: bool):
        gains = (PdControllerGains(p=self.stiffness_nm_per_rad, d=self.damping_nm_s_per_rad) if on
                 else PdControllerGains(p=0.0, d=0.0))
        for actuator in self._hand.actuators:
            actuator.set_controller_gains(gains)

    def engage(self, root_context) -> None:
        """Lock at the fingers' present angle (call once they have stalled)."""
        q = self._plant.GetPositions(self._plant.GetMyContextFromRoot(root_context))[self._iq]
        self.GetMyMutableContextFromRoot(root_context).get_mutable_discrete_state(self._lock).SetFromVector(
            [1.0, float(q)])
        self._set_gains(True)

    def release(self, root_context) -> None:
        """Unlock (an open command, or a new closing)."""
        self.GetMyMutableContextFromRoot(root_context).get_mutable_discrete_state(self._lock).SetFromVector(
            [0.0, 0.0])
        self._set_gains(False)

    def sync_gains(self, root_context) -> None:
        """Set the plant's gains to what `root_context` says (after restoring a saved
        context: the gains are the plant's, not the context's)."""
        self._set_gains(self.engaged(root_context))

    def engaged(self, root_context) -> bool:
        return bool(self.GetMyContextFromRoot(root_context).get_discrete_state(self._lock).GetAtIndex(0))


def add_transmission_lock(builder, plant, hand, time_step_s, grip_torque_nm, **gains) -> TransmissionLock:
    """Add the lock to `builder` for a finalized `plant` and wire it (state in, desired
    state out), with the drivers' total effort capped at LOCK_EFFORT_LIMIT_FACTOR x
    `grip_torque_nm`. Released until `engage`."""
    for actuator in hand.actuators:
        actuator.set_effort_limit(LOCK_EFFORT_LIMIT_FACTOR * float(grip_torque_nm))
    lock = builder.AddSystem(TransmissionLock(plant, hand, time_step_s, **gains))
    builder.Connect(plant.get_state_output_port(), lock.get_input_port())
    builder.Connect(lock.get_output_port(), plant.get_desired_state_input_port(hand.model_instance))
    return lock
