"""The UR arm adapter's failure paths (gravgrasp_detector/doc/arm-adapter.md lists them,
one row each) against tests/support/fake_rtde.py, which answers each call as ur_rtde
1.6.5 does in each robot and safety state: the robot's state named before any question
about the pose, recovery from a cleared stop without ~/reconnect, the RTDE watchdog on a
lost link, and the latched emergency stop."""
import functools
import threading
import time

import numpy as np
import pytest

from fake_rtde import FakeControl, FakeURController
from gravgrasp_detector.execution.ur_arm import ConnectionLost, TCPMismatch
from gravgrasp_detector.execution.ur_controller import ur_pose_to_matrix
from gravgrasp_detector.execution.ur_kinematics import flange_in_base
from test_ur_arm import _wait, make_arm, tcp


@pytest.mark.parametrize("state, words", [
    (dict(safety_mode=3, program_running=False), "PROTECTIVE_STOP: protective stop: find what the arm hit"),
    (dict(safety_mode=7, robot_mode=3, program_running=False), "ROBOT_EMERGENCY_STOP: robot emergency stop: make the cell safe"),
    (dict(safety_mode=5), "SAFEGUARD_STOP: safeguard stop"),
    (dict(safety_mode=4, program_running=False), "RECOVERY: safety RECOVERY mode: the arm is beyond a safety limit"),
    (dict(safety_mode=8, program_running=False), "VIOLATION: safety VIOLATION"),
    (dict(safety_mode=9, program_running=False), "FAULT: safety FAULT"),
    (dict(robot_mode=5), "robot mode is IDLE, not RUNNING: release the brakes"),
    (dict(speed_slider=0.0), "speed slider on the teach pendant is at 0 %"),
])
def test_the_robots_state_is_named_before_any_question_about_the_pose(state, words):
    arm, ur = make_arm()
    arm.connect()
    for name, value in state.items():
        setattr(ur, name, value)
    asked = 0
    if ur.safety_mode in (3, 7):  # what the old order answered: the safety question is false, whatever the pose
        assert FakeControl(ur).isPoseWithinSafetyLimits([0.4, 0.0, 0.3, 3.14, 0.0, 0.0]) is False
        asked = 1
    for check_only in (False, True):
        result = arm.move(tcp(0.15, 0.15, 0.20), check_only=check_only)
        assert not result.reachable and not result.success, result
        assert words in result.message and result.message.endswith("nothing moved"), result.message
    assert len(ur.called("isPoseWithinSafetyLimits")) == asked and ur.called("moveL") == []
    assert "beyond its safety limits" not in result.message


def test_protective_stop_cleared_on_the_pendant_restores_control_by_itself():
    lines = []
    arm, ur = make_arm(log=lines.append)
    ur.protective_stop_after_s = 0.1
    hit = arm.move(tcp(0.15, 0.15, 0.30), 0.2)
    assert not hit.success and hit.message.startswith("PROTECTIVE_STOP during the motion"), hit.message
    assert "unlock it on the teach pendant" in hit.message
    assert not ur.program_running, "the stand-in's control script ended with the stop"
    ur.protective_stop_after_s = None
    refused = arm.move(tcp(0.15, 0.15, 0.30), 0.5)
    assert "protective stop: find what the arm hit" in refused.message, refused.message
    ur.clear_protective_stop()
    assert arm.keep_connected() is None  # the node's periodic call: no request needed
    restored = [line for line in lines if line.startswith("control restored")]
    assert restored == ["control restored after a PROTECTIVE_STOP: the RTDE control script had ended; "
                        "re-uploaded it and set the TCP again"], lines
    assert ur.program_running and len(ur.called("reuploadScript")) == 1
    assert len(ur.called("setTcp")) == 4, "the TCP lives in the script: set again (connect, check, moveL, restore)"
    assert ur.controller_tcp == [0.0, 0.0, 0.1558, 0.0, 0.0, 0.0]
    again = arm.move(tcp(0.15, 0.15, 0.30), 0.5)
    assert again.success, again.message
    assert ur.connects == 1, "no reconnect was needed, nor a call to ~/reconnect"


