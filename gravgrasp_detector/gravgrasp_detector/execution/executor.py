"""Executing one grasp: checks first, then open, pre-grasp, approach, close, lift, verify.

No ROS here: the executor node (ros/execute_node.py) supplies an `Arm` (moves the TCP
along straight lines; the sim bridge or a real arm's adapter) and a gripper (the
Robotiq 2F-85 driver over Modbus RTU) and turns the `Outcome` into the service reply.

Stages and what stops them (result codes are ExecuteGrasp.srv's):
  validate   finite pose, unit quaternion, task frame           INVALID_REQUEST
  limits     TCP inside the workspace box, approach within the
             cone around gravity (down), lift inside the box     UNREACHABLE
  IK         pre-grasp, grasp, lift reachable by the arm model   UNREACHABLE
  collision  open hand at pre-grasp, along the approach and at
             the grasp, against the latest TSDF                   IN_COLLISION
  table      the pad tips of the fingers closed at the grasp stay
             above the table top (limits.table_z_m)              IN_COLLISION
  fresh view the latest TSDF is recent (node: max_tsdf_age_s)    STALE_SCENE
  connect    activate                                            GRIPPER_FAULT
  open (to limits.hand's opening); once per connection: move to the pre-grasp raised by the
  lift height and calibrate there (close on nothing), or take a
  stored value; pre-grasp, approach, close, lift                  GRIPPER_FAULT / ARM_FAULT / TIMEOUT / NOT_ARMED
             an approach or lift the arm stops short (its contact
             stop): open if closed, back out to the pre-grasp      UNREACHABLE
  verify     held = gOBJ 2 and the opening clearly wider than
             the calibrated empty-closed one, at the close (else
             the fingers open again and back out) and once the
             fingers are still after the lift                     NO_OBJECT / DROPPED
  backing out that fails disarms (the hand may be stuck)         its failure's code
  guarded    (limits.close_on_contact_within_m > 0) an approach
             the contact stop halted at most that far short of
             the grasp: back off 1 mm and close there instead of
             backing out; then verify and lift as above

`execute_first_feasible` takes grasps best first and runs the first one that passes the
checks before any motion (limits, IK, collision, table): a grasp refused there costs no
motion, so the next-ranked one is as safe to try; a failure after motion ends the call.

Why a calibration: closing fully on nothing, a 2F-85's fingertips can meet and report
an object (gOBJ 2), at an opening that varies by unit and by how the underactuated
fingers folded (robotiq_driver/grip_calibration.py). A fixed "closed" limit of 3 mm
once reported SUCCESS at 3.7 mm with nothing in the hand.
"""
from __future__ import annotations

import dataclasses
import enum
import math
import threading
from typing import Callable, NamedTuple, Protocol

import numpy as np

from robotiq_driver import grip_calibration
from robotiq_driver.gripper_client import GripperError, GripperTimeout
from robotiq_driver.gripper_registers import ObjectStatus

from ..perception import hand_clearance
from ..perception.hand_clearance import ROBOTIQ_2F85, HandGeometry
from ..poses import PoseError, matrix_from_pose


class ResultCode(enum.IntEnum):
    """Same numbers as gravgrasp_msgs/srv/ExecuteGrasp response constants."""
    SUCCESS = 0
    INVALID_REQUEST = 1
    UNREACHABLE = 2
    IN_COLLISION = 3
    GRIPPER_FAULT = 4
    NO_OBJECT = 5
    DROPPED = 6
    BUSY = 7
    TIMEOUT = 8
    NOT_ARMED = 9
    ARM_FAULT = 10
    STALE_SCENE = 11


@dataclasses.dataclass
class Outcome:
    code: ResultCode
    message: str
    # the arm's contact stop halted a motion of this execution (the flag the arm set, not
    # the message's words): what the benchmark's records classify jammed approaches by
    stopped_by_contact: bool = False

    @property
    def success(self) -> bool:
        return self.code == ResultCode.SUCCESS


class Abort(Exception):
    def __init__(self, code: ResultCode, message: str, stopped_by_contact: bool = False):
        super().__init__(message)
        self.outcome = Outcome(code, message, stopped_by_contact)

    @property
    def stopped_by_contact(self) -> bool:  # the arm's contact stop ended a motion
        return self.outcome.stopped_by_contact


