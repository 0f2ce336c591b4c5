"""The UR arm adapter's logic (gravgrasp_detector.execution.ur_arm) against a recording stand-in
of ur_rtde's interfaces (tests/support/fake_rtde.py): frames, the protective box, speed
limits, refusals before motion, stop, timeouts, a lost link and the reconnect. The
failure paths (stops, watchdog, latch): test_ur_arm_failures.py."""
import functools
import math
import threading
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fake_rtde import FakeControl, FakeURController
from gravgrasp_detector.execution.ur_arm import ConnectionLost, URArm
from gravgrasp_detector.execution.ur_arm_settings import URArmSettings, xyz_yaw_to_matrix
from gravgrasp_detector.execution.ur_controller import matrix_to_ur_pose, pose_error

DOWN = Rotation.from_euler("x", 180, degrees=True).as_matrix()  # TCP z pointing down


def tcp(x, y, z, R=DOWN):
    X = np.eye(4)
    X[:3, :3] = R
    X[:3, 3] = (x, y, z)
    return X


def make_arm(ur=None, log=None, **overrides):
    ur = ur or FakeURController()
    # The executor's default base: 0.45 m in front of the workspace, turned 90 deg.
    # Timeouts generous enough for a loaded 2-core machine; the hang tests shorten them. The
    # RTDE watchdog at its production period (0.5 s).
    settings = dict(X_task_base=xyz_yaw_to_matrix([0.15, -0.45, 0.0, math.pi / 2]), call_timeout_s=1.5,
                    connect_timeout_s=3.0, motion_timeout_margin_s=0.5, max_speed_mps=0.5, default_speed_mps=0.2)
    settings.update(overrides)
    arm = URArm(ur.connect, URArmSettings(**settings), log=log)
    # Start the fake TCP where the first target of most tests is, in the base frame.
    return arm, ur


def test_frames_tcp_and_the_pose_moveL_receives():
    arm, ur = make_arm()
    status = arm.connect()
    assert "RUNNING" in status and "NORMAL" in status, status
    assert ur.called("setTcp") == [([0.0, 0.0, 0.1558, 0.0, 0.0, 0.0],)], "the 2F-85's TCP is set on connect"
    result = arm.move(tcp(0.15, 0.15, 0.20), speed_mps=0.3)
    assert result.success, result.message
    (pose, speed, accel, asynchronous), = ur.called("moveL")
    # task (0.15, 0.15, 0.20) relative to the base at (0.15, -0.45, 0) is (0, 0.6, 0.2); the
    # base is turned +90 deg about z, so in the base frame that is (0.6, 0, 0.2).
    np.testing.assert_allclose(pose[:3], [0.6, 0.0, 0.2], atol=1e-12)
    R_base_tcp = Rotation.from_rotvec(pose[3:]).as_matrix()
    np.testing.assert_allclose(R_base_tcp, Rotation.from_euler("z", -90, degrees=True).as_matrix() @ DOWN, atol=1e-12)
    assert (speed, accel, asynchronous) == (0.3, 0.5, True)
    assert result.joint_positions == pytest.approx([0.1, -1.2, 1.5, -1.9, -1.57, 0.0])
    # The safety and IK questions were asked about the same base-frame pose, before moveL.
    names = [n for n, _ in ur.calls]
    assert names.index("isPoseWithinSafetyLimits") < names.index("moveL")
    assert ur.called("isPoseWithinSafetyLimits")[0][0] == pose
    print(f"task (0.15, 0.15, 0.20) -> base {np.round(pose[:3], 4).tolist()}; {result.message}")


def test_outside_the_box_is_refused_before_talking_to_the_robot():
    arm, ur = make_arm()
    result = arm.move(tcp(0.15, 0.15, -0.02))
    assert not result.reachable and not result.success
    assert "outside the protective box" in result.message and "20 mm along z" in result.message, result.message
    assert ur.calls == [], "a refused target must not even connect"


def test_speed_default_cap_and_bad_speed():
    arm, ur = make_arm()
    assert arm.move(tcp(0.15, 0.15, 0.20), speed_mps=0.0).success
    assert ur.called("moveL")[-1][1] == 0.2  # default
    capped = arm.move(tcp(0.15, 0.10, 0.20), speed_mps=3.0)
    assert capped.success and "capped to 0.5 m/s" in capped.message
    assert ur.called("moveL")[-1][1] == 0.5
    with pytest.raises(ValueError, match="must be >= 0"):
        arm.move(tcp(0.15, 0.10, 0.20), speed_mps=-1.0)


@pytest.mark.parametrize("fault, words", [
    (dict(safety_mode=3), "PROTECTIVE_STOP"),
    (dict(safety_mode=7), "ROBOT_EMERGENCY_STOP"),
    (dict(robot_mode=3), "POWER_OFF"),
    (dict(speed_slider=0.0), "speed slider"),
    (dict(within_safety_limits=False), "safety limits"),
    (dict(has_ik=False), "inverse-kinematics"),
])
def test_refusals_before_any_motion(fault, words):
    arm, ur = make_arm()
    for name, value in fault.items():
        setattr(ur, name, value)
    result = arm.move(tcp(0.15, 0.15, 0.20))
    assert not result.success and not result.reachable
    assert words in result.message and "nothing moved" in result.message, result.message
    assert ur.called("moveL") == []


