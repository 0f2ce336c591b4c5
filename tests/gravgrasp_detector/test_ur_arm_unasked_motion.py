"""No motion nobody asked for, no success that did not happen: the UR adapter against
ur_rtde's own reconnects (tests/support/fake_rtde.py follows them: the script restarted
with the pendant's TCP and payload, the command sent again), stale requests, the
emergency-stop race and the watchdog at its production period under load.
gravgrasp_detector/doc/arm-adapter.md has a row for each."""
import threading
import time

import numpy as np
import pytest

from fake_rtde import TCP_2F85
from gravgrasp_detector.execution.ur_arm import ConnectionLost
from gravgrasp_detector.execution.ur_controller import pose_error
from test_ur_arm import _wait, make_arm, tcp


def _reached(ur, target_pose) -> float:
    """Where the 2F-85's pinch point is, from the target (m), whatever the controller's TCP."""
    return pose_error(ur.tcp_pose_in(TCP_2F85), target_pose)[0]


# -- path 1: the TCP lapses when ur_rtde reconnects by itself ------------------------------

def test_tcp_and_payload_are_set_again_before_every_moveL():
    arm, ur = make_arm(payload_kg=0.925, payload_cog_m=(0.0, 0.0, 0.06))
    assert arm.move(tcp(0.15, 0.15, 0.25), 0.5).success
    ur.drop_link(0.05)  # a socket error; ur_rtde reconnects by itself and restarts its script
    assert _wait(lambda: ur.reconnects == 1 and ur.link_up, 2.0)
    assert ur.controller_tcp == [0.0] * 6 and ur.payload[0] == 0.0, "the restarted script has the pendant's"
    result = arm.move(tcp(0.15, 0.10, 0.25), 0.5)
    assert result.success, result.message
    assert ur.motions[-1]["tcp"] == list(TCP_2F85), "moveL ran with the pendant's TCP"
    assert ur.payload == (0.925, [0.0, 0.0, 0.06]), "the payload was not restored"
    assert _reached(ur, arm.to_base(tcp(0.15, 0.10, 0.25))) < 1e-6


def test_a_move_resent_with_the_pendants_tcp_is_stopped_and_latched():
    """ur_rtde reconnects inside moveL (its sendCommand: reconnect, then send the move
    again): the move runs with the pendant's TCP (the flange), so the fingers would go
    156 mm past the target. The TCP read back during the motion says so."""
    arm, ur = make_arm()
    arm.connect()
    fired = []
    ur.on_call["moveL"] = lambda: fired or (fired.append(1), ur._reconnect())
    target = tcp(0.15, 0.15, 0.30)
    result = arm.move(target, 0.5)
    print(f"\n{result.message}")
    assert not result.success and result.message.startswith("ur_rtde reconnected by itself during the motion"), \
        result.message
    assert "ran with the pendant's TCP" in result.message and not ur.motion_running
    assert arm.latched and "is latched" in arm.move(tcp(0.15, 0.15, 0.25), 0.5).message


def test_a_tcp_lapse_the_polls_missed_is_not_a_success():
    """The backstop: a motion over before the first poll. At its end the flange from the
    joint angles (nominal FK) and the TCP pose disagree by the 156 mm the TCP lapsed."""
    arm, ur = make_arm()
    arm.connect()
    ur.time_scale = 1e-4  # every motion is over within 10 ms, before the first 20 ms poll
    fired = []
    ur.on_call["moveL"] = lambda: fired or (fired.append(1), ur._reconnect())
    target = tcp(0.15, 0.15, 0.30)
    result = arm.move(target, 0.5)
    print(f"\n{result.message}")
    assert not result.success and "156 mm" in result.message and "ur_rtde restarted its control script" in result.message
    assert pose_error(ur.tcp_pose, arm.to_base(target))[0] < 1e-6, "the controller's TCP did reach the target"
    assert _reached(ur, arm.to_base(target)) > 0.15
    assert arm.latched


# -- path 2: a move ur_rtde sends again after the link came back ---------------------------

def _lose_link_inside_moveL(ur, down_s):
    fired = []
    ur.reconnect_wait_s = 5.0  # ur_rtde's reconnect waits for the network inside the moveL call
    ur.on_call["moveL"] = lambda: fired or (fired.append(1), ur.drop_link(down_s))