@dataclasses.dataclass
class ExecutionLimits:
    """Hard limits no request can exceed (node parameters)."""
    workspace_min_m: tuple = (-0.05, -0.05, 0.0)   # TCP box in the task frame
    workspace_max_m: tuple = (0.35, 0.35, 0.50)
    approach_cone_deg: float = 80.0    # max angle between approach (TCP z) and gravity (down)
    max_speed_mps: float = 0.25        # arm TCP speed cap
    approach_speed_mps: float = 0.05   # pre-grasp -> grasp, and backing out
    # A faster approach, as a real cell makes it: pre-grasp -> approach_slow_last_m short
    # of the grasp at this speed, the rest at approach_speed_mps. 0: all of it slow.
    approach_fast_speed_mps: float = 0.0
    approach_slow_last_m: float = 0.01
    lift_speed_mps: float = 0.05       # grasp -> lift, with the object in the hand
    max_force_n: float = 235.0         # gripper force cap (2F-85 max)
    grip_force_n: float = 40.0         # the paper's grasp force
    grip_speed_mps: float = 0.1
    pregrasp_distance_m: float = 0.05  # used when the grasp does not suggest one
    lift_height_m: float = 0.15
    gripper_timeout_s: float = 5.0
    arm_timeout_s: float = 20.0
    # Held = gOBJ 2 and an opening at least this much wider than where the fingers
    # close on nothing. 4 mm: in the Drake 2F-85 the empty-closed opening is 1.1 mm
    # from open but 3.7 mm after a fingertip pinch lost its object (folded fingers).
    min_object_width_m: float = 0.004
    # Where the fingers close on nothing, if measured before (m); None: measure it on
    # every connection (open, close on nothing at the grip's speed and force, open).
    empty_closed_width_m: float | None = None
    # Table top in the task frame (m): refuse grasps whose closing fingers would reach
    # below it (the labels' check; the 2F-85's linkage only). None: no table check.
    table_z_m: float | None = None
    # The hand: its opening and open-hand boxes (the clearance check). Not a node
    # parameter: the node runs the 2F-85; the sim bridge's benchmark passes the Panda's.
    hand: HandGeometry = ROBOTIQ_2F85
    # Guarded approach (m): an approach the arm's contact stop halts at most this far
    # short of the grasp closes there (1 mm backed off) instead of backing out. 0: off.
    # Why: in the benchmark most of Ours' approaches stopped by contact stopped within
    # 9 mm of the grasp, on a surface the TSDF check forgives (half a voxel).
    close_on_contact_within_m: float = 0.0


class ArmTimeout(Exception):
    """Raised by an Arm when a motion (or the arm's interface) did not answer within the
    motion's timeout: the result is TIMEOUT. A motion the arm refused or could not finish
    is (False, why) instead: UNREACHABLE."""


class ArmUnavailable(Exception):
    """Raised by an Arm when the arm itself is gone (its service vanished, the
    controller dropped the connection): where the arm stopped is unknown."""


class ArmMotion(NamedTuple):
    """How a motion ended (MoveToPose's response fields)."""
    arrived: bool
    message: str
    stopped_by_contact: bool = False  # the arm's contact stop halted it
    distance_left_m: float = math.nan  # from where the TCP stopped to the target; NaN: unknown


def arm_motion(result) -> ArmMotion:
    """An Arm's answer as an ArmMotion. A contact stop is known only from the flag the arm
    sets where it detects the stop (the sim world's motion, ur_arm's force check, MoveToPose's
    stopped_by_contact), never from the message's words: an arm that answers (arrived,
    message) only reports no contact stop, and how far short is unknown."""
    if isinstance(result, ArmMotion):
        return result
    arrived, message = result
    return ArmMotion(bool(arrived), message)


class Arm(Protocol):
    def move_to(self, X_task_tcp: np.ndarray, speed_mps: float, timeout_s: float) -> ArmMotion:
        """ArmMotion(arrived=True, ...) when the TCP arrived; arrived=False with why when the
        arm refused or could not finish the motion; raises ArmTimeout or ArmUnavailable.
        (arrived, message) is accepted too, with no contact stop (`arm_motion`)."""