def test_check_only_answers_without_moving():
    arm, ur = make_arm()
    result = arm.move(tcp(0.15, 0.15, 0.20), check_only=True)
    assert result.reachable and not result.success and len(result.joint_positions) == 6
    assert ur.called("moveL") == []


def test_stop_halts_a_running_motion_and_a_second_request_is_refused():
    arm, ur = make_arm()
    arm.connect()
    results = {}
    worker = threading.Thread(target=lambda: results.setdefault("r", arm.move(tcp(0.15, 0.15, 0.40), 0.05)))
    worker.start()  # 0.3 m at 0.05 m/s: 6 s unless stopped
    assert _wait(lambda: ur._motion is not None, 2.0), "the motion did not start"
    busy = arm.move(tcp(0.15, 0.15, 0.30), 0.05)
    assert not busy.success and "another motion" in busy.message
    t0 = time.monotonic()
    assert arm.stop() is True
    worker.join(3.0)
    result = results["r"]
    print(f"stopped after {time.monotonic() - t0:.3f} s: {result.message}")
    assert not result.success and "stopped by stop_motion" in result.message
    assert ur.called("stopL"), "stopL was not sent"
    assert arm.stop() is False, "no motion runs any more"
    assert arm.move(tcp(0.15, 0.15, 0.25), 0.5).success, "the arm moves again after a stop"


def test_motion_that_never_ends_is_stopped_at_its_deadline():
    arm, ur = make_arm()
    ur.never_finish = True
    t0 = time.monotonic()
    result = arm.move(tcp(0.15, 0.15, 0.25), 0.5)  # 0.15 m: 0.3 s + 0.5/0.5 s ramp + 0.5 s margin
    elapsed = time.monotonic() - t0
    assert not result.success and "did not end within 2.0 s" in result.message, result.message
    assert ur.called("stopL")
    assert elapsed < 3.0


def test_protective_stop_during_the_motion():
    arm, ur = make_arm()
    ur.protective_stop_after_s = 0.1
    result = arm.move(tcp(0.15, 0.15, 0.25), 0.2)
    assert not result.success and "PROTECTIVE_STOP during the motion" in result.message, result.message


def test_contact_stops_a_motion_by_the_force_gained_since_it_began():
    arm, ur = make_arm()
    ur.tcp_force = [3.0, -2.0, 10.0, 0.0, 0.0, 0.0]  # a bias (payload slightly off): stops nothing
    assert arm.move(tcp(0.15, 0.15, 0.25), 0.5).success
    ur.contact_after_s, ur.contact_force = 0.1, [0.0, 0.0, 80.0, 0.0, 0.0, 0.0]
    t0 = time.monotonic()
    result = arm.move(tcp(0.15, 0.15, 0.45), 0.2)  # 0.2 m at 0.2 m/s: ~1 s unless stopped
    assert result.reachable and not result.success
    # the sim stand-in's words, which the benchmark's report counts as a jam
    assert result.message.startswith("stopped by contact") and "rose from 11 to 90 N" in result.message, result.message
    assert "60 N limit" in result.message and ur.called("stopL")
    assert time.monotonic() - t0 < 0.8
    # how far short, in data too: the executor's guarded approach reads it
    assert result.stopped_by_contact and 0.0 < result.distance_left_m < 0.2, result
    # Still pressing with 90 N, past the limit: backing off is not stopped by that press.
    ur.contact_after_s = None
    back = arm.move(tcp(0.15, 0.15, 0.25), 0.5)
    assert back.success, back.message
    assert not back.stopped_by_contact and back.distance_left_m < 1e-3, back


def test_contact_stop_off_reads_no_force():
    arm, ur = make_arm(contact_force_limit_n=0.0)
    ur.contact_after_s, ur.contact_force = 0.05, [0.0, 0.0, 200.0, 0.0, 0.0, 0.0]
    assert arm.move(tcp(0.15, 0.15, 0.25), 0.5).success
    assert ur.called("getActualTCPForce") == []


def test_ending_off_target_is_not_success():
    arm, ur = make_arm()
    ur.arrive_offset_m = 0.005
    result = arm.move(tcp(0.15, 0.15, 0.25), 0.5)
    assert not result.success and "5.0 mm" in result.message, result.message


def test_lost_link_mid_motion_raises_then_reconnects():
    arm, ur = make_arm()
    arm.connect()
    ur.lose_link_after_s = 0.05
    with pytest.raises(ConnectionLost, match="lost during a motion"):
        arm.move(tcp(0.15, 0.15, 0.40), 0.1)
    assert not arm.connected
    ur.lose_link_after_s = None
    result = arm.move(tcp(0.15, 0.15, 0.40), 0.5)  # fresh interfaces, TCP set again
    assert result.success, result.message
    assert ur.connects == 2 and len(ur.called("setTcp")) == 6, "at each connect, check and moveL"