def test_a_lost_link_inside_moveL_disconnects_and_a_resent_move_is_halted_on_reconnect():
    arm, ur = make_arm()
    arm.connect()
    _lose_link_inside_moveL(ur, 2.0)
    with pytest.raises(ConnectionLost, match="while moveL"):
        arm.move(tcp(0.15, 0.15, 0.45), 0.1)
    assert "disconnect" in [n for n, _ in ur.calls], "the given-up interface was not disconnected"
    # ur_rtde's moveL is still waiting; the network comes back at 2 s, the move is sent again
    assert _wait(lambda: len(ur.motions) == 1, 4.0), "the stand-in did not send the move again"
    t_resent = time.monotonic()
    assert _wait(lambda: arm.keep_connected() is not None or arm.connected, 3.0)  # the node's timer
    assert _wait(lambda: not ur.motion_running, 1.0)
    travelled = ur.travelled_m(ur.motions[0])
    print(f"resent move halted {time.monotonic() - t_resent:.2f} s after it began, after {travelled * 1000:.0f} mm")
    assert travelled < 0.05
    assert ur.called("stopL"), "reconnecting halts whatever was sent again"


def test_a_move_resent_after_ur_arm_reconnected_is_stopped_and_latched():
    arm, ur = make_arm()
    arm.connect()
    ur.reconnect_takes_s = 0.6  # the given-up moveL's own reconnect finishes after ur_arm's
    _lose_link_inside_moveL(ur, 2.0)
    with pytest.raises(ConnectionLost):
        arm.move(tcp(0.15, 0.15, 0.45), 0.1)
    lines = []
    deadline = time.monotonic() + 6.0
    while time.monotonic() < deadline and not arm.latched:  # the node: reconnect, then watch at its state rate
        try:
            arm.keep_connected()
        except ConnectionLost:
            pass
        line = arm.watch()
        if line:
            lines.append(line)
        time.sleep(0.03)
    assert ur.motions and ur.motions[-1]["by"] is not arm._control, "no move was sent again by the old interface"
    print(f"\n{lines}")
    assert arm.latched == "a motion no request asked for", lines
    assert lines and "while no request ran" in lines[0]
    assert _wait(lambda: not ur.motion_running, 0.5)
    travelled = ur.travelled_m(ur.motions[-1])
    assert travelled < 0.02, f"the stale move went {travelled * 1000:.0f} mm"


# -- path 3: a request its caller gave up on ------------------------------------------------

def test_a_request_past_its_deadline_is_refused_and_a_late_motion_stopped():
    arm, ur = make_arm()
    arm.connect()
    late = arm.move(tcp(0.15, 0.15, 0.25), 0.5, deadline=time.monotonic() - 0.01)
    assert not late.reachable and "deadline passed" in late.message and ur.called("moveL") == [], late.message
    t0 = time.monotonic()
    cut = arm.move(tcp(0.15, 0.15, 0.45), 0.1, deadline=time.monotonic() + 0.5)  # 2 s of motion
    assert not cut.success and "stopped at the request's deadline" in cut.message, cut.message
    assert time.monotonic() - t0 < 1.0 and not ur.motion_running


def test_a_request_waiting_for_a_reconnect_is_refused_at_its_deadline():
    arm, ur = make_arm()
    arm.connect()
    with arm._motion_lock:  # a reconnect holds it (keep_connected)
        t0 = time.monotonic()
        result = arm.move(tcp(0.15, 0.15, 0.25), 0.5, deadline=time.monotonic() + 0.3)
    assert not result.reachable and "deadline passed while a reconnect" in result.message, result.message
    assert time.monotonic() - t0 < 1.0 and ur.called("moveL") == []


# -- path 4: the emergency stop against the send -------------------------------------------

def test_a_latch_just_before_moveL_sends_no_moveL():
    arm, ur = make_arm()
    arm.connect()
    ur.on_call["setWatchdog"] = lambda: arm.latch("the emergency stop (emergency_stop topic)")
    result = arm.move(tcp(0.15, 0.15, 0.30), 0.1)
    assert not result.success and "stopped before the motion started" in result.message, result.message
    assert ur.called("moveL") == [] and ur.motions == []


def test_a_latch_while_moveL_is_sent_stops_after_it():
    arm, ur = make_arm()
    arm.connect()
    ur.delay["moveL"] = 0.3
    results = {}
    worker = threading.Thread(target=lambda: results.setdefault("r", arm.move(tcp(0.15, 0.15, 0.45), 0.1)))
    worker.start()
    assert _wait(lambda: ur.called("moveL"), 2.0)
    arm.latch("the emergency stop (emergency_stop topic)")
    worker.join(3.0)
    names = [n for n, _ in ur.calls]
    assert names.index("stopL", names.index("moveL")) and "stopL" not in names[names.index("setWatchdog"):names.index("moveL")], \
        "stopL ran before the moveL it was meant to stop"
    assert not ur.motion_running
    travelled = ur.travelled_m(ur.motions[0])
    assert travelled < 0.002, f"moved {travelled * 1000:.1f} mm after the latch"
    assert "stopped by the emergency stop" in results["r"].message, results["r"].message


