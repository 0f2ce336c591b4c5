"""The executor's core: every refusal and every outcome, against the Robotiq emulator
over a real pseudo-terminal (Modbus RTU) and a recording arm.

The arm here is a test double (it records target poses and can block) and the object
is a 50 mm block that is between the fingers at the grasp pose, or while they hold
it; the end-to-end tests drive the Drake sim bridge instead.
"""
import threading
import time

import numpy as np
import pytest

from gravgrasp_detector.execution import executor as ge
from gravgrasp_detector.execution.reachability import ArmReachability
from gravgrasp_detector.perception import hand_clearance
from robotiq_driver.emulator.emulated_gripper import FingerReading, GripperEmulator, KinematicFingers
from robotiq_driver.emulator.pty_modbus_server import PtyModbusServer
from robotiq_driver.gripper_client import Robotiq2F85

DOWN = [1.0, 0.0, 0.0, 0.0]  # quaternion (x, y, z, w): 180 deg about x -> TCP z points down


class ObjectAtGrasp(KinematicFingers):
    """Fingers and one object of `size_m`: it is between them while the hand is at the
    grasp pose (`at_grasp`, set by the arm) or while they hold it; opened, it falls away.
    `lose()` makes a held object slip out; while `frozen` the fingers neither move nor
    stall, so the gripper keeps reporting "moving" (gOBJ 0), as a 2F-85 whose fingers are
    caught on something can."""

    def __init__(self, size_m=0.05, fingers_meet_m=0.0):
        super().__init__(fingers_meet_m=fingers_meet_m)
        self.size_m, self.at_grasp, self.held = size_m, False, False
        self.stuck = False  # between the fingers wherever the hand is
        self.frozen = False

    def lose(self):
        """The object slips out of the hand."""
        self.at_grasp = self.held = False

    def advance(self, dt_s, width_m, target_width_m, speed_mps, force_n):
        if self.frozen and target_width_m != width_m:
            return FingerReading(width_m, False, self.moving_current_a)
        there = self.size_m is not None and (self.at_grasp or self.held or self.stuck)
        self.object_width_m = self.size_m if there else None
        reading = super().advance(dt_s, width_m, target_width_m, speed_mps, force_n)
        if there and reading.blocked and abs(reading.width_m - self.size_m) < 1e-9:
            self.held = True
        elif not there or (target_width_m > width_m and reading.width_m > self.size_m):
            self.held = False
        return reading


class RecordingArm:
    def __init__(self, fingers=None):
        self.targets = []
        self.fingers = fingers
        self.gate = None  # an Event the arm waits on, to hold an execution open

    def move_to(self, X, speed_mps, timeout_s):
        self.targets.append((X.copy(), speed_mps))
        if self.fingers is not None:
            self.fingers.at_grasp = False  # the hand leaves where it was
        if self.gate is not None and not self.gate.wait(timeout_s):
            raise ge.ArmTimeout("timed out")
        if self.fingers is not None:  # the approach ends at the grasp pose, where the object is
            self.fingers.at_grasp = speed_mps == pytest.approx(0.05) and X[2, 3] < 0.1
        return True, "done"


@pytest.fixture
def fingers():
    return ObjectAtGrasp(0.05)


@pytest.fixture
def gripper_port(tmp_path, fingers):
    emulator = GripperEmulator(fingers, activation_time_s=0.05)
    with PtyModbusServer(emulator, link_path=str(tmp_path / "ttyGripper")) as server:
        server.emulator = emulator
        yield server


def make_executor(gripper_port, reach=None, armed=True, **limits):
    arm = RecordingArm(gripper_port.emulator.plant)
    lim = ge.ExecutionLimits(grip_speed_mps=0.15, **limits)
    # Modbus answers within 0.3 s: under load 0.1 s once missed one
    ex = ge.GraspExecutor(arm, lambda: Robotiq2F85(gripper_port.port, timeout_s=0.3, retries=1), lim, reach)
    ex.arm_motion(armed)
    return ex, arm


def grasp(x=0.15, y=0.15, z=0.08, q=DOWN):
    return ge.pose_to_matrix([x, y, z], q)


# The moves of an execution of grasp(): calibration pose (first execution of a
# connection: pre-grasp + 15 cm), pre-grasp, grasp, lift, told apart by height.
def is_grasp(X):
    return abs(X[2, 3] - 0.08) < 1e-6


def is_lift(X):
    return abs(X[2, 3] - 0.23) < 1e-6


def test_malformed_poses_are_invalid_requests():
    for p, q in [([np.nan, 0, 0], DOWN), ([0, 0, 0], [0, 0, 0, 2.0]), ([0, 0, np.inf], DOWN)]:
        with pytest.raises(ge.Abort) as err:
            ge.pose_to_matrix(p, q)
        assert err.value.outcome.code == ge.ResultCode.INVALID_REQUEST