def test_a_stop_between_two_calls_of_the_poll_is_a_stop_not_a_lost_link(monkeypatch):
    """The script may end (a protective stop) after the poll's isProgramRunning and before
    its getTCPOffset, which no script then answers: still a stop, with its own message."""
    arm, ur = make_arm()
    arm.connect()
    real = FakeControl.getTCPOffset

    @functools.wraps(real)
    def stop_mid_motion(control):
        if ur._motion is not None:  # the stand-in's own protective stop, due now
            ur.protective_stop_after_s = 0.0
            ur._update()
        return real(control)

    monkeypatch.setattr(FakeControl, "getTCPOffset", stop_mid_motion)
    hit = arm.move(tcp(0.15, 0.15, 0.30), 0.2)
    assert not hit.success and hit.message.startswith("PROTECTIVE_STOP during the motion"), hit.message
    assert arm.connected


def test_a_stop_just_before_isprogramrunning_is_that_stop_not_a_pendant_stop(monkeypatch):
    """The poll read NORMAL, then an emergency stop ended the script before isProgramRunning."""
    arm, ur = make_arm()
    arm.connect()
    real = FakeControl.isProgramRunning

    @functools.wraps(real)
    def stop_mid_motion(control):
        if ur._motion is not None:
            ur.emergency_stop_after_s = 0.0
            ur._update()
        return real(control)

    monkeypatch.setattr(FakeControl, "isProgramRunning", stop_mid_motion)
    hit = arm.move(tcp(0.15, 0.15, 0.30), 0.2)
    assert hit.message.startswith("ROBOT_EMERGENCY_STOP during the motion"), hit.message


def test_emergency_stop_released_restores_control_at_the_next_request():
    lines = []
    arm, ur = make_arm(log=lines.append)
    ur.emergency_stop_after_s = 0.1
    hit = arm.move(tcp(0.15, 0.15, 0.30), 0.2)
    assert hit.message.startswith("ROBOT_EMERGENCY_STOP during the motion"), hit.message
    ur.emergency_stop_after_s = None
    ur.safety_mode, ur.robot_mode = 1, 7  # released, reset, powered on, brakes released on the pendant
    again = arm.move(tcp(0.15, 0.15, 0.30), 0.5)
    assert again.success, again.message
    assert [line for line in lines if line.startswith("control restored after a ROBOT_EMERGENCY_STOP")], lines


def test_program_stopped_on_the_pendant_is_latched_until_armed():
    """Path 5: the operator's Stop on the pendant ends the control script with the robot
    RUNNING and NORMAL. Neither the next request nor the recovery timer may restart it and
    move: latched like the emergency stop until ~/arm."""
    lines = []
    arm, ur = make_arm(log=lines.append)
    arm.connect()
    ur.press_stop_on_pendant()
    result = arm.move(tcp(0.15, 0.15, 0.25), 0.5)
    assert not result.success and "the program stopped on the teach pendant" in result.message, result.message
    assert "is latched" in result.message and ur.called("moveL") == []
    assert arm.keep_connected() is None and arm.watch() is None
    assert ur.called("reuploadScript") == [] and not ur.program_running, "the recovery timer restarted the script"
    assert arm.arm(True).startswith("armed: motion allowed (cleared: the program stopped on the teach pendant")
    again = arm.move(tcp(0.15, 0.15, 0.25), 0.5)
    assert again.success, again.message
    assert [line for line in lines if line.startswith("control restored after ~/arm after the latch")], lines


def test_program_stopped_on_the_pendant_mid_motion_is_named_at_once():
    arm, ur = make_arm()
    arm.connect()
    ur.on_call["getAsyncOperationProgress"] = lambda: ur._motion and time.monotonic() - ur._motion["t0"] > 0.1 \
        and ur.press_stop_on_pendant()
    t0 = time.monotonic()
    result = arm.move(tcp(0.15, 0.15, 0.40), 0.1)  # 2 s unless stopped
    assert not result.success and "the program stopped on the teach pendant" in result.message, result.message
    assert "during the motion" in result.message and time.monotonic() - t0 < 1.0
    assert arm.latched