# -- path 7: the watchdog at its production period ------------------------------------------

def _busy(stop):
    x = 0
    while not stop.is_set():  # pure Python: holds the GIL between switches, as tsdf/detect would
        x = (x * 31 + 7) % 1000003


def test_watchdog_at_its_production_period_holds_under_load_and_logs_the_largest_gap():
    lines = []
    arm, ur = make_arm(log=lines.append)
    assert arm.settings.watchdog_period_s == 0.5
    stop = threading.Event()
    hogs = [threading.Thread(target=_busy, args=(stop,), daemon=True) for _ in range(2)]
    for hog in hogs:
        hog.start()
    try:
        for z in (0.35, 0.15, 0.35):
            result = arm.move(tcp(0.15, 0.15, z), 0.2)  # ~1 s each
            assert result.success, result.message
    finally:
        stop.set()
    gaps = [line for line in lines if line.startswith("motion: largest watchdog kick gap")]
    print(f"\n{gaps}")
    assert len(gaps) == 3 and not ur.watchdog_tripped
    assert all(int(line.split("gap ")[1].split(" ms")[0]) < 500 for line in gaps)


def test_a_watchdog_stop_is_named_at_once_not_after_the_deadline():
    arm, ur = make_arm()
    arm.connect()
    ur.delay["kickWatchdog"] = 0.6  # every kick reaches the controller after the 0.5 s period
    t0 = time.monotonic()
    result = arm.move(tcp(0.15, 0.15, 0.45), 0.1)  # 2 s of motion, +0.5 s margin
    elapsed = time.monotonic() - t0
    print(f"\n{elapsed:.2f} s: {result.message}")
    assert ur.watchdog_tripped
    assert not result.success and result.message.startswith("the RTDE watchdog stopped the motion"), result.message
    assert elapsed < 1.5 and not arm.latched
    ur.delay.clear()
    assert arm.move(tcp(0.15, 0.15, 0.30), 0.5).success, "the script is restarted after a watchdog stop"


def test_a_kick_goes_ahead_of_calls_waiting_for_the_rtde_thread():
    from gravgrasp_detector.execution.ur_controller import CallThread
    calls, order, gate = CallThread(), [], threading.Event()
    first = calls.submit(gate.wait, 2.0)  # a call in flight (moveL waiting for the script)
    waiting = [calls.submit(order.append, f"call {i}") for i in range(3)]
    kick = calls.submit(order.append, "kick", urgent=True)
    gate.set()
    for future in (first, kick, *waiting):
        future.result(2.0)
    calls.close()
    assert order == ["kick", "call 0", "call 1", "call 2"], order


# -- path 6: the protective box holds the hand, along the whole line ------------------------

def _tilted(x, y, z, deg):
    """TCP at (x, y, z), approach tilted `deg` about the task x axis from straight down."""
    from scipy.spatial.transform import Rotation
    return tcp(x, y, z, Rotation.from_euler("x", 180 + deg, degrees=True).as_matrix())


def test_the_box_holds_the_flange_and_the_fingers_not_only_the_tcp():
    arm, ur = make_arm()  # box [-0.1, -0.1, 0]..[0.4, 0.4, 0.8]
    high = arm.move(tcp(0.15, 0.15, 0.70), 0.5)  # the TCP inside, the flange at 0.856 m
    assert not high.reachable and "its flange at (0.150, 0.150, 0.856) m is 56 mm outside along z" in high.message, \
        high.message
    edge = arm.move(tcp(0.39, 0.15, 0.30), 0.5)  # the TCP 10 mm inside; the hand is 156 mm wide across x
    assert not edge.reachable and "housing corner at (0.427" in edge.message and "along x" in edge.message, edge.message
    assert ur.calls == [], "refused before connecting"


def test_the_box_holds_the_hand_along_the_straight_line_and_at_the_start():
    arm, ur = make_arm()
    arm.connect()
    ur.tcp_pose = arm.to_base(_tilted(0.15, 0.15, 0.67, -60))  # the hand's top at 0.785 m: inside
    target = _tilted(0.15, 0.15, 0.67, 60)  # inside too, but halfway the hand points down: flange at 0.826 m
    assert arm._box_refusal(target) is None
    result = arm.move(target, 0.2)
    print(f"\n{result.message}")
    assert not result.reachable and "% along the path: its" in result.message, result.message  # the first pose out
    assert "outside along z" in result.message
    ur.tcp_pose = arm.to_base(tcp(0.15, 0.15, 0.70))  # parked with the flange above the box
    parked = arm.move(tcp(0.15, 0.15, 0.30), 0.2)
    assert not parked.reachable and "at the start" in parked.message and "jog the arm into the box" in parked.message, \
        parked.message
    assert ur.called("moveL") == []