def test_successful_grasp_moves_through_pregrasp_grasp_lift(gripper_port):
    ex, arm = make_executor(gripper_port)
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.SUCCESS, outcome.message
    z = [round(X[2, 3], 3) for X, _ in arm.targets]
    # calibration 15 cm above the pre-grasp, pre-grasp 5 cm back along the approach, grasp, lift 15 cm
    assert z == [0.28, 0.13, 0.08, 0.23]
    assert arm.targets[2][1] == pytest.approx(0.05)  # approach at the approach speed
    assert ex.execute(grasp()).success
    assert [round(X[2, 3], 3) for X, _ in arm.targets[4:]] == [0.13, 0.08, 0.23]  # calibrated once per connection
    assert "held, opening 50.0 mm" in outcome.message


def test_closing_on_nothing_is_no_object(gripper_port, fingers):
    fingers.size_m = None
    ex, arm = make_executor(gripper_port)
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.NO_OBJECT
    assert arm.targets[-1][0][2, 3] == pytest.approx(0.13)  # backed out to the pre-grasp pose
    assert arm.targets[-1][1] == pytest.approx(0.05)  # at the approach speed
    assert gripper_port.emulator.width_m == pytest.approx(0.085)  # opened before backing out
    assert outcome.message.endswith("; opened and backed out to the pre-grasp") and ex.armed


@pytest.mark.parametrize("meet_mm", [0.0, 1.1, 3.7, 8.0])
def test_fingers_that_meet_and_report_an_object_are_no_false_success(tmp_path, meet_mm):
    """A 2F-85 closing on nothing can stop with its fingertips touching and report an
    object (gOBJ 2), at an opening that differs per unit. Calibrated per connection,
    the executor says NO_OBJECT for a miss and DROPPED for an object lost in the lift,
    wherever the fingers meet, and SUCCESS for a held 20 mm object."""
    fingers = ObjectAtGrasp(None, fingers_meet_m=meet_mm * 1e-3)
    emulator = GripperEmulator(fingers, activation_time_s=0.05)
    with PtyModbusServer(emulator, link_path=str(tmp_path / "ttyGripper")) as server:
        server.emulator = emulator
        ex, arm = make_executor(server)
        miss = ex.execute(grasp())
        assert ex.calibration.width_m == pytest.approx(meet_mm * 1e-3, abs=0.4e-3)  # one count is 0.33 mm
        assert miss.code == ge.ResultCode.NO_OBJECT, miss.message
        if meet_mm > 0:
            assert "where they close on nothing" in miss.message and "gOBJ 2" in miss.message

        fingers.size_m = 0.02
        assert ex.execute(grasp()).code == ge.ResultCode.SUCCESS

        original = arm.move_to

        def drop_on_lift(X, speed, timeout):
            if X[2, 3] > 0.2:  # the lift: the object slips out, the fingers close on to where they meet
                fingers.lose()
            return original(X, speed, timeout)

        arm.move_to = drop_on_lift
        dropped = ex.execute(grasp())
        assert dropped.code == ge.ResultCode.DROPPED, dropped.message


def test_a_pinch_thinner_than_the_margin_is_released_not_claimed(gripper_port, fingers):
    """An object 2 mm wider than where the fingers meet cannot be told from an empty
    hand: NO_OBJECT, and the fingers open so the answer matches what the hand holds."""
    fingers.fingers_meet_m, fingers.size_m = 0.0037, 0.0057
    ex, arm = make_executor(gripper_port)
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.NO_OBJECT, outcome.message
    assert gripper_port.emulator.width_m == pytest.approx(0.085) and not fingers.held


def test_stored_calibration_is_used_and_checked(gripper_port):
    ex, arm = make_executor(gripper_port, empty_closed_width_m=0.001)
    assert ex.execute(grasp()).code == ge.ResultCode.SUCCESS
    assert ex.calibration.source == "stored" and ex.calibration.width_m == 0.001
    with pytest.raises(ValueError, match="gripper_cli calibrate"):  # 30 mm is no empty hand
        make_executor(gripper_port, empty_closed_width_m=0.03)


def test_calibration_refuses_a_hand_that_is_not_empty(gripper_port, fingers):
    fingers.stuck = True  # something between the fingers even at the pre-grasp pose
    ex, arm = make_executor(gripper_port)
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.GRIPPER_FAULT and "something is between" in outcome.message
    assert len(arm.targets) == 1 and not ex.armed  # only the move to the calibration pose


