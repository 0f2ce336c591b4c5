"""A hand's fingers in a SimWorld: commands to its motor and what the gripper reports.

The motor is `physics.actuators.FingerServoSystem` (a LeafSystem): a position servo on
the driver joint (the 2F-85's driver, the Panda's finger joints) whose reference moves
at the commanded speed and whose effort is clipped at the value that squeezes the
commanded force. Blocked by an object, the reference runs on to the target and the
effort saturates: a force-limited grip, as the real grippers do. How joint and opening
relate is the hand's `finger_drives.FingerDrive`: the 2F-85 reports its width from the
driver angle through the free-closing calibration (`DRIVER_ANGLE_RAD` -> `PAD_GAP_M`),
as the real gripper reports its motor position, not the pad gap; the Panda its finger
positions. Whether the fingers move, reached the target or stopped on something comes
from a stall detection.

The 2F-85's drive self-locks (physics.transmission, SimSettings.drive "self_locking"):
once the fingers stop on something ("blocked", the gripper's gOBJ 1/2) the transmission
locks, so a load that pulls them open meets the lock, not the motor's current limit; any
new command (an open) releases it.

No thread locking here: SimWorld calls it under its lock."""

from __future__ import annotations

from dataclasses import dataclass



@dataclass
class FingerCommand:
    target_width_m: float
    speed_mps: float
    force_n: float
    t_start_s: float  # sim time the command arrived
    held: bool = False  # stopped where the fingers were (hold_fingers)


