"""A Universal Robots arm moving the 2F-85's TCP along straight lines, over RTDE.

The logic behind `ros2 run gravgrasp_detector ur_arm` (ros/ur_arm_node.py), with no rclpy
and no ur_rtde import: `URArm` takes a `connect()` callable that returns a pair
(control, receive) with the methods of ur_rtde's `RTDEControlInterface` and
`RTDEReceiveInterface` (ur-rtde 1.6.5). The node passes the real ones; the tests pass
an object that records every call. Its settings are `ur_arm_settings.URArmSettings`;
the controller's mode codes, pose format and call thread are in `ur_controller`.

Frames (all 4x4 homogeneous transforms; UR poses are [x, y, z, rx, ry, rz], metres
and a rotation vector in radians, in the robot's base frame):

    X_task_tcp   the request: TCP in the gravity-aligned task frame (Grasp.msg's TCP)
    X_task_base  where the robot's base frame sits in the task frame (a parameter)
    X_base_tcp = inv(X_task_base) @ X_task_tcp   what moveL gets
    tcp_in_flange  the TCP in the tool flange frame, set on the controller with setTcp
                   when connecting and before every motion (2F-85: 0.1558 m out along
                   the flange z)

What happens to a request, in order; nothing moves until every check passed. The
robot's state comes before any question about the pose: ur_rtde answers
isPoseWithinSafetyLimits false whenever its command cannot reach the control script
(protective stop, emergency stop, script stopped), which would name the wrong cause.

    0. a motion while a latch is set (emergency stop, disarm, the pendant's
       Stop, a motion nobody asked for, a motion with the wrong TCP)   refused (until arm(True))
    1. the TCP target inside the protective box, and the hand there too
       (the TCP, the flange, the open 2F-85's hull corners)            refused otherwise
    2. speed: 0 means the default; above max_speed_mps it is capped
    3. connected (else one reconnect attempt); a request still waiting
       for a reconnect when its deadline passes                         ConnectionLost / refused
    4. safety mode normal or reduced (protective stop, emergency
       stop, safeguard stop, recovery, violation, fault named with
       what to do)                                                      refused otherwise
    5. robot mode RUNNING (powered, brakes released)                   refused otherwise
    6. the RTDE control script runs; if it ended after a protective or
       emergency stop (cleared on the pendant), the watchdog or ~/arm,
       it is re-uploaded, the TCP set again, one line logged; if it ended
       with no such cause (the pendant's Stop, another program) the
       adapter latches until arm(True)                                  refused otherwise
    7. speed slider above 1 %                                          refused otherwise
    8. setTcp, setPayload, getTCPOffset read back; then the hand at the
       start pose and along the straight line to the target stays in
       the box                                                          refused otherwise
    9. the controller says the pose is within its safety limits and
       has an inverse-kinematics solution                              refused otherwise
   10. the TCP and payload set and read back again, setWatchdog(1 / watchdog_period_s);
       then, under one lock with stop() and latch(): the stop, the latch and the request's
       deadline checked, moveL (asynchronous) sent. Poll: stop, latch -> stopL; the
       deadline -> stopL; protective stop, lost link -> fail; the script not running
       (the watchdog, named by the kick gap, or the pendant's Stop, latched) -> fail at
       once; the controller's TCP no longer tcp_in_flange (ur_rtde reconnected by itself
       and restarted its script) -> stopL, fail, and latch if a motion still ran (the move
       it sent again, with the pendant's TCP); contact: the TCP force's magnitude risen by
       more than contact_force_limit_n since the motion began -> stopL and fail, "stopped
       by contact" (the sim stand-in's rule and words); no end within the expected time
       (+ margin, scaled by the speed slider) -> stopL and fail. At the end the actual TCP
       must be within tolerance of the target, and the flange from the joint angles
       (nominal FK) must agree with it (else the TCP lapsed: latched).

Between requests (watch(), at the node's state rate): a flange (from the joint angles)
that moves more than idle_motion_limit_m is a motion nobody asked for: stopL and latch.

After a lost link: the dropped interfaces are disconnect()ed (ur_rtde would otherwise
reconnect them by itself and send again what they were sending); the fresh connection's
first command is stopL; ur_arm never resumes a motion by itself.

Fail-safe: once a watchdog is set, this connection's kick loop sends kickWatchdog every
poll_period_s, ahead of any call waiting for the connection's thread. A lost link (cable,
a hung process) stops the kicks, and the controller stops the control script, and with it
the arm, within watchdog_period_s (0.5 s: each kick needs two handoffs of Python's GIL and
waits behind the call in flight; a loaded 2-core machine showed gaps of 100-200 ms). Each
motion logs its largest kick gap. Nothing is kicked while the script does not run (a
refused kick ends the kicks until the next setWatchdog): ur_rtde would print an error for
every one.

Why the contact stop counts the rise, not the force: the reading has a bias (payload
settings, drift) and a motion may start under load, e.g. a lift with the closed fingers
pressing the object on the table, which the lift relieves. A bias b raises the trip point
by at most 2|b| (a 60 N limit trips between 60 and 60 + 2|b| N of contact); the UR's own
force limit (pendant, Safety > Limits) stays the hard backstop.

Monitoring only: `connect(receive)` may return (None, receive, why) when the control
interface cannot be built (e.g. the pendant is in Local mode for jogging); then poses are
read (flange_pose, for calibration) and every motion request is answered with the robot's
state or raises ConnectionLost saying so. Retrying passes the live receive interface back
to `connect`, so flange_pose has no gaps while the control interface is retried.

The flange pose is the actual TCP pose (the controller's calibrated kinematics) times
inv(tcp_in_flange), which holds only while the controller's TCP is tcp_in_flange. With
control, setTcp makes it so. Monitoring only, setTcp cannot be sent and the TCP is the
pendant's; ur_rtde's getTCPOffset is a control-interface call, so it cannot be read either.
So each flange pose is checked first: the nominal UR5e kinematics of the joint angles
(getActualQ, ur_kinematics) give the flange, and inv(flange) @ actual TCP is the TCP the
controller uses. Off tcp_in_flange by more than tcp_check_tolerance_m / _deg, no pose is
given (TCPMismatch, saying what to set). The nominal kinematics only judge the TCP: they
can be millimetres off the robot's own calibration, which the controller's pose is not.

Never hang: every RTDE call runs on this connection's own thread and is waited on for
at most `call_timeout_s` (`connect_timeout_s` for connecting); no answer, an exception,
or isConnected() false raise `ConnectionLost` and drop the connection; the next request
(or `connect()`) builds fresh interfaces.
"""
from __future__ import annotations