def test_program_that_cannot_restart_is_refused_with_what_to_do():
    arm, ur = make_arm(connect_timeout_s=0.3)
    arm.connect()
    ur.press_stop_on_pendant()
    assert "is latched" in arm.move(tcp(0.15, 0.15, 0.25), 0.5).message
    arm.arm(True)  # a person armed it again, then switched the pendant to Local
    ur.control_unavailable = True  # the pendant switched to Local mode: the re-uploaded script is not run
    result = arm.move(tcp(0.15, 0.15, 0.25), 0.5)
    assert not result.reachable and "could not be restarted" in result.message, result.message
    assert "enable remote control" in result.message and ur.called("moveL") == []
    assert arm.receiving and not arm.connected, "watching only, until Remote Control is back"


def test_watchdog_is_set_before_every_motion_and_kicked_while_it_runs():
    arm, ur = make_arm()
    assert arm.move(tcp(0.15, 0.15, 0.30), 0.2).success  # ~0.5 s
    names = [n for n, _ in ur.calls]
    assert ur.called("setWatchdog") == [(2.0,)], "1 / watchdog_period_s (0.5 s)"
    assert names.index("setWatchdog") < names.index("moveL")
    kicks = names.count("kickWatchdog")
    print(f"{kicks} kicks during a 0.5 s motion")
    assert kicks >= 5
    time.sleep(0.5)  # between motions the kicks go on: the script must not be stopped while idle
    assert ur.program_running and not ur.watchdog_tripped
    assert arm.move(tcp(0.15, 0.15, 0.20), 0.5).success
    assert len(ur.called("setWatchdog")) == 2


def test_link_lost_mid_motion_the_watchdog_stops_the_arm():
    arm, ur = make_arm()
    arm.connect()
    ur.lose_link_after_s = 0.2
    start = np.array(ur.tcp_pose[:3])
    t0 = time.monotonic()
    with pytest.raises(ConnectionLost, match="watchdog stops the arm within 0.5 s"):
        arm.move(tcp(0.15, 0.15, 0.50), 0.1)  # 224 mm at 0.1 m/s: 2.2 s if nothing stops it
    assert time.monotonic() - t0 < 2.0
    assert _wait(lambda: not ur.motion_running, 1.0), "the controller went on moving"
    travelled_m = float(np.linalg.norm(np.array(ur.tcp_pose[:3]) - start))
    print(f"link lost after 0.2 s: the arm stopped after {travelled_m * 1000:.0f} mm of 224 mm")
    assert ur.watchdog_tripped and not ur.program_running
    assert travelled_m < 0.1 * (0.2 + 0.5 + 0.1), "stopped within the watchdog period (+ a poll)"
    ur.lose_link_after_s = None
    result = arm.move(tcp(0.15, 0.15, 0.30), 0.5)
    assert result.success, result.message  # fresh interfaces; their constructor uploads the script


def test_link_lost_before_a_motion_commands_nothing():
    arm, ur = make_arm()
    arm.connect()
    ur.link_up = False
    with pytest.raises(ConnectionLost, match="reports itself lost"):
        arm.move(tcp(0.15, 0.15, 0.25), 0.5)
    assert ur.called("moveL") == [] and ur.called("setWatchdog") == []


def test_emergency_stop_during_a_motion_latches_until_armed():
    arm, ur = make_arm()
    arm.connect()
    results = {}
    worker = threading.Thread(target=lambda: results.setdefault("r", arm.move(tcp(0.15, 0.15, 0.45), 0.05)))
    worker.start()
    assert _wait(lambda: ur._motion is not None, 2.0), "the motion did not start"
    assert arm.latch("the emergency stop (emergency_stop topic)") is True
    worker.join(3.0)
    assert "motion stopped by the emergency stop (emergency_stop topic)" in results["r"].message, results["r"].message
    assert ur.called("stopL") and not ur.motion_running
    moves = len(ur.called("moveL"))
    latched = arm.move(tcp(0.15, 0.15, 0.30), 0.5)
    assert not latched.success and "is latched: nothing moves until ~/arm" in latched.message, latched.message
    assert len(ur.called("moveL")) == moves, "a latched request commands nothing"
    assert arm.move(tcp(0.15, 0.15, 0.30), check_only=True).reachable, "asking without moving still answers"
    assert arm.arm(True).startswith("armed: motion allowed (cleared: the emergency stop")
    assert arm.move(tcp(0.15, 0.15, 0.30), 0.5).success