def test_object_lost_during_the_lift_is_dropped(gripper_port, fingers):
    ex, arm = make_executor(gripper_port)
    original = arm.move_to

    def drop_on_lift(X, speed, timeout):
        if is_lift(X):  # the object slips out
            fingers.lose()
            gripper_port.emulator.advance()
        return original(X, speed, timeout)

    arm.move_to = drop_on_lift
    outcome = ex.execute(grasp())
    # The fingers move on and stop fully closed; the executor judges once they are still.
    assert outcome.code == ge.ResultCode.DROPPED, outcome.message
    assert "slipped out" in outcome.message


CONTACT = "stopped by contact after 0.030 of 0.050 m: the force on the hand rose from 0 to 64 N, by more than the 60 N limit"


def stopping_arm(arm, stops):
    """The arm's contact stop ends the motions `stops(X)` picks, short of them."""
    original = arm.move_to

    def move_to(X, speed, timeout):
        if stops(X):
            arm.targets.append((X.copy(), speed))
            return ge.ArmMotion(False, CONTACT, stopped_by_contact=True)
        return original(X, speed, timeout)
    arm.move_to = move_to


def test_an_approach_stopped_by_contact_backs_out_to_the_pregrasp(gripper_port):
    ex, arm = make_executor(gripper_port)
    stopping_arm(arm, is_grasp)
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.UNREACHABLE
    assert outcome.message == f"arm could not reach the grasp pose: {CONTACT}; backed out to the pre-grasp"
    assert outcome.stopped_by_contact  # the arm's flag, carried to the outcome (the benchmark's records)
    assert [round(X[2, 3], 3) for X, _ in arm.targets] == [0.28, 0.13, 0.08, 0.13]
    assert arm.targets[-1][1] == pytest.approx(0.05)  # back out as slowly as it went in
    assert gripper_port.emulator.width_m == pytest.approx(0.085) and ex.armed


def short_approach(arm, left_m, by_contact=True):
    """The approach ends `left_m` short of the grasp pose, as the arm reports it (ArmMotion)."""
    original = arm.move_to

    def move_to(X, speed, timeout):
        if is_grasp(X):
            arm.targets.append((X.copy(), speed))
            return ge.ArmMotion(False, CONTACT if by_contact else "protective stop", by_contact, left_m)
        return original(X, speed, timeout)
    arm.move_to = move_to


def test_a_guarded_approach_closes_where_contact_stopped_it(gripper_port):
    """close_on_contact_within_m: stopped 4 mm short, the hand backs off 1 mm and closes
    there, then lifts straight up from there."""
    ex, arm = make_executor(gripper_port, close_on_contact_within_m=0.01)
    short_approach(arm, 0.004)
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.SUCCESS, outcome.message
    assert "closed 5.0 mm short of the grasp pose" in outcome.message, outcome.message
    assert [round(X[2, 3], 4) for X, _ in arm.targets] == [0.28, 0.13, 0.08, 0.085, 0.235]
    assert arm.targets[3][1] == pytest.approx(0.05)  # the back-off at the approach speed
    assert np.allclose(arm.targets[3][0][:3, :3], arm.targets[2][0][:3, :3])


def test_a_guarded_close_on_nothing_says_where_it_closed(gripper_port, fingers):
    fingers.size_m = None
    ex, arm = make_executor(gripper_port, close_on_contact_within_m=0.01)
    short_approach(arm, 0.004)
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.NO_OBJECT, outcome.message
    assert ge.GraspExecutor.CLOSED_SHORT in outcome.message and outcome.message.endswith("backed out to the pre-grasp")


@pytest.mark.parametrize("left_m, by_contact", [(0.012, True), (0.004, False), (float("nan"), True)])
def test_a_guarded_approach_backs_out_when_too_short_or_not_by_contact(gripper_port, left_m, by_contact):
    """Farther short than the limit, stopped for another reason, or how far unknown: back
    out as without the guard."""
    ex, arm = make_executor(gripper_port, close_on_contact_within_m=0.01)
    short_approach(arm, left_m, by_contact)
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.UNREACHABLE and ex.armed, outcome.message
    assert outcome.message.endswith("; backed out to the pre-grasp"), outcome.message
    assert outcome.stopped_by_contact == by_contact
    assert [round(X[2, 3], 3) for X, _ in arm.targets] == [0.28, 0.13, 0.08, 0.13]
    assert gripper_port.emulator.width_m == pytest.approx(0.085)


def test_without_the_guard_a_short_contact_stop_backs_out(gripper_port):
    ex, arm = make_executor(gripper_port)  # close_on_contact_within_m 0: the default
    short_approach(arm, 0.001)
    assert ex.execute(grasp()).code == ge.ResultCode.UNREACHABLE
    assert [round(X[2, 3], 3) for X, _ in arm.targets] == [0.28, 0.13, 0.08, 0.13]


