"""The simulated cell the benchmark runs a round in: the grasp executor's arm and gripper
adapters over a SimWorld in simulated time (`SimArm`, `SimGripper`, `PandaSimGripper`),
and `SimCell`, which clearing.clear_table drives, with the hand its method's grasps are
for (physics.hands; the executor gets that hand's opening and boxes, `HAND_GEOMETRY`)."""

from __future__ import annotations

import numpy as np

from gravgrasp_detector.execution.executor import (Abort, ArmMotion, ExecutionLimits, GraspExecutor, check_limits,
                                                   plan_poses, scene_collision)
from gravgrasp_detector.perception.hand_clearance import ROBOTIQ_2F85, HandGeometry
from robotiq_driver.gripper_client import GripperTimeout
from robotiq_driver.gripper_registers import ActivationStatus, GripperScale, GripperState, ObjectStatus

from ..datagen.object_sources import ObjectSource
from ..physics import panda_hand
from ..physics.contact import SimSettings
from ..physics.hands import HANDS, hand_spec
from ..world import SceneConfig, SimWorld, WorldSettings
from .clearing import Refused, grasp_fields
from .protocol import LIFTED_MIN_HEIGHT_M, Protocol

# What the executor knows of each hand (physics.hands' names): its opening and the open
# hand's boxes for the clearance check. The 2F-85's are robotiq_driver's, as the execute
# node's; the Panda's are physics.panda_hand's (checked against its collision meshes).
HAND_GEOMETRY = {
    "2f85": ROBOTIQ_2F85,
    "panda": HandGeometry("panda", panda_hand.MAX_OPENING_M, panda_hand.HAND_PARTS, panda_hand.OPEN_HAND_BOXES_TCP),
}
assert set(HAND_GEOMETRY) == set(HANDS), "every hand of physics.hands needs its executor geometry here"

# the simulated cell: executor adapters in simulated time


class SimArm:
    """gravgrasp_detector.execution.executor.Arm on a SimWorld: straight-line TCP motions stepped here."""
    def __init__(self, world):
        self.world = world

    def move_to(self, X_task_tcp, speed_mps, timeout_s) -> ArmMotion:
        m = self.world.travel(X_task_tcp, speed_mps, timeout_s)
        return ArmMotion(*m.result, m.stopped_by_contact, m.left_m)


class SimGripper:
    """The executor's gripper client (Robotiq2F85's read_state / activate /
    move_and_wait / wait / width_m / stop) on a SimWorld's finger servo, in simulated time,
    without the Modbus emulator: deterministic, and no wall-clock polling."""
    STEP_S = 0.01

    def __init__(self, world):
        self.world, self.scale, self._closing = world, GripperScale(), True

    def read_state(self):
        width, state = self.world.finger_status()
        if state == "blocked":
            obj = ObjectStatus.CONTACT_CLOSING if self._closing else ObjectStatus.CONTACT_OPENING
        else:
            obj = ObjectStatus.AT_POSITION if state == "at_target" else ObjectStatus.MOVING
        return GripperState(activated=True, go=True, activation_status=ActivationStatus.ACTIVATED,
                            object_status=obj, position=self.scale.width_to_counts(min(width, self.scale.stroke_m)))

    def activate(self, timeout_s=5.0, force=False):
        return self.read_state()

    def width_m(self, state):
        return self.scale.counts_to_width(state.position)

    def move_and_wait(self, width_m, speed_mps, force_n, timeout_s):
        self._closing = width_m < self.world.finger_width_m()
        self.world.command_fingers(width_m, speed_mps, force_n)
        return self.wait(timeout_s)

    def wait(self, timeout_s, requested=None):
        t_end = self.world.time_s + timeout_s
        while self.world.time_s < t_end:
            self.world.advance(self.STEP_S)
            if self.world.finger_status()[1] != "moving":
                return self.read_state()
        raise GripperTimeout(f"fingers still moving after {timeout_s} s of simulated time")

    def stop(self):
        self.world.hold_fingers()


class PandaSimGripper(SimGripper):
    """The Panda hand's gripper for the executor. The Panda reports only where its fingers
    are, so "stopped on an object" (gOBJ 2) is the world's parallel-grip verdict: fingers
    stopped clearly short of closed with an object touching both (world.parallel_grip).
    Fingers stopped on something else (the table, one finger on a neighbour) read "at
    position", and the executor's judge says the fingers did not stop on an object.
    Closing on nothing ends at 0 mm, where the executor's calibration then sits."""

    def __init__(self, world):
        super().__init__(world)
        self.scale = GripperScale(stroke_m=panda_hand.MAX_OPENING_M)

    def read_state(self):
        width, state = self.world.finger_status()
        if state == "moving":
            obj = ObjectStatus.MOVING
        elif self._closing:
            obj = ObjectStatus.CONTACT_CLOSING if self.world.parallel_grip().held else ObjectStatus.AT_POSITION
        else:
            obj = ObjectStatus.CONTACT_OPENING if state == "blocked" else ObjectStatus.AT_POSITION
        return GripperState(activated=True, go=True, activation_status=ActivationStatus.ACTIVATED,
                            object_status=obj, position=self.scale.width_to_counts(min(width, self.scale.stroke_m)))