# -- path 9: the stand-in follows ur_rtde where these paths depend on it ---------------------

def test_the_stand_in_serves_cached_state_reconnects_resends_and_resets_the_tcp_like_ur_rtde():
    from fake_rtde import FakeURController
    ur = FakeURController()
    control, receive = ur.connect()
    assert control.setTcp(list(TCP_2F85)) and control.setPayload(0.9, [0.0, 0.0, 0.05])
    pose = receive.getActualTCPPose()
    ur.drop_link(0.3)
    assert not control.isConnected() and not receive.isConnected()
    assert receive.getActualTCPPose() == pose and control.isProgramRunning() is True, "cached state, no exception"
    ur.reconnect_wait_s = 1.0
    target = list(np.add(pose, [0.0, 0.0, -0.05, 0.0, 0.0, 0.0]))
    assert control.moveL(target, 0.1, 0.5, True), "sent again after ur_rtde's own reconnect"
    assert ur.reconnects == 1 and control.isConnected()
    assert ur.motions[-1]["tcp"] == [0.0] * 6 and ur.payload == (0.0, [0.0, 0.0, 0.0]), "the script restarted"
    assert control.getAsyncOperationProgress() >= 0
    ur.press_stop_on_pendant()  # the script ends mid-move: nothing writes the register
    assert control.getAsyncOperationProgress() >= 0 and not ur.motion_running
    control.reuploadScript()  # the new script's reset_async_progress()
    assert control.getAsyncOperationProgress() < 0


def test_ur_rtde_reconnecting_mid_motion_is_named_at_once():
    """Found by the arm soak: a 0.3 s drop during a motion, a kick waiting through it, and
    ur_rtde's own reconnect restarts the script: the motion ends, the TCP is the pendant's,
    and the async register can read as before the motion. Named at once, not after the
    motion's deadline; the next request sets the TCP before it reads the start pose."""
    arm, ur = make_arm(workspace_max_m=(0.40, 0.40, 0.62))  # the flange starts at 0.556 m
    arm.connect()
    ur.reconnect_wait_s = 1.0
    ur.on_call["getAsyncOperationProgress"] = lambda: ur._motion and time.monotonic() - ur._motion["t0"] > 0.2 \
        and ur.link_up and not ur.reconnects and ur.drop_link(0.3)
    t0 = time.monotonic()
    result = arm.move(tcp(0.15, 0.15, 0.20), 0.1)  # down from 0.40 m: 2 s of motion
    print(f"\n{time.monotonic() - t0:.2f} s: {result.message}")
    assert not result.success and result.message.startswith("ur_rtde reconnected by itself during the motion"), \
        result.message
    assert time.monotonic() - t0 < 1.5 and not ur.motion_running and not arm.latched
    ur.on_call.clear()
    # read in the pendant's TCP (the flange), the start would put the hand's top 156 mm higher: out of the box
    again = arm.move(tcp(0.15, 0.15, 0.30), 0.5)
    assert again.success, again.message


def test_a_tcp_that_changes_while_idle_is_not_a_motion():
    """Found by the arm soak: the TCP pose jumps 156 mm when ur_rtde restarts its script
    (the pendant's TCP) with the arm standing still; the idle guard watches the flange."""
    arm, ur = make_arm()
    assert arm.move(tcp(0.15, 0.15, 0.30), 0.5).success
    assert arm.watch() is None  # takes the pose where the request left the arm
    ur.drop_link(0.05)
    assert _wait(lambda: ur.reconnects == 1 and ur.link_up, 2.0)
    assert ur.controller_tcp == [0.0] * 6
    assert arm.watch() is None and not arm.latched


def test_a_motion_ended_by_ur_rtdes_restart_is_not_called_a_tcp_lapse():
    """Found by the arm soak: the restart ends the motion short and resets the async
    register to a value that differs from before, so the loop sees an end; the TCP pose,
    now read in the pendant's TCP, is off the target. A restart, said so, not latched (no
    motion ran with the wrong TCP)."""
    arm, ur = make_arm()
    arm.connect()
    assert arm.move(tcp(0.15, 0.15, 0.30), 0.5).success  # the register: -1 after this one
    fired = []
    ur.on_call["getSafetyMode"] = lambda: (not fired and ur._motion and time.monotonic() - ur._motion["t0"] > 0.2
                                           and (fired.append(1), ur.drop_link(0.0)))
    result = arm.move(tcp(0.15, 0.15, 0.45), 0.1)
    print(f"\n{result.message}")
    assert fired and not result.success, result.message
    assert result.message.startswith("ur_rtde reconnected by itself during the motion"), result.message
    assert not arm.latched