def test_a_fast_approach_slows_for_the_last_centimetre(gripper_port):
    """approach_fast_speed_mps: pre-grasp -> 1 cm short of the grasp at that speed, the
    last centimetre at the approach speed (as a real cell approaches)."""
    ex, arm = make_executor(gripper_port, approach_fast_speed_mps=0.15)
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.SUCCESS, outcome.message
    assert [round(X[2, 3], 3) for X, _ in arm.targets] == [0.28, 0.13, 0.09, 0.08, 0.23]
    assert [s for _, s in arm.targets[2:4]] == [pytest.approx(0.15), pytest.approx(0.05)]


@pytest.mark.parametrize("left_m, closes", [(0.001, True), (0.009, False)])
def test_a_stop_on_the_fast_part_of_the_approach_counts_its_distance_to_the_grasp(gripper_port, left_m, closes):
    """Stopped `left_m` short of the fast part's end is left_m + 1 cm short of the grasp:
    the guard (15 mm) closes there only if that is within it."""
    ex, arm = make_executor(gripper_port, approach_fast_speed_mps=0.15, close_on_contact_within_m=0.015)
    original = arm.move_to

    def move_to(X, speed, timeout):
        if abs(X[2, 3] - 0.09) < 1e-6:
            arm.targets.append((X.copy(), speed))
            return ge.ArmMotion(False, CONTACT, True, left_m)
        return original(X, speed, timeout)
    arm.move_to = move_to
    outcome = ex.execute(grasp())
    if closes:
        assert outcome.code == ge.ResultCode.SUCCESS, outcome.message
        assert "closed 12.0 mm short of the grasp pose" in outcome.message, outcome.message
    else:
        assert outcome.code == ge.ResultCode.UNREACHABLE and outcome.stopped_by_contact, outcome.message
        assert [round(X[2, 3], 3) for X, _ in arm.targets] == [0.28, 0.13, 0.09, 0.13]


def test_a_bad_guard_distance_is_refused_at_start(gripper_port):
    for bad in (-0.001, float("nan")):
        with pytest.raises(ValueError, match="close_on_contact_within_m"):
            make_executor(gripper_port, close_on_contact_within_m=bad)
        with pytest.raises(ValueError, match="approach_fast_speed_mps"):
            make_executor(gripper_port, approach_fast_speed_mps=bad)


def test_a_contact_stop_is_the_arms_flag_not_its_words():
    """An arm that answers (arrived, message) reports no contact stop, whatever the message
    says; only the flag set where the stop is detected counts."""
    motion = ge.arm_motion((False, CONTACT))
    assert (motion.arrived, motion.stopped_by_contact) == (False, False) and np.isnan(motion.distance_left_m)
    assert ge.arm_motion((True, "reached")).stopped_by_contact is False
    flagged = ge.ArmMotion(False, "halted", stopped_by_contact=True, distance_left_m=0.02)
    assert ge.arm_motion(flagged) is flagged


@pytest.mark.parametrize("flagged", [True, False], ids=["flag", "words only"])
def test_only_the_flag_makes_a_stop_on_the_way_to_the_pregrasp_a_contact_stop(gripper_port, flagged):
    """A contact stop on the way to the pre-grasp disarms (the hand touched something
    unexpected); the same words without the flag are an ordinary unreachable pose."""
    ex, arm = make_executor(gripper_port)
    original = arm.move_to

    def move_to(X, speed, timeout):
        if round(X[2, 3], 3) == 0.13 and not arm.targets[1:]:  # the pre-grasp, coming from above
            arm.targets.append((X.copy(), speed))
            return ge.ArmMotion(False, CONTACT, stopped_by_contact=True) if flagged else (False, CONTACT)
        return original(X, speed, timeout)
    arm.move_to = move_to
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.UNREACHABLE, outcome.message
    assert outcome.message.startswith(f"arm could not reach the pregrasp pose: {CONTACT}"), outcome.message
    assert ("touched something" in outcome.message) == flagged, outcome.message
    assert ex.armed != flagged and outcome.stopped_by_contact == flagged


def test_a_lift_stopped_by_contact_opens_and_backs_out(gripper_port):
    ex, arm = make_executor(gripper_port)
    stopping_arm(arm, is_lift)
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.UNREACHABLE
    assert outcome.message.startswith("arm could not reach the lift pose: stopped by contact"), outcome.message
    assert outcome.message.endswith("; opened and backed out to the pre-grasp"), outcome.message
    assert outcome.stopped_by_contact
    assert [round(X[2, 3], 3) for X, _ in arm.targets] == [0.28, 0.13, 0.08, 0.23, 0.13]
    assert gripper_port.emulator.width_m == pytest.approx(0.085) and ex.armed