def pose_to_matrix(position, quaternion_xyzw) -> np.ndarray:
    """Validated grasp pose -> 4x4; raises Abort(INVALID_REQUEST) with the reason."""
    try:
        return matrix_from_pose(position, quaternion_xyzw)
    except PoseError as e:
        raise Abort(ResultCode.INVALID_REQUEST, f"grasp pose: {e}: send a finite pose with a unit quaternion") from None


def plan_poses(X_grasp, pregrasp_distance_m, lift_height_m) -> dict[str, np.ndarray]:
    """Pre-grasp: back off along -approach; lift: straight up along task z."""
    pregrasp, lift = X_grasp.copy(), X_grasp.copy()
    pregrasp[:3, 3] -= pregrasp_distance_m * X_grasp[:3, 2]
    lift[2, 3] += lift_height_m
    return {"pregrasp": pregrasp, "grasp": X_grasp, "lift": lift}


def check_limits(poses, limits: ExecutionLimits) -> None:
    lo, hi = np.asarray(limits.workspace_min_m, float), np.asarray(limits.workspace_max_m, float)
    for name, X in poses.items():
        p = X[:3, 3]
        if np.any(p < lo) or np.any(p > hi):
            raise Abort(ResultCode.UNREACHABLE,
                        f"{name} TCP position {np.round(p, 3).tolist()} m is outside the workspace box "
                        f"{lo.tolist()}..{hi.tolist()} m (parameters workspace_min_m/workspace_max_m)")
    approach = poses["grasp"][:3, 2]
    angle = np.degrees(np.arccos(np.clip(-approach[2], -1.0, 1.0)))  # 0 = straight down
    if angle > limits.approach_cone_deg:
        raise Abort(ResultCode.UNREACHABLE,
                    f"approach is {angle:.0f} deg from straight down, beyond the {limits.approach_cone_deg:.0f} deg "
                    "cone (parameter approach_cone_deg)")


def scene_collision(poses, tsdf, limits: ExecutionLimits) -> str:
    """'' if the open hand clears the TSDF at the pre-grasp, along the approach and at the
    grasp (`tsdf`: (grid, voxel_size_m, origin), or None: unchecked), and the closing
    fingertips stay above the table (limits.table_z_m); otherwise why not."""
    hit = hand_clearance.first_collision(poses, tsdf, limits.hand) if tsdf is not None else ""
    if not hit and limits.table_z_m is not None:
        hit = hand_clearance.closed_tips_below_table(poses["grasp"], tsdf, limits.table_z_m)
    return hit