class Fingers:
    """The finger servo of one world diagram (`diagram.WorldDiagram`, driven as its
    `drive` says) run by `simulator`; a new world gets new Fingers. Until the first
    command the servo holds them open at `grip_force_n`'s effort."""

    STALL_HOLD_S = 0.04  # stalled this long = stopped
    START_GRACE_S = 0.06  # after a new command, before a stop can be declared

    def __init__(self, model, simulator, grip_force_n: float):
        self._model, self._simulator = model, simulator
        self._drive = model.drive
        self._lock = getattr(model, "transmission_lock", None)
        self._command = None
        self._stall_since_s = self._blocked_angle = None
        model.finger_servo.set_command(self._servo_context(), self._drive.open_joint, 1.0,
                                       self._drive.effort_for_force(grip_force_n))

    def _time_s(self) -> float:
        return self._simulator.get_context().get_time()

    def _plant_context(self):
        return self._model.plant.GetMyMutableContextFromRoot(self._simulator.get_mutable_context())

    def _servo_context(self):
        return self._model.finger_servo.GetMyMutableContextFromRoot(self._simulator.get_mutable_context())

    def command(self, target_width_m: float, speed_mps: float, force_n: float) -> None:
        """Move towards an opening [m] at a speed [m/s of opening], squeezing at most
        `force_n` [N] (a new target restarts the stall detection)."""
        cmd = self._command
        if cmd is None or (cmd.target_width_m, cmd.speed_mps, cmd.force_n) != (target_width_m, speed_mps, force_n):
            self._command = FingerCommand(target_width_m, speed_mps, force_n, self._time_s())
            self._stall_since_s = self._blocked_angle = None
            if self._lock is not None:  # the motor drives again: the screw turns
                self._lock.release(self._simulator.get_mutable_context())
            ctx = self._servo_context()
            if cmd is None:  # first command: start the reference where the fingers are
                self._model.finger_servo.set_reference(ctx, self.driver_angle_rad())
            d = self._drive
            self._model.finger_servo.set_command(
                ctx, d.joint_for_width(target_width_m), max(speed_mps, 1e-3) / d.width_per_joint_m,
                d.effort_for_force(force_n))

    def commanded(self) -> bool:
        """True while a command runs (not stopped by `hold`)."""
        return self._command is not None and not self._command.held

    def hold(self) -> None:
        """Stop where they are (the 2F-85's rGTO = 0; its drive self-locks). Locked on an
        object, the transmission keeps the grip as it is."""
        if self._command is None:
            return
        if self.locked():
            self._command = FingerCommand(self._command.target_width_m, self._command.speed_mps,
                                          self._command.force_n, self._command.t_start_s, held=True)
            return
        angle = self.driver_angle_rad()
        ctx = self._servo_context()
        _, rate, torque = self._model.finger_servo.command(ctx)
        self._model.finger_servo.set_reference(ctx, angle)
        self._model.finger_servo.set_command(ctx, angle, rate, torque)
        self._command = FingerCommand(self._drive.width_at(angle), self._command.speed_mps,
                                      self._command.force_n, self._time_s(), held=True)

    def driver_angle_rad(self) -> float:
        """The servo's joint: the 2F-85's driver angle [rad], a Panda finger's position [m]."""
        iq = self._model.hand.driver_joints[0].position_start()
        return float(self._model.plant.GetPositions(self._plant_context())[iq])

    def width_m(self) -> float:
        return self._drive.width_at(self.driver_angle_rad())

    def _driver_rate(self):
        iv = self._model.hand.driver_joints[0].velocity_start()
        return float(self._model.plant.GetVelocities(self._plant_context())[iv])

    def update_stall(self) -> None:
        """After every time step: when the driver stalled; stopped on something, a
        self-locking transmission locks."""
        if self._command is None:
            return
        if abs(self._driver_rate()) < self._drive.stall_rate:
            if self._stall_since_s is None:
                self._stall_since_s = self._time_s()
        else:
            self._stall_since_s = None
        if (self._lock is not None and self._stall_since_s is not None and not self._command.held
                and not self.locked() and self.status()[1] == "blocked"):
            self._lock.engage(self._simulator.get_mutable_context())

    def locked(self) -> bool:
        """The self-locking transmission holds the fingers (False for a back-drivable drive)."""
        return self._lock is not None and self._lock.engaged(self._simulator.get_context())

    def status(self) -> tuple:
        """(width_m, state) with state 'moving', 'at_target' or 'blocked' (stopped short
        of the target: on an object, or with the fingers touching each other)."""
        cmd = self._command
        width = self.width_m()
        if cmd is None:
            return width, "at_target"
        target_angle = self._drive.joint_for_width(cmd.target_width_m)
        if self._blocked_angle is not None:
            # Once stopped on an object, stay so while the fingers keep still: a lift
            # that flexes the fingers for a moment is no dropped object. Only moving
            # on towards the target (the object slipped out) ends it, as on the 2F-85.
            if abs(self.driver_angle_rad() - self._blocked_angle) < self._drive.block_release:
                return width, "blocked"
            self._blocked_angle = None
            self._stall_since_s = None
        t = self._time_s()
        # Stopped = stalled while the motor pushes with its full torque towards the
        # target, or with its reference already at the target: the servo's torque is
        # then KP x what is left (the pads meeting 0.02 rad short of closed give 2.1 Nm,
        # under 90 % of the limit from ~46 N of grip force), and nothing will change.
        # Right after a reversal (open after a squeeze) the fingers stall too, until the
        # servo reference has come back past them: that is no stop.
        stopped = (self._stall_since_s is not None and t - self._stall_since_s >= self.STALL_HOLD_S
                   and t - cmd.t_start_s >= self.START_GRACE_S
                   and (self._pushing(target_angle) or self._reference_done()))
        close_enough = self._drive.reached(self.driver_angle_rad(), cmd.target_width_m)
        if close_enough and (stopped or t - cmd.t_start_s >= self.START_GRACE_S):
            return cmd.target_width_m, "at_target"
        if stopped:
            # Stopped short of the target: on an object, or on the other finger (the
            # pads or fingertips meet when closing on nothing; where depends on how
            # the underactuated fingers folded: 1.1 mm from open, 3.7 mm after a
            # fingertip pinch lost its object). Either way the 2F-85 reports an
            # object (gOBJ 2) at its motor position; telling them apart is the
            # executor's job (robotiq_driver.grip_calibration).
            self._blocked_angle = self.driver_angle_rad()
            return width, "blocked"
        return width, "moving"

    def _pushing(self, target_angle) -> bool:
        """The finger servo's torque is (nearly) at its limit, towards the target."""
        ctx = self._servo_context()
        _, _, limit = self._model.finger_servo.command(ctx)
        q = self.driver_angle_rad()
        tau = self._drive.kp * (self._model.finger_servo.reference(ctx) - q)
        return tau * (target_angle - q) > 0 and abs(tau) >= 0.9 * limit

    def _reference_done(self) -> bool:
        """The servo reference has run all the way to its target."""
        ctx = self._servo_context()
        target, _, _ = self._model.finger_servo.command(ctx)
        return abs(self._model.finger_servo.reference(ctx) - target) <= 1e-9

    def busy(self) -> bool:
        """True while the fingers move or the servo is still building up its grip."""
        if self._command is None:
            return False
        ctx = self._servo_context()
        target, _, _ = self._model.finger_servo.command(ctx)
        ref = self._model.finger_servo.reference(ctx)
        return abs(ref - target) > 1e-9 or self.status()[1] == "moving"