def test_a_hand_that_cannot_back_out_disarms(gripper_port):
    ex, arm = make_executor(gripper_port)
    stopping_arm(arm, lambda X: abs(X[2, 3] - 0.13) < 1e-6 and len(arm.targets) > 2 or is_grasp(X))
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.UNREACHABLE and not ex.armed
    assert "; backing out failed: arm could not reach the pre-grasp (backing out) pose: stopped by contact" in outcome.message
    assert outcome.message.endswith("disarmed: check the hand, then arm again"), outcome.message
    assert outcome.stopped_by_contact
    assert ex.execute(grasp()).code == ge.ResultCode.NOT_ARMED


def test_a_move_to_the_pregrasp_stopped_by_contact_disarms(gripper_port):
    """Only the poses were checked, not the way from wherever the arm was: a contact
    there is unexpected, with no known path back, so the executor stops and disarms."""
    ex, arm = make_executor(gripper_port)
    stopping_arm(arm, lambda X: abs(X[2, 3] - 0.13) < 1e-6 and len(arm.targets) == 1)
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.UNREACHABLE and not ex.armed
    assert outcome.message.startswith(f"arm could not reach the pregrasp pose: {CONTACT}"), outcome.message
    assert outcome.message.endswith("disarmed: check the cell, then arm again"), outcome.message
    assert [round(X[2, 3], 3) for X, _ in arm.targets] == [0.28, 0.13]  # no further motion
    assert ex.execute(grasp()).code == ge.ResultCode.NOT_ARMED


def test_a_pregrasp_the_arm_refuses_leaves_the_executor_armed(gripper_port):
    """No contact (e.g. outside the arm's reach): nothing touched, nothing to look at."""
    ex, arm = make_executor(gripper_port)
    original = arm.move_to
    arm.move_to = lambda X, speed, timeout: ((False, "outside the arm's reach") if abs(X[2, 3] - 0.13) < 1e-6
                                            else original(X, speed, timeout))
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.UNREACHABLE and ex.armed, outcome.message
    assert not outcome.stopped_by_contact


def test_a_miss_that_cannot_back_out_disarms(gripper_port, fingers):
    """Closed on nothing, then the way back is blocked: the hand may be stuck in the
    scene, so the executor disarms, as after a stopped approach that cannot back out."""
    fingers.size_m = None
    ex, arm = make_executor(gripper_port)
    stopping_arm(arm, lambda X: abs(X[2, 3] - 0.13) < 1e-6 and len(arm.targets) > 2)
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.UNREACHABLE and not ex.armed
    assert outcome.message.startswith("the grasp missed the object: "), outcome.message
    assert "; backing out failed: arm could not reach the pre-grasp (backing out) pose: stopped by contact" in outcome.message
    assert gripper_port.emulator.width_m == pytest.approx(0.085)  # opened before it tried


def test_object_that_shifts_in_the_hand_during_the_lift_is_held(gripper_port, fingers):
    """The fingers move on while the object re-seats (gOBJ 0) and stop on it again:
    judged once they are still, that is a held object, not a drop."""
    ex, arm = make_executor(gripper_port)
    original = arm.move_to

    def shift_on_lift(X, speed, timeout):
        if is_lift(X):  # the object slides 5 mm deeper between the fingers
            fingers.size_m = 0.045
            gripper_port.emulator.advance()
        return original(X, speed, timeout)

    arm.move_to = shift_on_lift
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.SUCCESS, outcome.message
    assert "opening 45.0 mm" in outcome.message


def test_refusals_say_why_and_do_not_move(gripper_port):
    ex, arm = make_executor(gripper_port, armed=False)
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.NOT_ARMED and "~/arm" in outcome.message
    ex.arm_motion(True)
    assert ex.execute(grasp(x=0.9)).code == ge.ResultCode.UNREACHABLE       # outside the box
    upward = ex.execute(grasp(q=[0, 0, 0, 1.0]))                           # approach pointing up
    assert upward.code == ge.ResultCode.UNREACHABLE and "cone" in upward.message
    assert arm.targets == []


def test_pose_out_of_the_arms_reach_is_unreachable(gripper_port):
    X_task_base = np.eye(4)
    X_task_base[:3, 3] = [0.15, -1.6, 0.0]  # arm mounted far away
    ex, arm = make_executor(gripper_port, reach=ArmReachability(X_task_base))
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.UNREACHABLE and "inverse-kinematics" in outcome.message
    assert arm.targets == []