def test_disarm_latches_without_a_motion():
    arm, ur = make_arm()
    assert arm.arm(False).startswith("disarmed")
    assert "a disarm (~/arm false) is latched" in arm.move(tcp(0.15, 0.15, 0.30), 0.5).message
    assert ur.calls == [], "refused before connecting"
    arm.arm(True)
    assert arm.move(tcp(0.15, 0.15, 0.30), 0.5).success


def test_stopl_without_a_running_script_does_nothing_in_the_stand_in():
    """ur_rtde's void stopL goes through sendCommand: without the script nothing is sent.
    So the adapter cannot rely on stopL after a stop; the watchdog and the stop itself halt the arm."""
    ur = FakeURController()
    control, _ = ur.connect()
    assert control.moveL([0.4, 0.0, 0.1, 3.14, 0.0, 0.0], 0.05, 0.5, True)
    ur.program_running = False
    control.stopL(2.0)
    assert ur._motion is not None


def test_monitor_only_refuses_flange_poses_when_the_pendants_tcp_is_not_tcp_in_flange():
    """Pendant in Local mode: setTcp cannot be sent (and getTCPOffset, a control-interface
    call, cannot be read), so the controller's TCP is judged from the joint angles."""
    arm, ur = make_arm()
    ur.control_unavailable = True
    arm.connect()
    assert arm.monitor_only
    with pytest.raises(TCPMismatch) as refused:  # the pendant's default TCP: the flange itself
        arm.flange_in_base()
    message = str(refused.value)
    print(f"\n{message}")
    assert message.startswith("the controller's TCP differs from tcp_in_flange by 156 mm / 0.0 deg")
    assert "set the TCP on the pendant (Installation > General > TCP) to tcp_in_flange" in message
    assert "correct ur_arm.tcp_in_flange in the cell file" in message
    ur.controller_tcp = [0.0, 0.0, 0.1558, 0.0, 0.0, 1.5708]  # fingers turned 90 deg: refused too
    with pytest.raises(TCPMismatch, match="by 0 mm / 90.0 deg"):
        arm.flange_in_base()
    ur.controller_tcp = [0.0, 0.0, 0.1538, 0.0, 0.0, 0.0]  # 2 mm: within the nominal kinematics' error
    arm.flange_in_base()
    ur.controller_tcp = [0.0, 0.0, 0.1558, 0.0, 0.0, 0.0]  # set on the pendant: no restart needed
    X = arm.flange_in_base()
    np.testing.assert_allclose(X[:3, 3], [0.4, 0.0, 0.4 + 0.1558], atol=1e-9)


def test_monitor_only_judges_the_tcp_by_the_ur5e_kinematics_of_getActualQ():
    arm, ur = make_arm()
    ur.control_unavailable = True
    ur.controller_tcp = [0.0, 0.0, 0.1558, 0.0, 0.0, 0.0]
    ur.tcp_pose = [0.35, 0.2, 0.3, 2.0, 1.0, 0.5]
    arm.connect()
    arm.flange_in_base()
    assert len(ur.called("getActualQ")) == 1
    q = ur.joint_angles()  # the fake's angles: FK(q) @ controller TCP is the TCP it reports
    np.testing.assert_allclose(flange_in_base(q) @ ur_pose_to_matrix(ur.controller_tcp),
                               ur_pose_to_matrix(ur.tcp_pose), atol=1e-7)
    ur.joint_angles = lambda: [v + 0.02 for v in q]  # angles that put the flange elsewhere: refused
    with pytest.raises(TCPMismatch):
        arm.flange_in_base()


def test_with_control_the_tcp_is_set_not_judged():
    arm, ur = make_arm()
    arm.connect()
    X = arm.flange_in_base()
    assert ur.called("setTcp") and ur.called("getActualQ") == []
    np.testing.assert_allclose(X[:3, 3], [0.4, 0.0, 0.4 + 0.1558], atol=1e-9)