import concurrent.futures
import dataclasses
import itertools
import math
import threading
import time
from typing import Callable

import numpy as np
from robotiq_driver.hand_geometry import HAND_PARTS, OPEN_HAND_BOXES_TCP
from scipy.spatial.transform import Rotation

from .ur_arm_settings import URArmSettings
from .ur_controller import (ROBOT_MODES, SAFETY_MODES, SAFETY_MODES_THAT_MOVE, CallThread, matrix_to_ur_pose,
                            pose_error, safety_action, state_refusal, ur_pose_to_matrix)
from .ur_kinematics import flange_in_base as nominal_flange_in_base


def _quietly(fn):
    try:
        fn()
    except Exception:  # best effort: the link is being dropped anyway
        pass


class URArmError(Exception):
    """Base of this module's errors."""


class ConnectionLost(URArmError):
    """The link to the controller failed: not reachable, no answer within the timeout,
    an RTDE call raised, or the interfaces report a lost connection. The connection is
    dropped; the next request or `connect()` builds fresh interfaces."""


class TCPMismatch(URArmError):
    """Monitoring only: the controller's TCP (the pendant's) is not tcp_in_flange, so the
    actual TCP pose does not give the flange; the message says what to set."""


@dataclasses.dataclass
class MoveResult:
    """MoveToPose's response fields."""
    reachable: bool
    success: bool
    message: str
    joint_positions: list = dataclasses.field(default_factory=list)
    stopped_by_contact: bool = False  # the contact force limit ended the motion
    distance_left_m: float = math.nan  # from where the TCP stopped to the target [m]; NaN: nothing moved