def test_hand_colliding_with_the_tsdf_is_in_collision(gripper_port):
    ex, arm = make_executor(gripper_port)
    voxel = 0.0075
    grid = np.zeros((40, 40, 40), np.float32)
    # A 3 cm thick slab behind a surface, 1.5..4.5 cm to the side of the grasp axis:
    # where the right finger is, not between the fingers.
    i0, i1 = int(0.135 / voxel), int(0.165 / voxel)
    grid[i0:i1, int(0.195 / voxel):int(0.225 / voxel), int(0.04 / voxel):int(0.12 / voxel)] = 0.3
    outcome = ex.execute(grasp(), tsdf=(grid, voxel, np.zeros(3)))
    assert outcome.code == ge.ResultCode.IN_COLLISION and "left distal link" in outcome.message, outcome.message
    # The same slab between the fingers (where the object belongs) is no collision.
    between = np.zeros_like(grid)
    between[i0:i1, int(0.14 / voxel):int(0.16 / voxel), int(0.04 / voxel):int(0.09 / voxel)] = 0.3
    assert ex.execute(grasp(), tsdf=(between, voxel, np.zeros(3))).code == ge.ResultCode.SUCCESS


def test_another_hand_opens_to_its_width_and_is_checked_with_its_own_boxes(gripper_port, fingers):
    """ExecutionLimits.hand: a narrower hand (60 mm, fingers 80..100 mm off the axis: a
    made-up one, the sim bridge passes the Panda's) opens to its width, is checked with its
    boxes and names its parts; the 2F-85's linkage model of the table check is refused."""
    toy = hand_clearance.HandGeometry("toy", 0.06, ("palm", "left finger", "right finger"), np.array([
        [[-0.03, -0.1, -0.1], [0.03, 0.1, -0.05]],
        [[-0.01, 0.08, -0.05], [0.01, 0.1, 0.05]],
        [[-0.01, -0.1, -0.05], [0.01, -0.08, 0.05]]]))
    ex, arm = make_executor(gripper_port, hand=toy)
    voxel = 0.0075
    grid = np.zeros((40, 40, 40), np.float32)
    i0, i1 = int(0.135 / voxel), int(0.165 / voxel)
    # where the 2F-85's left distal link is (the test above), between the toy's fingers
    grid[i0:i1, int(0.195 / voxel):int(0.225 / voxel), int(0.04 / voxel):int(0.12 / voxel)] = 0.3
    assert ex.execute(grasp(), tsdf=(grid, voxel, np.zeros(3))).code == ge.ResultCode.SUCCESS
    outside = np.zeros_like(grid)
    outside[i0:i1, int(0.0525 / voxel):int(0.0675 / voxel), int(0.04 / voxel):int(0.12 / voxel)] = 0.3
    hit = ex.execute(grasp(), tsdf=(outside, voxel, np.zeros(3)))
    assert hit.code == ge.ResultCode.IN_COLLISION and "finger:" in hit.message, hit.message
    fingers.size_m = None
    assert ex.execute(grasp()).code == ge.ResultCode.NO_OBJECT
    assert gripper_port.emulator.width_m == pytest.approx(0.06, abs=1e-3)  # opened to the toy's width
    with pytest.raises(ValueError, match="models the 2F-85's linkage"):
        make_executor(gripper_port, hand=toy, table_z_m=0.05)
    with pytest.raises(ValueError, match="one \\(lo, hi\\) box per part"):
        hand_clearance.HandGeometry("bad", 0.06, ("palm",), np.zeros((2, 2, 3)))


def test_closing_fingertips_below_the_table_are_refused(gripper_port):
    """The labels' check at execution: closing swings the pad tips up to 18 mm past the
    TCP, less the wider the object between the pads (seen in the TSDF) stops them."""
    ex, arm = make_executor(gripper_port, table_z_m=0.05)
    voxel = 0.0075
    table = np.zeros((40, 40, 40), np.float32)
    table[:, :, :int(0.05 / voxel) + 1] = 0.3  # the table top: occupied, stops no finger

    def with_object(width_m):
        grid = table.copy()
        j0, j1 = round((0.15 - width_m / 2) / voxel), round((0.15 + width_m / 2) / voxel)
        grid[18:22, j0:j1, int(0.05 / voxel):int(0.09 / voxel)] = 0.3
        return grid, voxel, np.zeros(3)

    low = grasp(z=0.062)  # TCP 12 mm above the table
    narrow = ex.execute(low, tsdf=with_object(0.015))
    assert narrow.code == ge.ResultCode.IN_COLLISION and "into the table" in narrow.message, narrow.message
    assert "table_z_m" in narrow.message and arm.targets == []
    # nothing seen between the pads: they may close fully, the deepest case
    assert ex.execute(low, tsdf=None).code == ge.ResultCode.IN_COLLISION
    # an object that stops the pads 7 cm apart keeps their tips 3 mm above the table
    assert ex.execute(low, tsdf=with_object(0.08)).code == ge.ResultCode.SUCCESS
    # higher up, the narrow object is fine too
    assert ex.execute(grasp(z=0.075), tsdf=with_object(0.015)).code == ge.ResultCode.SUCCESS
    with pytest.raises(ValueError, match="table_z_m nan"):
        make_executor(gripper_port, table_z_m=float("nan"))