class GraspExecutor:
    """Runs one grasp at a time; `armed` gates every motion, `estop()` disarms."""

    def __init__(self, arm: Arm, gripper_factory: Callable[[], object], limits: ExecutionLimits,
                 reachability=None, log=print):
        self.arm = arm
        self.gripper_factory = gripper_factory  # connects lazily; a replugged gripper reconnects
        self.gripper = None
        self.calibration = None  # grip_calibration.EmptyClosedCalibration of this connection
        self.limits = limits
        if limits.table_z_m is not None and not np.isfinite(limits.table_z_m):
            raise ValueError(f"table_z_m {limits.table_z_m}: give the table top's height in the task frame [m] "
                             "(0.0 when the task frame's origin is on the table)")
        if limits.table_z_m is not None and not limits.hand.closing_tips_modelled:
            raise ValueError(f"table_z_m: the fingertip-against-table check models the 2F-85's linkage, not the "
                             f"{limits.hand.name} hand's: leave table_z_m unset (None) for it")
        if not (np.isfinite(limits.close_on_contact_within_m) and limits.close_on_contact_within_m >= 0):
            raise ValueError(f"close_on_contact_within_m {limits.close_on_contact_within_m}: give how far short of "
                             "the grasp [m] a contact-stopped approach may close (0 = always back out)")
        for name in ("approach_fast_speed_mps", "approach_slow_last_m"):
            value = getattr(limits, name)
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"{name} {value}: give a value >= 0 (approach_fast_speed_mps 0: the whole "
                                 "approach at approach_speed_mps)")
        self._stored_calibration = None  # a bad stored value stops the node at start (ValueError)
        if limits.empty_closed_width_m is not None:
            self._stored_calibration = grip_calibration.stored_calibration(
                limits.empty_closed_width_m, limits.grip_speed_mps, min(limits.grip_force_n, limits.max_force_n))
        self.reachability = reachability
        self.log = log
        self.armed = False
        self.estopped = threading.Event()
        self._busy = threading.Lock()

    def arm_motion(self, enable: bool) -> str:
        if enable and self.estopped.is_set():
            self.estopped.clear()
        self.armed = enable
        return "armed: motion allowed" if enable else "disarmed: motion refused"

    def estop(self) -> None:
        self.estopped.set()
        self.armed = False
        if self.gripper is not None:
            try:
                self.gripper.stop()
            except GripperError:
                pass

    def execute(self, X_grasp: np.ndarray, tsdf=None, pregrasp_distance_m: float = 0.0) -> Outcome:
        """Execute, or refuse with BUSY at once if another execution runs."""
        return self.execute_first_feasible([(X_grasp, pregrasp_distance_m)], tsdf)[0]

    def execute_first_feasible(self, grasps, tsdf=None) -> tuple[Outcome, int]:
        """`grasps`: (X_grasp, pregrasp_distance_m) best first. Runs the first that passes
        the checks before motion; returns (its outcome, its index = how many were refused
        before it). If every one is refused: the last refusal, len - 1. BUSY at once if
        another execution runs (index 0)."""
        if not self._busy.acquire(blocking=False):
            return Outcome(ResultCode.BUSY, "another grasp is being executed; retry when it has finished"), 0
        index = 0
        try:
            self.refuse_if_estopped("execute a grasp")
            for index, (X_grasp, pregrasp_distance_m) in enumerate(grasps):
                try:
                    poses = self._checked_poses(X_grasp, tsdf, pregrasp_distance_m)
                except Abort as refusal:
                    if index == len(grasps) - 1:
                        if index:
                            refusal.outcome.message = (f"all {len(grasps)} grasps refused before any motion; "
                                                       f"the last: {refusal.outcome.message}")
                        raise
                    continue
                return self._execute(poses), index
            raise Abort(ResultCode.INVALID_REQUEST, "no grasp to execute")
        except Abort as abort:
            if abort.outcome.code in (ResultCode.GRIPPER_FAULT, ResultCode.ARM_FAULT, ResultCode.TIMEOUT,
                                      ResultCode.NOT_ARMED):
                self.armed = False  # any fault disarms: a person must look before the next motion
            return abort.outcome, index
        finally:
            self._busy.release()

    # -- stages ---------------------------------------------------------------------

    def _checked_poses(self, X_grasp, tsdf, pregrasp_distance_m) -> dict:
        """The poses of an execution, after every check that needs no motion (limits, IK,
        the open hand against the TSDF, the fingertips against the table); Abort with
        UNREACHABLE or IN_COLLISION if one fails."""
        lim = self.limits
        poses = plan_poses(X_grasp, pregrasp_distance_m or lim.pregrasp_distance_m, lim.lift_height_m)
        if self.calibration is None and self._stored_calibration is None:
            # Measure where the fingers close on nothing well clear of the scene: the
            # pre-grasp raised by the lift height (at the pre-grasp itself the top of a
            # tall object can already be between the fingers).
            X_cal = poses["pregrasp"].copy()
            top = float(lim.workspace_max_m[2])  # a high grasp: as high as the workspace allows
            X_cal[2, 3] = max(X_cal[2, 3], min(X_cal[2, 3] + lim.lift_height_m, top))
            poses = {"calibrate": X_cal, **poses}
        check_limits(poses, lim)
        if self.reachability is not None:
            reach = self.reachability.check(poses)
            if not reach.reachable:
                raise Abort(ResultCode.UNREACHABLE, reach.message)
        hit = scene_collision(poses, tsdf, lim)
        if hit:
            raise Abort(ResultCode.IN_COLLISION, hit)
        return poses

    def _execute(self, poses) -> Outcome:
        lim = self.limits
        self._require_armed("open the gripper")
        gripper = self._gripper()
        self._grip(gripper, self.limits.hand.open_width_m, "opening")
        if "calibrate" in poses:  # once per connection
            self._move_to_start("calibration", poses["calibrate"])
            self._calibrate()
        elif self.calibration is None:
            self._calibrate()  # the stored value
        self._move_to_start("pregrasp", poses["pregrasp"])
        guarded = ""
        try:
            motion = self._approach(poses)
            if not motion.arrived:
                poses, guarded = self._close_short(motion, poses)
        except Abort as abort:
            raise self._backed_out(abort, gripper, poses, open_first=False) from None
        closed = self._grip(gripper, 0.0, "closing")
        verdict = self._judge(gripper, closed)
        if not verdict.held:
            # Open before backing out: a thin pinch the check cannot tell from an empty
            # hand must not be carried away while the answer says "nothing".
            raise self._back_out(gripper, poses, ResultCode.NO_OBJECT,
                                 f"the grasp missed the object: {verdict.reason}{guarded}", open_first=True)
        try:
            self._move("lift", poses["lift"], lim.lift_speed_mps)
        except Abort as abort:
            abort.outcome.message += guarded
            raise self._backed_out(abort, gripper, poses, open_first=True) from None
        after = self._after_lift(gripper)
        verdict = self._judge(gripper, after)
        if not verdict.held:
            return Outcome(ResultCode.DROPPED, f"the object slipped out during the lift: {verdict.reason}{guarded}")
        return Outcome(ResultCode.SUCCESS, f"lifted {lim.lift_height_m:.2f} m and held, {verdict.reason}{guarded}")

    def _approach(self, poses) -> ArmMotion:
        """Pre-grasp -> grasp: at approach_speed_mps, or, with approach_fast_speed_mps set,
        fast to approach_slow_last_m short of the grasp and slow from there. A stop on the
        fast part is reported as the approach's: its distance left counts to the grasp."""
        lim = self.limits
        guarded = lim.close_on_contact_within_m > 0
        slow_m = lim.approach_slow_last_m
        travel_m = float(np.linalg.norm(poses["grasp"][:3, 3] - poses["pregrasp"][:3, 3]))
        if lim.approach_fast_speed_mps > lim.approach_speed_mps and travel_m > slow_m:
            X_slow = poses["grasp"].copy()
            X_slow[:3, 3] -= slow_m * poses["grasp"][:3, 2]
            fast = self._move("grasp", X_slow, lim.approach_fast_speed_mps, require_arrival=not guarded)
            if not fast.arrived:
                return fast._replace(distance_left_m=fast.distance_left_m + slow_m)
        return self._move("grasp", poses["grasp"], lim.approach_speed_mps, require_arrival=not guarded)

    CONTACT_BACKOFF_M = 0.001  # off the surface the contact stop pressed on, before closing
    CLOSED_SHORT = "mm short of the grasp pose"  # in every outcome after a guarded close

    def _close_short(self, motion: ArmMotion, poses) -> tuple[dict, str]:
        """The guarded approach: the arm stopped on the way to the grasp. A contact stop at
        most limits.close_on_contact_within_m short: back off CONTACT_BACKOFF_M along the
        approach and return the poses to close and lift from there, with a note for the
        outcome. Anything else raises Abort(UNREACHABLE) (the caller backs out)."""
        short_m = motion.distance_left_m
        within = self.limits.close_on_contact_within_m
        why = f"arm could not reach the grasp pose: {motion.message}"
        if not (motion.stopped_by_contact and within > 0 and math.isfinite(short_m) and short_m <= within):
            raise Abort(ResultCode.UNREACHABLE, why, motion.stopped_by_contact)
        back_m = short_m + self.CONTACT_BACKOFF_M
        approach = poses["grasp"][:3, 2]
        closing = {name: X.copy() for name, X in poses.items()}
        for name in ("grasp", "lift"):
            closing[name][:3, 3] -= back_m * approach
        try:
            check_limits({"lift": closing["lift"], "grasp": closing["grasp"]}, self.limits)
        except Abort as refusal:
            raise Abort(ResultCode.UNREACHABLE, f"{why}; closing there: {refusal.outcome.message}", True) from None
        self._move("backed-off grasp", closing["grasp"], self.limits.approach_speed_mps)
        note = (f"; closed {back_m * 1e3:.1f} {self.CLOSED_SHORT}, backed off where the arm's contact "
                f"stop halted the approach (close_on_contact_within_m {within * 1e3:.0f} mm)")
        return closing, note

    def _move_to_start(self, name, X):
        """A move from wherever the arm is to a pose above the scene (calibration,
        pre-grasp). Only the poses were checked, not the way there: if the arm's contact
        stop halts it, the hand touched something unexpected (a person, a part of the cell
        outside the volume). There is no known path to back out along, so the executor
        disarms: a person must look before it moves again."""
        try:
            self._move(name, X, self.limits.max_speed_mps)
        except Abort as abort:
            if abort.outcome.code != ResultCode.UNREACHABLE or not abort.stopped_by_contact:
                raise
            self.armed = False
            raise Abort(ResultCode.UNREACHABLE, f"{abort.outcome.message}; the hand touched something on its way "
                                                "to a pose above the scene; disarmed: check the cell, then arm "
                                                "again", True) from None

    def _backed_out(self, abort: Abort, gripper, poses, open_first: bool) -> Abort:
        """After the approach or the lift stopped short (UNREACHABLE: e.g. the arm's
        contact stop), back the hand out (`_back_out`), so that it does not stay pressed
        into the scene and the next motion does not start there. Faults, timeouts and
        stops are left as they are (the executor is disarmed)."""
        if abort.outcome.code != ResultCode.UNREACHABLE:
            return abort
        return self._back_out(gripper, poses, ResultCode.UNREACHABLE, abort.outcome.message, open_first,
                              abort.stopped_by_contact)

    def _back_out(self, gripper, poses, code: ResultCode, message: str, open_first: bool,
                  stopped_by_contact: bool = False) -> Abort:
        """Open the fingers if they closed, then move back along the approach to the
        pre-grasp at the approach speed. Returns the Abort to raise: `code` with `message`
        and what was done, or, when backing out failed, that failure's code, having
        disarmed (the hand may be stuck in the scene: a person must look)."""
        try:
            if open_first:
                self._grip(gripper, self.limits.hand.open_width_m, "opening")
            self._move("pre-grasp (backing out)", poses["pregrasp"], self.limits.approach_speed_mps)
        except Abort as failed:
            self.armed = False
            return Abort(failed.outcome.code, f"{message}; backing out failed: {failed.outcome.message}; "
                                              "disarmed: check the hand, then arm again",
                         stopped_by_contact or failed.stopped_by_contact)
        done = "opened and backed out" if open_first else "backed out"
        return Abort(code, f"{message}; {done} to the pre-grasp", stopped_by_contact)

    def _judge(self, gripper, state):
        return grip_calibration.judge_grip(state.object_status, gripper.width_m(state), self.calibration,
                                           self.limits.min_object_width_m)

    def refuse_if_estopped(self, action):
        """Raises Abort(NOT_ARMED) while an emergency stop is active. Checked before any
        other check too: until a person releases it, nothing else about a request
        (its pose, the age of the view) is the answer an operator needs."""
        if self.estopped.is_set():
            raise Abort(ResultCode.NOT_ARMED, f"emergency stop is active: refusing to {action}; "
                                              "release it and arm again (service ~/arm)")

    def _require_armed(self, action):
        self.refuse_if_estopped(action)
        if not self.armed:
            raise Abort(ResultCode.NOT_ARMED, f"executor is not armed: refusing to {action}; "
                                              "call the ~/arm service (std_srvs/SetBool true) first")

    def _gripper(self):
        if self.gripper is None:
            try:
                self.gripper = self.gripper_factory()
                # Also clears a latched major fault: we only get here armed, i.e. after a
                # person re-armed following the fault.
                self.gripper.activate(timeout_s=self.limits.gripper_timeout_s)
            except (GripperError, OSError) as err:
                self._drop_gripper()
                raise Abort(ResultCode.GRIPPER_FAULT, f"gripper unavailable: {err}") from None
        return self.gripper

    def _calibrate(self):
        """Where this gripper's fingers close on nothing: stored, or measured now, at the
        calibration pose (pre-grasp + lift height: nothing should be between the fingers
        there; after a fault the hand may still surround an object at the last grasp
        pose, so calibrating where the hand happens to be would refuse)."""
        lim = self.limits
        force = min(lim.grip_force_n, lim.max_force_n)
        try:
            if self._stored_calibration is not None:
                self.calibration = self._stored_calibration
            else:
                self._require_armed("calibrate the gripper (it closes once on nothing)")
                self.calibration = grip_calibration.calibrate_empty_closed(
                    self.gripper, lim.grip_speed_mps, force, lim.gripper_timeout_s)
        except GripperError as err:
            self._drop_gripper()
            if self.estopped.is_set():  # estop() stopped the fingers mid-calibration
                raise Abort(ResultCode.NOT_ARMED, "emergency stop during the gripper calibration: fingers halted; "
                                                  "release it and arm again (service ~/arm)") from None
            code = ResultCode.TIMEOUT if isinstance(err, GripperTimeout) else ResultCode.GRIPPER_FAULT
            raise Abort(code, f"gripper calibration failed: {err}") from None
        self.log(f"gripper calibrated: {self.calibration.describe()}; held needs "
                 f">= {(self.calibration.width_m + lim.min_object_width_m) * 1e3:.1f} mm with gOBJ 2")

    def _drop_gripper(self):
        """Forget the connection (closing it: the port is opened exclusively, so a
        reconnect would fail while the old client holds it) and its calibration."""
        gripper, self.gripper = self.gripper, None
        self.calibration = None
        if gripper is not None and hasattr(gripper, "close"):
            try:
                gripper.close()
            except (GripperError, OSError):
                pass

    def _read(self, gripper):
        try:
            return gripper.read_state()
        except GripperError as err:
            self._drop_gripper()
            raise Abort(ResultCode.GRIPPER_FAULT, f"gripper stopped answering: {err}") from None

    def _after_lift(self, gripper):
        """The gripper's state once the fingers are still again. Lifting can shift the
        object in the hand: the fingers move on (gOBJ 0) until they stop on it again
        (an underactuated finger wrapping into a power grasp) or close on nothing (it
        slipped out). A read in that moment is neither, so wait for the end."""
        state = self._read(gripper)
        if state.object_status != ObjectStatus.MOVING:
            return state
        try:
            return gripper.wait(timeout_s=self.limits.gripper_timeout_s)
        except GripperTimeout as err:
            raise Abort(ResultCode.TIMEOUT, f"fingers still moving after the lift: {err}") from None
        except GripperError as err:
            self._drop_gripper()
            raise Abort(ResultCode.GRIPPER_FAULT, f"gripper failed after the lift: {err}") from None

    GRIP_VERBS = {"opening": "open", "closing": "close"}

    def _grip(self, gripper, width_m, what):
        self._require_armed(f"{self.GRIP_VERBS[what]} the gripper")
        force = min(self.limits.grip_force_n, self.limits.max_force_n)
        try:
            return gripper.move_and_wait(width_m, self.limits.grip_speed_mps, force,
                                         timeout_s=self.limits.gripper_timeout_s)
        except GripperTimeout as err:
            if self.estopped.is_set():  # estop() stopped the fingers mid-motion
                raise Abort(ResultCode.NOT_ARMED, f"emergency stop during gripper {what}: fingers halted; "
                                                  "release it and arm again (service ~/arm)") from None
            raise Abort(ResultCode.TIMEOUT, f"gripper {what} did not finish: {err}") from None
        except GripperError as err:
            self._drop_gripper()  # reconnect (and re-activate) on the next attempt
            raise Abort(ResultCode.GRIPPER_FAULT, f"gripper {what} failed: {err}") from None

    def _move(self, name, X, speed_mps, require_arrival=True) -> ArmMotion:
        """Move the TCP to X. Raises Abort if the arm did not arrive, unless
        `require_arrival` is False (the caller decides, from the ArmMotion)."""
        self._require_armed(f"move to the {name} pose")
        try:
            motion = arm_motion(self.arm.move_to(X, min(speed_mps, self.limits.max_speed_mps),
                                                 self.limits.arm_timeout_s))
        except ArmTimeout as err:
            raise Abort(ResultCode.TIMEOUT, f"arm could not reach the {name} pose: {err}") from None
        except ArmUnavailable as err:
            raise Abort(ResultCode.ARM_FAULT, f"arm lost during the move to the {name} pose: {err}; "
                                              "check the arm and its driver, then arm again") from None
        if self.estopped.is_set():
            raise Abort(ResultCode.NOT_ARMED, f"emergency stop during the move to {name}")
        if not motion.arrived and require_arrival:
            raise Abort(ResultCode.UNREACHABLE, f"arm could not reach the {name} pose: {motion.message}",
                        motion.stopped_by_contact)
        return motion