class URArm:
    """Moves a UR arm's TCP to task-frame poses along straight lines (moveL)."""

    def __init__(self, connect: Callable[[], tuple], settings: URArmSettings | None = None,
                 log: Callable[[str], None] | None = None, clock=time.monotonic):
        self.settings = settings or URArmSettings()
        self.settings.check()
        self._connect = connect
        self._log = log or (lambda text: None)
        self._clock = clock
        self._X_base_task = np.linalg.inv(np.asarray(self.settings.X_task_base, float))
        corners, names = [[0.0, 0.0, 0.0]], ["TCP"]
        corners.append(list(np.linalg.inv(ur_pose_to_matrix(self.settings.tcp_in_flange))[:3, 3]))
        names.append("flange")
        for part, (lo, hi) in zip(HAND_PARTS, OPEN_HAND_BOXES_TCP):
            if part == "wrist":  # the robot's wrist behind the flange, not the hand
                continue
            for corner in itertools.product(*zip(lo, hi)):
                corners.append(list(corner))
                names.append(f"{part} corner")
        self._hand_points_tcp = np.asarray(corners, float)
        self._hand_point_names = names
        self._control = self._receive = self._calls = None
        self._link_lock = threading.Lock()     # connect / drop
        self._motion_lock = threading.Lock()   # a request or a reconnect, one at a time
        self._request_lock = threading.Lock()
        self._request_active = False           # a second request is refused, not queued
        self._stop = threading.Event()
        self._moving = threading.Event()
        self.last_error = "not connected yet"
        self.monitor_only = ""   # why only the receive interface is connected ('' = both or none)
        self.latched = ""        # why motions are refused until arm(True) ('' = not latched)
        self._kicking = False    # a watchdog is set on the controller: the kick loop kicks it
        self._stop_cause = ""    # the last stop seen (safety mode), for the log line on recovery
        # moveL and the stop/latch flags change together: a stop either sees the motion sent
        # (and sends stopL after it) or the motion sees the stop (and sends nothing)
        self._send_lock = threading.Lock()
        self._kick_ok_t = None   # when the last kick was accepted (monotonic)
        self._kick_gap_s = 0.0   # the largest gap between accepted kicks since reset
        self._kick_refused_gap_s = 0.0  # the gap before the kick the controller refused
        self._idle_pose = None   # where the flange was when the last request ended (base frame)

    # -- connection -----------------------------------------------------------------

    @property
    def connected(self) -> bool:
        """Both interfaces up: the arm can be moved."""
        return self._control is not None

    @property
    def receiving(self) -> bool:
        """At least the receive interface is up (flange_pose can be published)."""
        return self._receive is not None

    @property
    def busy(self) -> bool:
        """A request (check or motion) or a reconnect is running."""
        return self._request_active or self._motion_lock.locked()

    def connect(self) -> str:
        """(Re)build the interfaces and set the TCP (and payload). Returns a status line;
        raises ConnectionLost saying why it failed."""
        with self._link_lock:
            # Watching only: keep the live receive interface, so flange_pose has no gap.
            keep = self._receive if self._control is None else None
            self._drop_locked("reconnecting", keep)
            calls = CallThread()
            try:
                got = self._wait(calls.submit(self._connect, keep), self.settings.connect_timeout_s,
                                 "connecting to the controller")
            except ConnectionLost:
                calls.close()
                raise
            control, receive = got[0], got[1]
            self._control, self._receive, self._calls = control, receive, calls
            self.monitor_only = "" if control is not None else (got[2] if len(got) > 2 else "no control interface")
        if control is None:  # watching only (pendant in Local mode): flange_pose, no motion
            status = self.status_line()
            self.last_error = f"monitoring only, the control interface is not connected ({self.monitor_only})"
            return f"{status}; {self.last_error}"
        threading.Thread(target=self._kick_loop, args=(calls, control), name="rtde-watchdog", daemon=True).start()
        try:
            # Before anything else: halt whatever ur_rtde may have sent again on a connection
            # ur_arm gave up (its reconnect resends the command it was sending). ur_arm never
            # resumes a motion by itself; a new request is a new motion.
            self._rpc(control.stopL, float(self.settings.stop_deceleration_mps2), False)
            self._configure(control)
            status = self.status_line()
            self._idle_pose = None
        except ConnectionLost as e:
            self.last_error = str(e)
            raise
        self.last_error = ""
        return status

    def _configure(self, control):
        """Set the TCP (and payload), and read the TCP back: at every connect, every start
        of the control script and before every moveL. set_tcp and set_payload last only as
        long as the script runs, and ur_rtde restarts the script by itself when it
        reconnects after a socket error, with no sign to its caller: the pendant's TCP
        (often the flange) and payload are back. Raises ConnectionLost."""
        tcp = [float(v) for v in self.settings.tcp_in_flange]
        if not self._rpc(control.setTcp, tcp):
            raise self._lost("the controller refused setTcp (is the RTDE control script running?)")
        if self.settings.payload_kg > 0:
            if not self._rpc(control.setPayload, float(self.settings.payload_kg),
                             [float(v) for v in self.settings.payload_cog_m]):
                raise self._lost("the controller refused setPayload")
        held = [float(v) for v in self._rpc(control.getTCPOffset)]
        if len(held) != 6 or max(abs(a - b) for a, b in zip(held, tcp)) > 1e-6:
            raise self._lost(f"the controller holds the TCP {np.round(held, 4).tolist()} right after setTcp "
                             f"{tcp}: its control script restarted in between")

    def keep_connected(self) -> str | None:
        """Reconnect if the link is down, or restart the control script once a stop that
        ended it is cleared, while no request runs (the node calls this periodically).
        Returns the status line after a reconnect, None otherwise (a restart logs itself);
        raises ConnectionLost if reconnecting failed."""
        if not self._motion_lock.acquire(blocking=False):
            return None
        try:
            if not self.connected:
                return self.connect()
            control, receive = self._control, self._receive
            if state_refusal(self._rpc(receive.getRobotMode), self._rpc(receive.getSafetyMode)) is None \
                    and not self._rpc(control.isProgramRunning) and not self._latch_unexplained_end():
                self._restore_control(control)  # logs its one line
            return None
        finally:
            self._motion_lock.release()

    def _latch_unexplained_end(self) -> bool:
        """The control script ended with the robot RUNNING and NORMAL. After a protective or
        emergency stop (seen, so a person cleared it on the pendant) or the watchdog (the
        kicks were late) ur_arm restarts it. Otherwise a person stopped the program on the
        pendant, or played another one: latched like the emergency stop until arm(True),
        so neither the next request nor the recovery timer moves the arm again. True if
        latched (now or before)."""
        if self.latched:
            return True
        if self._stop_cause:
            return False
        if self._kick_refused_gap_s >= 0.8 * self.settings.watchdog_period_s:
            self._stop_cause = (f"the RTDE watchdog (no kick reached the controller for {self._kick_refused_gap_s:.2f} s "
                                f"of {self.settings.watchdog_period_s:g} s)")
            return False
        self.latched = ("the program stopped on the teach pendant (its Stop, or another program played; the robot "
                        "is RUNNING with no safety stop)")
        self._log(f"{self.latched}: latched, nothing moves until ~/arm is called with data: true")
        return True

    def _restore_control(self, control):
        """Re-upload ur_rtde's control script (it ended with a protective or emergency stop,
        the watchdog, or a program started on the pendant), wait until it runs, set the TCP
        again, and say so in one line. Falls back to a full reconnect. Raises ConnectionLost."""
        after = f" after {self._stop_cause}" if self._stop_cause else ""
        self._kicking = False
        if self._rpc(control.reuploadScript):
            deadline = self._clock() + self.settings.connect_timeout_s
            while self._clock() < deadline:
                if self._rpc(control.isProgramRunning):
                    self._configure(control)
                    self._log(f"control restored{after}: the RTDE control script had ended; re-uploaded it "
                              "and set the TCP again")
                    self._stop_cause, self._kick_refused_gap_s = "", 0.0
                    return
                time.sleep(self.settings.poll_period_s)
        with self._link_lock:
            self._drop_locked("the control script did not restart")
        self.connect()  # ur_rtde's constructor uploads the script and waits for it
        if not self.connected:
            raise ConnectionLost(self.last_error)
        self._log(f"control restored{after}: the RTDE control script had ended and did not restart on "
                  "reuploadScript; reconnected")
        self._stop_cause, self._kick_refused_gap_s = "", 0.0

    def _kick_loop(self, calls, control):
        """This connection's watchdog kicks, one in flight at a time, never waited on: a
        hung link stops them, which is the point."""
        pending = None
        while self._calls is calls:
            time.sleep(self.settings.poll_period_s)
            if not self._kicking or (pending is not None and not pending.done()):
                continue
            if pending is not None and pending.exception() is None:
                now = self._clock()
                gap = now - self._kick_ok_t if self._kick_ok_t is not None else 0.0
                if pending.result() is False:
                    self._kicking = False  # the script does not run: nothing to kick until setWatchdog
                    self._kick_refused_gap_s = gap
                    pending = None
                    continue
                self._kick_gap_s = max(self._kick_gap_s, gap)
                self._kick_ok_t = now
            pending = calls.submit(control.kickWatchdog, urgent=True)

    def close(self):
        with self._link_lock:
            control, receive = self._control, self._receive
            self._drop_locked("closed")
        for interface in (control, receive):
            if interface is not None:
                try:  # best effort: a dead link must not block shutdown
                    done = threading.Event()
                    threading.Thread(target=lambda i=interface: (i.disconnect(), done.set()), daemon=True).start()
                    done.wait(self.settings.call_timeout_s)
                except Exception:
                    pass

    def _drop_locked(self, why: str, keep=None):
        if self._calls is not None:
            self._calls.close()
        # disconnect() what is dropped, so that ur_rtde's own reconnect does not bring it back
        # (and send again what it was sending); off this thread: it may hang like the link.
        for interface in (self._control, self._receive):
            if interface is not None and interface is not keep and hasattr(interface, "disconnect"):
                threading.Thread(target=_quietly, args=(interface.disconnect,), name="rtde-disconnect",
                                 daemon=True).start()
        self._control = self._receive = self._calls = None
        self._kicking = False
        self.monitor_only = ""
        self.last_error = why

    def _lost(self, why: str) -> ConnectionLost:
        with self._link_lock:
            self._drop_locked(why)
        return ConnectionLost(why)

    def _wait(self, future, timeout_s, what):
        try:
            return future.result(timeout_s)
        except concurrent.futures.TimeoutError:
            raise ConnectionLost(f"no answer from the controller within {timeout_s:g} s while {what}") from None
        except Exception as e:  # ur_rtde raises RuntimeError on socket errors
            raise ConnectionLost(f"{what} failed: {type(e).__name__}: {e}") from None

    def _connection(self):
        """The connection's call thread; ConnectionLost while not connected."""
        calls = self._calls  # read once: a drop on another thread may clear it
        if calls is None:
            raise ConnectionLost(f"not connected to the robot ({self.last_error})")
        return calls

    def _call(self, calls, method, *args):
        """One RTDE call on the connection's thread `calls`, waited on at most call_timeout_s;
        raises ConnectionLost and leaves the link to the caller."""
        return self._wait(calls.submit(method, *args), self.settings.call_timeout_s,
                          getattr(method, "__name__", "an RTDE call"))

    def _rpc(self, method, *args):
        """`_call`, the link dropped when it fails."""
        calls = self._connection()
        try:
            return self._call(calls, method, *args)
        except ConnectionLost as e:
            raise self._lost(str(e)) from None

    def _ensure_connected(self):
        """(control, receive); control is None while only watching. Raises ConnectionLost."""
        if self._control is None:
            self._log(f"not connected ({self.last_error}): connecting")
            self.connect()
        control, receive = self._control, self._receive
        links = [i for i in (control, receive) if i is not None]
        if not links or not all(self._rpc(i.isConnected) for i in links):
            raise self._lost("the RTDE connection reports itself lost (cable, controller restart, or another client)")
        return control, receive

    # -- state ----------------------------------------------------------------------

    def status_line(self) -> str:
        receive = self._receive
        if receive is None:
            raise ConnectionLost(f"not connected to the robot ({self.last_error})")
        robot = self._rpc(receive.getRobotMode)
        safety = self._rpc(receive.getSafetyMode)
        slider = self._rpc(receive.getTargetSpeedFraction)
        return (f"robot mode {ROBOT_MODES.get(robot, robot)}, safety {SAFETY_MODES.get(safety, safety)}, "
                f"speed slider {100 * slider:.0f} %")

    def _refusal_for_state(self, control, receive) -> str | None:
        """Why the robot cannot move now, said so a person at the pendant can fix it (checks
        4-7); restarts the control script when only that is missing. Raises ConnectionLost."""
        safety = self._rpc(receive.getSafetyMode)
        refusal = state_refusal(self._rpc(receive.getRobotMode), safety)
        if refusal:
            if safety not in SAFETY_MODES_THAT_MOVE:
                self._stop_cause = f"a {SAFETY_MODES.get(safety, safety)}"
            return refusal
        if control is None:
            raise ConnectionLost(f"the RTDE control interface is not connected ({self.monitor_only}): switch the "
                                 "pendant to Remote Control (ur_arm retries), until then it only watches the arm")
        if not self._rpc(control.isProgramRunning):
            if self._latch_unexplained_end():
                return f"{self.latched} is latched: nothing moves until ~/arm is called with data: true"
            try:
                self._restore_control(control)
            except ConnectionLost as e:
                return (f"the RTDE control script is not running and could not be restarted ({e}): stop any program "
                        "on the teach pendant and check that it is in Remote Control")
            control = self._control
        slider = self._rpc(receive.getTargetSpeedFraction)
        if slider < 0.01:
            return "the speed slider on the teach pendant is at 0 %: the arm would not move; raise it"
        return None

    # -- motion ---------------------------------------------------------------------

    def to_base(self, X_task_tcp) -> list:
        return matrix_to_ur_pose(self._X_base_task @ np.asarray(X_task_tcp, float))

    def _hand_points(self, X_task_tcp) -> np.ndarray:
        """(n, 3) task-frame points of the hand at a TCP pose: the TCP, the flange and the
        corners of the open 2F-85's housing and finger boxes (robotiq_driver.hand_geometry)."""
        X = np.asarray(X_task_tcp, float)
        return X[:3, :3] @ self._hand_points_tcp.T + X[:3, 3:4]

    def _box_refusal(self, X_task_tcp, start=None) -> str | None:
        """Why the hand would leave the protective box at the target, or (given the start
        TCP pose, task frame) anywhere along the straight line from it; None if it stays in."""
        lo, hi = np.asarray(self.settings.workspace_min_m), np.asarray(self.settings.workspace_max_m)
        p = np.asarray(X_task_tcp, float)[:3, 3]
        if not ((p >= lo) & (p <= hi)).all():
            axis = int(np.argmax(np.maximum(lo - p, p - hi)))
            by = float(max(lo[axis] - p[axis], p[axis] - hi[axis]))
            return (f"TCP target ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}) m lies outside the protective box "
                    f"{np.round(lo, 3).tolist()}..{np.round(hi, 3).tolist()} (task frame) by {by * 1000:.0f} mm "
                    f"along {'xyz'[axis]}; nothing moved")
        for where, X in self._path_poses(X_task_tcp, start):
            points = self._hand_points(X)
            out = np.maximum(lo[:, None] - points, points - hi[:, None])  # (3, n): > 0 outside
            if (out > 1e-9).any():
                axis, i = np.unravel_index(int(np.argmax(out)), out.shape)
                q = points[:, i]
                return (f"the hand would leave the protective box {np.round(lo, 3).tolist()}..{np.round(hi, 3).tolist()} "
                        f"(task frame) {where}: its {self._hand_point_names[i]} at ({q[0]:.3f}, {q[1]:.3f}, {q[2]:.3f}) m "
                        f"is {out[axis, i] * 1000:.0f} mm outside along {'xyz'[axis]}"
                        + ("; jog the arm into the box on the teach pendant" if where == "at the start" else "")
                        + "; nothing moved")
        return None

    def _path_poses(self, X_target, start):
        """(words, X_task_tcp) along moveL's straight line: the target, or the start, every
        10 mm and 5 deg between, and the target (the TCP moves on the line, its
        orientation turns at a proportional rate)."""
        if start is None:
            yield "at the target", X_target
            return
        X0, X1 = np.asarray(start, float), np.asarray(X_target, float)
        turn = Rotation.from_matrix(X0[:3, :3]).inv() * Rotation.from_matrix(X1[:3, :3])
        steps = int(max(1, np.ceil(np.linalg.norm(X1[:3, 3] - X0[:3, 3]) / 0.01), np.ceil(np.degrees(turn.magnitude()) / 5)))
        for k in range(steps + 1):
            f = k / steps
            X = np.eye(4)
            X[:3, :3] = (Rotation.from_matrix(X0[:3, :3]) * Rotation.from_rotvec(f * turn.as_rotvec())).as_matrix()
            X[:3, 3] = X0[:3, 3] + f * (X1[:3, 3] - X0[:3, 3])
            yield ("at the start" if k == 0 else "at the target" if k == steps else f"{100 * f:.0f} % along the path"), X

    def speed_for(self, speed_mps: float) -> tuple[float, str]:
        if not math.isfinite(speed_mps) or speed_mps < 0:
            raise ValueError(f"speed_mps {speed_mps} must be >= 0 (0 = default {self.settings.default_speed_mps} m/s)")
        if speed_mps == 0:
            return self.settings.default_speed_mps, ""
        if speed_mps > self.settings.max_speed_mps:
            return self.settings.max_speed_mps, f" (speed {speed_mps:g} m/s capped to {self.settings.max_speed_mps:g} m/s)"
        return float(speed_mps), ""

    def check(self, X_task_tcp) -> MoveResult:
        """Checks 1-8 without moving: refusals come back as reachable=False."""
        refusal = self._box_refusal(X_task_tcp)
        if refusal:
            return MoveResult(False, False, f"refused: {refusal}")
        control, receive = self._ensure_connected()
        refusal = self._refusal_for_state(control, receive)
        if refusal:
            return MoveResult(False, False, f"refused: {refusal}; nothing moved")
        control = self._control
        # The TCP first: the start pose is read in the controller's TCP, which a restart of the
        # script by ur_rtde itself has turned back to the pendant's.
        self._configure(control)
        X_task_start = np.asarray(self.settings.X_task_base, float) @ ur_pose_to_matrix(self._rpc(receive.getActualTCPPose))
        refusal = self._box_refusal(X_task_tcp, X_task_start)
        if refusal:
            return MoveResult(False, False, f"refused: {refusal}")
        pose = self.to_base(X_task_tcp)
        if not self._rpc(control.isPoseWithinSafetyLimits, pose):
            return MoveResult(False, False, "refused: the controller says the TCP pose "
                              f"{np.round(pose, 4).tolist()} (base frame) is beyond its safety limits or reach "
                              "(safety planes, tool orientation limits, arm range); nothing moved")
        if not self._rpc(control.getInverseKinematicsHasSolution, pose):
            return MoveResult(False, False, f"refused: no inverse-kinematics solution for the TCP pose "
                              f"{np.round(pose, 4).tolist()} (base frame); nothing moved")
        joints = [float(q) for q in self._rpc(control.getInverseKinematics, pose)]
        return MoveResult(True, False, "reachable", joints)

    def move(self, X_task_tcp, speed_mps: float = 0.0, check_only: bool = False,
             deadline: float | None = None) -> MoveResult:
        """Move the TCP to `X_task_tcp` along a straight line, or only check it.

        `deadline` (on this arm's clock, time.monotonic by default): the caller gives up
        then; a request still waiting is refused, a motion still running is stopped.
        Refusals (box, robot state, limits, deadline) return reachable=False before any
        motion. Raises ConnectionLost when the link fails (before or during the motion)
        and ValueError for a bad speed."""
        speed, speed_note = self.speed_for(speed_mps)
        if self.latched and not check_only:
            return MoveResult(False, False, f"refused: {self.latched} is latched: nothing moves until ~/arm is "
                              "called with data: true (after making the cell safe); nothing moved")
        with self._request_lock:
            if self._request_active:
                return MoveResult(False, False, "refused: another motion is running on this arm")
            self._request_active = True
        # A reconnect in progress (keep_connected) holds the motion lock: wait for it, not
        # past the caller's deadline.
        wait_s = self.settings.connect_timeout_s + 4 * self.settings.call_timeout_s
        if deadline is not None:
            wait_s = max(0.0, min(wait_s, deadline - self._clock()))
        if not self._motion_lock.acquire(timeout=wait_s):
            self._request_active = False
            if deadline is not None and self._clock() >= deadline:
                return MoveResult(False, False, "refused: the request's deadline passed while a reconnect to the "
                                  "controller ran; nothing moved")
            raise ConnectionLost("a reconnect to the controller did not finish in time")
        try:
            self._stop.clear()
            checked = self.check(X_task_tcp)
            if not checked.reachable or check_only:
                return checked
            control, receive = self._control, self._receive
            return self._run_motion(control, receive, self.to_base(X_task_tcp), speed, speed_note,
                                    checked.joint_positions, deadline)
        finally:
            self._moving.clear()
            self._request_active = False
            self._motion_lock.release()
            self._idle_pose = None  # watch() takes the pose where this request left the arm

    def _late(self, deadline) -> bool:
        return deadline is not None and self._clock() >= deadline

    def _run_motion(self, control, receive, target, speed, speed_note, joints, deadline=None) -> MoveResult:
        s = self.settings
        start = self._rpc(receive.getActualTCPPose)
        distance_m = float(np.linalg.norm(np.subtract(target[:3], start[:3])))
        slider = max(float(self._rpc(receive.getTargetSpeedFraction)), 0.01)
        # Trapezoid profile time at the commanded speed, stretched by the speed slider.
        # (A pure reorientation is bounded by the margin.)
        expected_s = (distance_m / speed + speed / s.acceleration_mps2) / slider
        limit_s = expected_s + s.motion_timeout_margin_s
        # getAsyncOperationProgress toggles between negative values (-1/-2) from one async
        # operation to the next: "< 0 and different from before" is this motion's end, even
        # for a motion too short to be seen running (ur_rtde's documented contract).
        before = self._rpc(control.getAsyncOperationProgress)
        limit_n = s.contact_force_limit_n
        force_start_n = self._tcp_force_n(receive) if limit_n > 0 else 0.0
        # The TCP and payload again, right before the motion: ur_rtde may have restarted its
        # script (and so reset both) on a reconnect of its own since the last request.
        self._configure(control)
        # The watchdog first: no motion runs without it (removed whenever the script ends).
        if not self._rpc(control.setWatchdog, 1.0 / s.watchdog_period_s):
            why = self._refusal_for_state(control, receive) or "the control script did not accept setWatchdog"
            return MoveResult(False, False, f"refused: {why}; nothing moved", joints)
        self._kicking = True
        self._kick_gap_s, self._kick_ok_t = 0.0, self._clock()
        with self._send_lock:  # a stop or latch from here on either prevents moveL or follows it
            if self._stop.is_set() or self.latched:
                return MoveResult(True, False, f"stopped before the motion started ({self._stopper()}); nothing moved",
                                  joints)
            if self._late(deadline):
                return MoveResult(False, False, "refused: the request's deadline passed before the motion started "
                                  "(the caller gave up on it); nothing moved", joints)
            sent = self._rpc(control.moveL, target, float(speed), float(s.acceleration_mps2), True)
            if sent:
                self._moving.set()
        if not sent:
            why = self._refusal_for_state(control, receive)
            return MoveResult(True, False, f"the controller did not start the motion{': ' + why if why else ''}", joints)
        deadline_motion = self._clock() + limit_s
        try:
            return self._watch_motion(control, receive, target, before, force_start_n, slider, limit_s,
                                      deadline_motion, deadline, speed_note, joints)
        except ConnectionLost as e:  # one message whichever call saw the link go down first
            raise self._lost(f"the RTDE connection was lost during a motion ({e}): the controller's watchdog stops "
                             f"the arm within {s.watchdog_period_s:g} s of the last kick; check it on the teach "
                             "pendant") from None
        finally:
            self._log(f"motion: largest watchdog kick gap {self._kick_gap_s * 1000:.0f} ms "
                      f"(watchdog {s.watchdog_period_s * 1000:.0f} ms)")

    def _watch_motion(self, control, receive, target, before, force_start_n, slider, limit_s, deadline_motion,
                      deadline, speed_note, joints) -> MoveResult:
        s = self.settings
        limit_n = s.contact_force_limit_n
        while True:
            time.sleep(s.poll_period_s)
            if self._stop.is_set():
                self._rpc(control.stopL, float(s.stop_deceleration_mps2), False)
                where, left_m = self._where(receive, target)
                return MoveResult(True, False, f"motion stopped by {self._stopper()} {where}", joints, False, left_m)
            if self._late(deadline):
                self._rpc(control.stopL, float(s.stop_deceleration_mps2), False)
                where, left_m = self._where(receive, target)
                return MoveResult(True, False, f"motion stopped at the request's deadline (the caller gave up on it) "
                                  f"{where}", joints, False, left_m)
            if not (self._rpc(control.isConnected) and self._rpc(receive.isConnected)):
                raise self._lost("the interfaces report themselves disconnected")
            safety = self._rpc(receive.getSafetyMode)
            if safety not in SAFETY_MODES_THAT_MOVE:
                self._stop_cause = f"a {SAFETY_MODES.get(safety, safety)}"
                where, left_m = self._where(receive, target)
                return MoveResult(True, False, f"{SAFETY_MODES.get(safety, safety)} during the motion {where}: "
                                  f"{safety_action(safety)}", joints, False, left_m)
            if limit_n > 0:
                force_n = self._tcp_force_n(receive)
                if force_n - force_start_n > limit_n:
                    self._rpc(control.stopL, float(s.stop_deceleration_mps2), False)
                    where, left_m = self._where(receive, target)
                    return MoveResult(True, False, f"stopped by contact {where}: the force on "
                                      f"the hand rose from {force_start_n:.0f} to {force_n:.0f} N, by more than the "
                                      f"{limit_n:.0f} N limit (contact_force_limit_n)", joints, True, left_m)
            progress = self._rpc(control.getAsyncOperationProgress)
            if progress < 0 and progress != before:
                break
            # The script writes the end of a motion only from its own threads: a script that
            # stopped mid-move (the watchdog, the pendant's Stop) leaves "running" for ever.
            if not self._rpc(control.isProgramRunning):
                if self._rpc(receive.getSafetyMode) not in SAFETY_MODES_THAT_MOVE:
                    continue  # a stop since the check above ended the script: the next poll reports it
                return self._script_ended(receive, target, joints)
            # ur_rtde reconnecting by itself mid-motion (a kick or a poll hit a socket error)
            # restarts its script: that ends the motion, or, when the command it resends is this
            # moveL, runs it with the pendant's TCP; either way the TCP is the pendant's again.
            held = self._tcp_offset_mid_motion(control, receive)
            if held is None:  # the script ended between isProgramRunning and this command: the next poll says why
                continue
            if max(abs(a - b) for a, b in zip(held, s.tcp_in_flange)) > 1e-6:
                return self._restarted_mid_motion(control, receive, target, joints)
            if self._clock() > deadline_motion:
                self._rpc(control.stopL, float(s.stop_deceleration_mps2), False)
                where, left_m = self._where(receive, target)
                return MoveResult(True, False, f"motion did not end within {limit_s:.1f} s "
                                  f"(speed slider {100 * slider:.0f} %); stopped {where}", joints, False, left_m)
        if self._stop.is_set():  # stop() halts the arm itself: the end seen may be its stopL
            where, left_m = self._where(receive, target)
            return MoveResult(True, False, f"motion stopped by {self._stopper()} {where}", joints, False, left_m)
        actual = self._rpc(receive.getActualTCPPose)
        dp, da = pose_error(actual, target)
        arrived = dp <= s.position_tolerance_m and da <= s.orientation_tolerance_deg
        if not arrived and not self._rpc(control.isProgramRunning):
            return self._script_ended(receive, target, joints)
        held = [float(v) for v in self._rpc(control.getTCPOffset)]
        if max(abs(a - b) for a, b in zip(held, s.tcp_in_flange)) > 1e-6 and not arrived:
            # the script restarted (ur_rtde's own reconnect) and ended the motion short
            return self._restarted_mid_motion(control, receive, target, joints)
        lapse = self._tcp_lapse(receive, actual)  # arrived with the pendant's TCP: the fingers are not there
        if lapse:
            return MoveResult(True, False, lapse, joints, False, dp)
        if dp > s.position_tolerance_m or da > s.orientation_tolerance_deg:
            return MoveResult(True, False, f"motion ended {dp * 1000:.1f} mm / {da:.1f} deg from the target "
                              f"(tolerance {s.position_tolerance_m * 1000:g} mm / {s.orientation_tolerance_deg:g} deg)",
                              joints, False, dp)
        return MoveResult(True, True, f"reached the target ({dp * 1000:.1f} mm, {da:.2f} deg){speed_note}", joints,
                          False, dp)

    def _tcp_offset_mid_motion(self, control, receive):
        """getTCPOffset during a motion; None where no script answered it (ur_rtde throws "did
        not succeed") because the script ended meanwhile with the link still up: a stop, which
        the caller reports as such, not as a lost link. Raises ConnectionLost otherwise."""
        calls = self._connection()
        try:
            return [float(v) for v in self._call(calls, control.getTCPOffset)]
        except ConnectionLost as e:
            if self._rpc(receive.isConnected) and not self._rpc(control.isProgramRunning):
                return None
            raise self._lost(str(e)) from None

    def _restarted_mid_motion(self, control, receive, target, joints) -> MoveResult:
        s = self.settings
        progress = self._rpc(control.getAsyncOperationProgress)  # the restarted script's register
        self._rpc(control.stopL, float(s.stop_deceleration_mps2), False)
        where, left_m = self._where_flange(receive, target)
        text = ("ur_rtde reconnected by itself during the motion and restarted its control script (the controller's "
                f"TCP is the pendant's again): stopped (stopL) {where}")
        if progress >= 0:  # a motion still ran: the move ur_rtde resent, with the wrong TCP
            self.latched = "a motion with the wrong TCP"
            return MoveResult(True, False, f"{text}; the move ur_rtde sent again ran with the pendant's TCP, so the hand "
                              "is not where the target says; latched: check the cell, then call ~/arm with data: true",
                              joints, False, left_m)
        self._stop_cause = "ur_rtde's own reconnect"
        return MoveResult(True, False, f"{text}; ur_arm sets the TCP again before the next motion", joints, False, left_m)

    def _script_ended(self, receive, target, joints) -> MoveResult:
        """The control script stopped during the motion with no safety stop: the watchdog
        (the kicks were late) or a person at the pendant, each said so at once."""
        s = self.settings
        where, left_m = self._where(receive, target)
        late_s = max(self._kick_refused_gap_s, self._clock() - self._kick_ok_t if self._kick_ok_t else 0.0)
        if late_s >= 0.8 * s.watchdog_period_s:
            self._stop_cause = "the RTDE watchdog"
            return MoveResult(True, False, f"the RTDE watchdog stopped the motion {where}: no kick reached the "
                              f"controller for {late_s:.2f} s (watchdog_period_s {s.watchdog_period_s:g}; this "
                              "process was starved or the link stalled); ur_arm restarts the control script",
                              joints, False, left_m)
        self._latch_unexplained_end()
        return MoveResult(True, False, f"{self.latched} during the motion {where}; nothing moves until ~/arm is called "
                          "with data: true", joints, False, left_m)

    def _tcp_lapse(self, receive, actual) -> str:
        """'' if the flange from the joint angles (nominal FK of getActualQ) and the flange
        from the TCP pose and tcp_in_flange agree; otherwise why not, having latched: the
        motion put the controller's TCP, not the hand's pinch point, on the target."""
        s = self.settings
        X_base_flange = nominal_flange_in_base(self._rpc(receive.getActualQ))
        held = matrix_to_ur_pose(np.linalg.inv(X_base_flange) @ ur_pose_to_matrix(actual))
        off_m, off_deg = pose_error(held, list(s.tcp_in_flange))
        if off_m <= s.tcp_check_tolerance_m and off_deg <= s.tcp_check_tolerance_deg:
            return ""
        self.latched = "a motion with the wrong TCP"
        return (f"the motion ran with the controller's TCP {off_m * 1000:.0f} mm / {off_deg:.1f} deg off tcp_in_flange "
                f"(the pendant's TCP ~{np.round(held, 4).tolist()}, from the joint angles): ur_rtde restarted its "
                "control script by itself (a reconnect after a socket error), so the hand is not where the target "
                "says; latched: check the cell, then call ~/arm with data: true")

    def watch(self) -> str | None:
        """Between requests (the node calls this at its state rate): the arm must not move.
        A flange that moved more than idle_motion_limit_m since the last request ended is a
        motion nobody asked for (ur_rtde resending a command after its own reconnect, or
        the pendant): stopL and latch. Returns the line to log, or None."""
        if self.busy or self._control is None:
            return None
        if not self._motion_lock.acquire(blocking=False):
            return None
        try:
            control, receive = self._control, self._receive
            if control is None:
                return None
            # The flange from the joint angles: the TCP pose jumps without any motion when the
            # controller's TCP changes (ur_rtde restarting its script, ur_arm setting it again).
            flange = nominal_flange_in_base(self._rpc(receive.getActualQ))[:3, 3]
            if self._idle_pose is None:
                self._idle_pose = flange
                return None
            moved_m = float(np.linalg.norm(flange - self._idle_pose))
            if moved_m <= self.settings.idle_motion_limit_m:
                return None
            self._rpc(control.stopL, float(self.settings.stop_deceleration_mps2), False)
            self._idle_pose = None
            self.latched = "a motion no request asked for"
            return (f"the arm moved {moved_m * 1000:.0f} mm while no request ran (a command ur_rtde sent again after "
                    "reconnecting by itself, or the pendant): stopped it (stopL) and latched: nothing moves until "
                    "~/arm is called with data: true")
        except ConnectionLost:
            return None  # the node's reconnect reports it
        finally:
            self._motion_lock.release()

    def flange_in_base(self) -> np.ndarray:
        """X_base_flange now: the actual TCP pose and tcp_in_flange; monitoring only, after
        checking the controller's TCP (module doc). Raises ConnectionLost, TCPMismatch."""
        receive = self._receive
        if receive is None:
            raise ConnectionLost(f"not connected to the robot ({self.last_error})")
        X_base_tcp = ur_pose_to_matrix(self._rpc(receive.getActualTCPPose))
        X_flange_tcp = ur_pose_to_matrix(self.settings.tcp_in_flange)
        if self.monitor_only:
            X_base_flange = nominal_flange_in_base(self._rpc(receive.getActualQ))
            self._check_controller_tcp(np.linalg.inv(X_base_flange) @ X_base_tcp)
        return X_base_tcp @ np.linalg.inv(X_flange_tcp)

    def flange_in_task(self) -> np.ndarray:
        """X_task_flange now (flange_in_base in the task frame). Raises ConnectionLost, TCPMismatch."""
        return np.asarray(self.settings.X_task_base, float) @ self.flange_in_base()

    def _check_controller_tcp(self, X_flange_tcp_controller):
        s = self.settings
        controller = matrix_to_ur_pose(X_flange_tcp_controller)
        off_m, off_deg = pose_error(controller, list(s.tcp_in_flange))
        if off_m > s.tcp_check_tolerance_m or off_deg > s.tcp_check_tolerance_deg:
            raise TCPMismatch(
                f"the controller's TCP differs from tcp_in_flange by {off_m * 1000:.0f} mm / {off_deg:.1f} deg "
                f"(the pendant's TCP is ~{np.round(controller, 4).tolist()} from the joint angles, tcp_in_flange "
                f"{[float(v) for v in s.tcp_in_flange]}): monitoring only, ur_arm cannot set it, so flange_pose is "
                "not published and the camera cannot be calibrated; set the TCP on the pendant (Installation > "
                "General > TCP) to tcp_in_flange, or correct ur_arm.tcp_in_flange in the cell file if the pendant's "
                "is the gripper's (then restart)")

    def _tcp_force_n(self, receive) -> float:
        """|force| of the controller's TCP wrench (payload-compensated), N."""
        return float(np.linalg.norm(np.asarray(self._rpc(receive.getActualTCPForce), float)[:3]))

    def _where_flange(self, receive, target) -> tuple[str, float]:
        """_where when the controller's TCP may not be tcp_in_flange: from the joint angles."""
        X = nominal_flange_in_base(self._rpc(receive.getActualQ)) @ ur_pose_to_matrix(self.settings.tcp_in_flange)
        dp = float(np.linalg.norm(X[:3, 3] - np.asarray(target[:3])))
        return f"{dp * 1000:.0f} mm before the target", dp

    def _where(self, receive, target) -> tuple[str, float]:
        """(words, distance [m]): where the TCP stopped, from the target."""
        dp, _ = pose_error(self._rpc(receive.getActualTCPPose), target)
        return f"{dp * 1000:.0f} mm before the target", float(dp)

    def _stopper(self) -> str:
        return self.latched or "stop_motion"

    def latch(self, why: str) -> bool:
        """The emergency stop: halt the running motion and refuse every motion until
        arm(True). True if a motion was running."""
        self.latched = why
        return self.stop()

    def arm(self, enable: bool) -> str:
        """arm(True) clears the latch; arm(False) latches without an emergency."""
        if not enable:
            self.latch("a disarm (~/arm false)")
            return "disarmed: every motion is refused until ~/arm is called with data: true"
        was, self.latched = self.latched, ""
        if was:  # a person armed: a script that ended meanwhile may be restarted
            self._stop_cause = self._stop_cause or "~/arm after the latch"
        return f"armed: motion allowed{' (cleared: ' + was + ')' if was else ''}"

    def stop(self) -> bool:
        """Halt the running motion (stopL). True if a motion was running; its move()
        then returns success=False. A motion whose moveL is being sent is waited for, so
        the stopL follows it; one not yet sent will not be."""
        self._stop.set()
        with self._send_lock:
            moving = self._moving.is_set()
        if not moving:
            return False
        control = self._control
        if control is not None:
            try:  # at once from this thread too: the motion loop may be waiting on a call
                self._rpc(control.stopL, float(self.settings.stop_deceleration_mps2), True)
            except ConnectionLost:
                pass  # the motion loop reports the lost link
        return True