def test_second_concurrent_call_is_busy_at_once(gripper_port):
    ex, arm = make_executor(gripper_port)
    arm.gate = threading.Event()
    first = {}
    thread = threading.Thread(target=lambda: first.setdefault("outcome", ex.execute(grasp())))
    thread.start()
    while not arm.targets:
        threading.Event().wait(0.01)
    second = ex.execute(grasp())
    assert second.code == ge.ResultCode.BUSY
    arm.gate.set()
    thread.join(10)
    assert first["outcome"].code == ge.ResultCode.SUCCESS


def test_gripper_fault_mid_grasp_disarms(gripper_port):
    ex, arm = make_executor(gripper_port)
    original = arm.move_to

    def fault_at_grasp(X, speed, timeout):
        if is_grasp(X):
            gripper_port.emulator.inject_fault(0x0E)  # overcurrent, during the approach
        return original(X, speed, timeout)

    arm.move_to = fault_at_grasp
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.GRIPPER_FAULT and "overcurrent" in outcome.message
    assert not ex.armed


def test_emergency_stop_aborts_and_disarms(gripper_port):
    ex, arm = make_executor(gripper_port)
    original = arm.move_to

    def estop_during_pregrasp(X, speed, timeout):
        ex.estop()
        return original(X, speed, timeout)

    arm.move_to = estop_during_pregrasp
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.NOT_ARMED and "emergency stop" in outcome.message
    assert len(arm.targets) == 1 and not ex.armed
    assert ex.execute(grasp()).code == ge.ResultCode.NOT_ARMED
    # While the stop is active it is the answer, before the request's own faults.
    far = ex.execute(grasp(x=5.0))
    assert far.code == ge.ResultCode.NOT_ARMED and "emergency stop is active" in far.message
    ex.arm_motion(True)  # released (arming clears the stop) ...
    ex.arm_motion(False)  # ... then disarmed: the pose check answers first again
    assert ex.execute(grasp(x=5.0)).code == ge.ResultCode.UNREACHABLE


# -- the fault matrix (README): each fault gives a typed result within its timeout, and the
#    executor runs the next grasp once re-armed.

def test_gripper_silent_during_the_close_is_a_fault_then_recovers(gripper_port):
    ex, arm = make_executor(gripper_port)
    emulator = gripper_port.emulator
    original = arm.move_to

    def silence_once_closing(X, speed, timeout):
        result = original(X, speed, timeout)
        if is_grasp(X):  # at the grasp pose: the cable dies once the close was sent
            def watch():
                while emulator.command.position != 255 or not emulator.command.go:
                    time.sleep(0.001)
                gripper_port.respond = False
            threading.Thread(target=watch, daemon=True).start()
        return result

    arm.move_to = silence_once_closing
    t0 = time.monotonic()
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.GRIPPER_FAULT and "closing failed" in outcome.message, outcome.message
    assert time.monotonic() - t0 < ex.limits.gripper_timeout_s + 2.0
    assert not ex.armed and ex.gripper is None
    gripper_port.respond = True
    arm.move_to = original
    ex.arm_motion(True)
    assert ex.execute(grasp()).code == ge.ResultCode.SUCCESS


def test_a_close_that_never_finishes_is_a_timeout_that_leaves_the_hand_where_it_is(gripper_port, fingers):
    """TIMEOUT disarms without backing out: the fingers' state is unknown (they may be
    caught on the object), so no motion follows until a person has looked and re-armed."""
    ex, arm = make_executor(gripper_port, gripper_timeout_s=1.5)
    original = arm.move_to

    def jam_at_grasp(X, speed, timeout):
        result = original(X, speed, timeout)
        fingers.frozen = is_grasp(X)
        return result

    arm.move_to = jam_at_grasp
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.TIMEOUT and "closing did not finish" in outcome.message, outcome.message
    assert not ex.armed
    assert is_grasp(arm.targets[-1][0])  # no back out, no lift: the hand stayed at the grasp
    moves = len(arm.targets)
    assert ex.execute(grasp()).code == ge.ResultCode.NOT_ARMED
    assert len(arm.targets) == moves
    fingers.frozen = False
    arm.move_to = original
    ex.arm_motion(True)
    assert ex.execute(grasp()).code == ge.ResultCode.SUCCESS