GRIPPERS = {"2f85": SimGripper, "panda": PandaSimGripper}  # the executor's gripper per hand


class SimCell:
    """One scene in Drake with the executor; what `clear_table` drives. `detect(tsdf)` ->
    ranked grasps (best first) for `hand` (physics.hands: "2f85" or "panda", whose files
    come from `baselines_dir`, "" = physics.baseline_files' default)."""
    def __init__(self, scene: dict, mass_kg: float, protocol: Protocol, volume, detect, hand: str = "2f85",
                 baselines_dir: str = ""):
        self.hand = hand_spec(hand).name  # one clear error for a hand that does not exist

        objects = tuple((ObjectSource(**o["source"]).load(), np.asarray(o["X_task_object"]))
                        for o in scene["objects"])
        settings = WorldSettings(contact=SimSettings(time_step_s=protocol.time_step_s,
                                                     grip_force_n=protocol.grip_force_n,
                                                     relaxation_time_s=protocol.relaxation_time_s,
                                                     drive=protocol.drive),
                                 max_speed_mps=protocol.free_space_speed_mps,
                                 freeze_resting_objects=protocol.freeze_resting_objects,
                                 hand=hand, baselines_dir=baselines_dir or "")
        self.world = SimWorld(SceneConfig(objects=objects, object_mass_kg=mass_kg,
                                          arrangement=scene["arrangement"]), settings)
        self.protocol, self.volume, self._detect = protocol, volume, detect
        # The executor's limits are the ROS node's defaults but the free-space speed; grip
        # force per the paper. No fingertip-table check (table_z_m), as the node's default:
        # its parallel-closing estimate refused half of the power labels simulation passed.
        self.limits = ExecutionLimits(grip_force_n=protocol.grip_force_n, arm_timeout_s=30.0,
                                      max_speed_mps=protocol.free_space_speed_mps,
                                      lift_speed_mps=protocol.lift_speed_mps,
                                      approach_fast_speed_mps=protocol.approach_fast_speed_mps,
                                      close_on_contact_within_m=protocol.close_on_contact_within_m,
                                      hand=HAND_GEOMETRY[hand])
        gripper = GRIPPERS[hand]
        self.executor = GraspExecutor(SimArm(self.world), lambda: gripper(self.world), self.limits,
                                      reachability=None, log=lambda *_: None)
        self.home = self.world.tcp_pose()
        self._fallen = set()

    def settle(self, max_s: float = 2.0, speed_mps: float = 5e-3) -> float:
        """Let the scene come to rest at the round's weight before the first view: the
        layout was settled with the objects' own masses, and a heavier pile shifts (a
        1.5 kg cylinder slid off a sphere, which rolled off the table). Returns the
        simulated settling time."""
        t0 = self.world.time_s
        before = {s.name: s.X_task_object[:3, 3] for s in self.world.object_states()}
        while self.world.time_s < t0 + max_s:
            self.world.advance(0.1)
            now = {s.name: s.X_task_object[:3, 3] for s in self.world.object_states() if not s.out_of_workspace}
            speed = max((np.linalg.norm(p - before.get(n, p)) / 0.1 for n, p in now.items()), default=0.0)
            before = now
            if speed < speed_mps:
                break
        return self.world.time_s - t0

    def objects_on_table(self) -> list:
        return [s.name for s in self.world.object_states() if not s.out_of_workspace]

    def remove_fallen(self) -> list:
        """Objects that left the cube since the last call. The world takes those gone past
        the table out of the physics itself (world.out_of_play: left falling, they spun up
        until Drake's poses went non-finite); those still on the table outside the cube
        stay. objects_on_table leaves them all out."""
        fallen = [s.name for s in self.world.object_states() if s.out_of_workspace and s.name not in self._fallen]
        self._fallen.update(fallen)
        return fallen

    def checkpoint(self):
        """The cell's state (world, executor, fallen objects, settings) to `rewind` to:
        one attempt can then run again from the same scene."""
        ex = self.executor
        return (self.world.checkpoint(), set(self._fallen), self.protocol, self.limits,
                {k: getattr(ex, k) for k in ("calibration", "gripper", "armed", "limits")})

    def rewind(self, checkpoint) -> None:
        world, fallen, self.protocol, self.limits, executor = checkpoint
        self.world.rewind(world)
        self._fallen = set(fallen)
        for k, v in executor.items():
            setattr(self.executor, k, v)

    def observe(self):
        """One depth image from the fixed camera -> a fresh TSDF: (grid, voxel_size_m, origin)."""
        depth, intrinsics, T_task_camera = self.world.render_depth()
        self.volume.reset()
        self.volume.integrate(depth, intrinsics, T_task_camera)
        return self.volume.grid(), self.volume.voxel_size_m, self.volume.origin.copy()

    def detect(self) -> tuple:
        """(tsdf, ranked grasps) of a fresh view."""
        tsdf = self.observe()
        return tsdf, self._detect(tsdf)

    def feasible(self, grasp, tsdf) -> str:
        """'' if the executor would start this grasp, else why not (its own checks)."""
        poses = plan_poses(grasp.pose, self.limits.pregrasp_distance_m, self.limits.lift_height_m)
        try:
            check_limits(poses, self.limits)
        except Abort as e:
            return str(e)
        for X in poses.values():
            ok, message = self.world.check_reachable(X)
            if not ok:
                return message
        return scene_collision(poses, tsdf, self.limits)

    def execute(self, grasp, tsdf) -> dict:
        """Run the grasp, hold, shake, judge by ground truth, remove what was lifted,
        open and go home. -> {pose, score_n, validness, rank_key (clearing.grasp_fields),
        outcome, reason, stopped_by_contact (the executor's), lifted, mode}; `mode`
        is "power" or "precision" for an object in the hand after the executor's lift, else
        "". Raises
        Refused for a grasp the executor would not start (`feasible`)."""
        why = self.feasible(grasp, tsdf)
        if why:
            raise Refused(why)
        p = self.protocol
        self.executor.arm_motion(True)  # a fault disarms it; each attempt starts armed
        result = self.executor.execute(grasp.pose, tsdf=tsdf)
        # How the hand holds what it lifted (contacts), before the hold and shake test it.
        mode = next((s.grasp_mode for s in self.world.object_states() if s.in_hand), "")
        if result.success:
            outcome, reason = self._hold_and_shake()
        else:
            outcome, reason = result.code.name.lower(), result.message
        lifted = [s.name for s in self.world.object_states()
                  if s.in_hand and s.height_above_table_m >= LIFTED_MIN_HEIGHT_M]
        if outcome == "success" and not lifted:
            outcome, reason = "not_lifted", "the gripper reports a held object, but none is between the fingers above the table"
        for name in lifted if outcome == "success" else []:
            self.world.remove_object(name)
        # Open where the hand is (anything still held drops back), then home.
        self.world.command_fingers(self.limits.hand.open_width_m, 0.1, p.grip_force_n)
        self.world.advance(0.6)
        if not self.world.move_tcp(self.home, self.limits.max_speed_mps, 30.0)[0]:
            up = self.world.tcp_pose()
            up[2, 3] = self.home[2, 3]  # straight up first if the direct path is blocked
            self.world.move_tcp(up, self.limits.max_speed_mps, 30.0)
            self.world.move_tcp(self.home, self.limits.max_speed_mps, 30.0)
        return {"pose": np.asarray(grasp.pose).round(6).tolist(), **grasp_fields(grasp),
                "stopped_by_contact": result.stopped_by_contact,
                "outcome": outcome, "reason": reason, "lifted": lifted if outcome == "success" else [],
                "mode": mode}

    def _hold_and_shake(self) -> tuple:
        p = self.protocol
        self.world.advance(p.hold_s)
        if not self._held():
            return "dropped_in_hold", f"the object fell out during the {p.hold_s:.1f} s hold"
        X0 = self.world.tcp_pose()
        for axis in (2, 0):  # vertical first: that is where the weight pulls
            if p.shake_m <= 0:
                break
            for offset in (p.shake_m, -p.shake_m, 0.0):
                X = X0.copy()
                X[axis, 3] += offset
                ok, message = self.world.move_tcp(X, p.shake_speed_mps, 10.0)
                if not ok:
                    return "shake_stopped", f"the shake motion stopped: {message}"
        if not self._held():
            return "dropped_in_shake", f"the object fell out during the +-{p.shake_m * 100:.0f} cm shake"
        return "success", f"held {p.hold_s:.1f} s and through a +-{p.shake_m * 100:.0f} cm shake"

    def _held(self) -> bool:
        return any(s.in_hand and s.height_above_table_m >= LIFTED_MIN_HEIGHT_M for s in self.world.object_states())