def test_a_link_lost_under_any_call_of_a_motion_gives_the_same_message(monkeypatch):
    """The link may go down between the loop's isConnected and its next command: that command
    then raises (ur_rtde's reconnect fails) and the message must still say what happened."""
    arm, ur = make_arm()
    arm.connect()
    real = FakeControl.getTCPOffset

    @functools.wraps(real)
    def down_mid_motion(control):
        if ur._motion is not None:  # the read-back before moveL passes; the one in the loop meets the loss
            ur._set_link(False)
        return real(control)

    monkeypatch.setattr(FakeControl, "getTCPOffset", down_mid_motion)
    with pytest.raises(ConnectionLost, match=r"lost during a motion \(getTCPOffset failed: RuntimeError: .*"
                       r"Robot is disconnected.*\): the controller's watchdog stops the arm within 0.5 s"):
        arm.move(tcp(0.15, 0.15, 0.40), 0.1)
    assert not arm.connected


def test_a_call_that_never_answers_is_a_lost_link_not_a_hang():
    arm, ur = make_arm()
    arm.connect()
    arm.settings.call_timeout_s = 0.3
    ur.hang.add("getActualTCPPose")
    t0 = time.monotonic()
    try:
        with pytest.raises(ConnectionLost, match="no answer .* within 0.3 s while getActualTCPPose"):
            arm.move(tcp(0.15, 0.15, 0.25), 0.5)
        elapsed = time.monotonic() - t0
        print(f"hung getActualTCPPose -> ConnectionLost after {elapsed:.2f} s")
        assert elapsed < 1.5
        assert not arm.connected
    finally:
        ur.release()


def test_unreachable_or_silent_controller_at_connect():
    arm, ur = make_arm()
    ur.refuse_connect = True
    with pytest.raises(ConnectionLost, match="Could not connect"):
        arm.connect()
    result_error = None
    try:
        arm.move(tcp(0.15, 0.15, 0.25))
    except ConnectionLost as e:
        result_error = str(e)
    assert result_error and "verify the IP" in result_error
    ur.refuse_connect = False
    arm.settings.connect_timeout_s = 0.5
    ur.hang.add("connect")
    t0 = time.monotonic()
    try:
        with pytest.raises(ConnectionLost, match="within 0.5 s while connecting"):
            arm.connect()
        assert time.monotonic() - t0 < 1.5
    finally:
        ur.release()


def test_local_mode_watches_the_arm_but_never_moves_it():
    arm, ur = make_arm()
    ur.control_unavailable = True
    ur.controller_tcp = [0.0, 0.0, 0.1558, 0.0, 0.0, 0.0]  # the pendant's TCP is the 2F-85's
    status = arm.connect()
    assert "monitoring only" in status and "enable remote control" in status, status
    assert arm.receiving and not arm.connected
    X = arm.flange_in_task()  # the fake TCP (0.4, 0, 0.4) in the base, pointing down
    np.testing.assert_allclose(X[:3, 3], [0.15, -0.05, 0.4 + 0.1558], atol=1e-9)
    with pytest.raises(ConnectionLost, match="switch the pendant to Remote Control"):
        arm.move(tcp(0.15, 0.15, 0.25))
    assert ur.called("moveL") == [] and ur.called("setTcp") == []
    receive = arm._receive
    assert "monitoring only" in arm.keep_connected() and arm._receive is receive, "a retry keeps the receive link"
    ur.control_unavailable = False
    assert "RUNNING" in arm.keep_connected() and arm.connected


def test_keep_connected_reconnects_only_when_down():
    arm, ur = make_arm()
    assert "RUNNING" in arm.keep_connected()
    assert arm.keep_connected() is None and ur.connects == 1


def test_bad_settings_are_named():
    with pytest.raises(ValueError, match="workspace_min_m"):
        URArmSettings(workspace_min_m=(0, 0, 0.5), workspace_max_m=(1, 1, 0.2)).check()
    with pytest.raises(ValueError, match="default_speed_mps"):
        URArmSettings(default_speed_mps=1.0, max_speed_mps=0.25).check()
    with pytest.raises(ValueError, match="contact_force_limit_n"):
        URArmSettings(contact_force_limit_n=-1.0).check()
    with pytest.raises(ValueError, match="base pose"):
        xyz_yaw_to_matrix([0, 0, 0])


def test_tcp_constant_matches_the_hand_geometry():
    from robotiq_driver.hand_geometry import FLANGE_TO_TCP_M
    assert URArmSettings().tcp_in_flange[2] == FLANGE_TO_TCP_M


def test_pose_helpers_round_trip():
    X = tcp(0.1, -0.2, 0.3, Rotation.from_euler("xyz", [170, 10, 45], degrees=True).as_matrix())
    dp, da = pose_error(matrix_to_ur_pose(X), matrix_to_ur_pose(X))
    assert dp == 0 and da < 1e-6


def _wait(predicate, timeout_s):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.01)
    return predicate()