def test_gripper_silent_during_the_lift_is_a_fault_then_recovers(gripper_port):
    ex, arm = make_executor(gripper_port)
    original = arm.move_to

    def silence_on_lift(X, speed, timeout):
        if is_lift(X):
            gripper_port.respond = False
        return original(X, speed, timeout)

    arm.move_to = silence_on_lift
    t0 = time.monotonic()
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.GRIPPER_FAULT and "stopped answering" in outcome.message, outcome.message
    assert time.monotonic() - t0 < ex.limits.gripper_timeout_s + 2.0
    assert not ex.armed
    gripper_port.respond = True
    arm.move_to = original
    ex.arm_motion(True)
    # Reconnected, recalibrated (opening first lets the lifted block go), then a new grasp.
    again = ex.execute(grasp())
    assert again.code == ge.ResultCode.SUCCESS, again.message
    assert ex.calibration.width_m == pytest.approx(0.0, abs=0.4e-3)


def test_emergency_stop_during_the_approach_then_rearm_recovers(gripper_port):
    ex, arm = make_executor(gripper_port)
    original = arm.move_to

    def estop_during_approach(X, speed, timeout):
        if is_grasp(X):
            ex.estop()
        return original(X, speed, timeout)

    arm.move_to = estop_during_approach
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.NOT_ARMED and "emergency stop during the move to grasp" in outcome.message
    assert is_grasp(arm.targets[-1][0]) and not ex.armed
    arm.move_to = original
    ex.arm_motion(True)
    assert ex.execute(grasp()).code == ge.ResultCode.SUCCESS


def test_disarmed_before_closing_says_close_the_gripper(gripper_port):
    ex, arm = make_executor(gripper_port)
    original = arm.move_to

    def disarm_at_grasp(X, speed, timeout):
        result = original(X, speed, timeout)
        if is_grasp(X):
            ex.arm_motion(False)
        return result

    arm.move_to = disarm_at_grasp
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.NOT_ARMED
    assert "refusing to close the gripper" in outcome.message, outcome.message


def test_arm_timeout_is_timeout_and_a_refusal_is_unreachable(gripper_port):
    """The result code comes from what the arm raised or returned, not from its words."""
    ex, arm = make_executor(gripper_port)

    def times_out(X, speed, timeout):
        raise ge.ArmTimeout("no answer within 30 s")

    arm.move_to = times_out
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.TIMEOUT and "no answer within 30 s" in outcome.message
    ex.arm_motion(True)
    arm.move_to = lambda X, speed, timeout: (False, "motion timed out: the target is out of reach")
    outcome = ex.execute(grasp())
    assert outcome.code == ge.ResultCode.UNREACHABLE, outcome.message


def test_first_feasible_runs_the_best_grasp_the_checks_pass_and_says_which(gripper_port):
    ex, arm = make_executor(gripper_port)
    voxel = 0.0075
    grid = np.zeros((40, 40, 40), np.float32)
    # The slab of the collision test beside grasp(): the first candidate is outside the
    # workspace, the second meets the slab, the third (5 cm along x) clears it and runs, the
    # fourth is never tried.
    grid[int(0.135 / voxel):int(0.165 / voxel), int(0.195 / voxel):int(0.225 / voxel),
         int(0.04 / voxel):int(0.12 / voxel)] = 0.3
    candidates = [(grasp(x=0.9), 0.0), (grasp(), 0.0), (grasp(x=0.20), 0.0), (grasp(x=0.25), 0.0)]
    outcome, index = ex.execute_first_feasible(candidates, tsdf=(grid, voxel, np.zeros(3)))
    assert (outcome.code, index) == (ge.ResultCode.SUCCESS, 2), outcome.message
    assert all(abs(X[0, 3] - 0.20) < 1e-6 for X, _ in arm.targets)  # only the third grasp moved the arm


def test_first_feasible_stops_at_a_failure_after_motion(gripper_port, fingers):
    ex, arm = make_executor(gripper_port)
    fingers.size_m = None  # nothing at any grasp: the close finds no object
    outcome, index = ex.execute_first_feasible([(grasp(), 0.0), (grasp(x=0.20), 0.0)])
    assert (outcome.code, index) == (ge.ResultCode.NO_OBJECT, 0), outcome.message
    assert not any(abs(X[0, 3] - 0.20) < 1e-6 for X, _ in arm.targets)


def test_first_feasible_with_every_grasp_refused_says_so_and_does_not_move(gripper_port):
    ex, arm = make_executor(gripper_port)
    outcome, index = ex.execute_first_feasible([(grasp(x=0.9), 0.0), (grasp(q=[0, 0, 0, 1.0]), 0.0)])
    assert (outcome.code, index) == (ge.ResultCode.UNREACHABLE, 1)
    assert outcome.message.startswith("all 2 grasps refused before any motion; the last:") and "cone" in outcome.message
    assert arm.targets == []
