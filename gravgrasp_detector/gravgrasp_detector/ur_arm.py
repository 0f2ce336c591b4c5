"""A Universal Robots arm moving the 2F-85's TCP along straight lines, over RTDE.

The logic behind `ros2 run gravgrasp_detector ur_arm` (ur_arm_node.py), with no rclpy
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
                   when connecting (2F-85: 0.1558 m out along the flange z)

What happens to a request, in order; nothing moves until every check passed:

    1. the TCP target lies inside the protective box (task frame)     refused otherwise
    2. speed: 0 means the default; above max_speed_mps it is capped
    3. connected (else one reconnect attempt)                          ConnectionLost
    4. robot powered and running, safety mode normal or reduced, the
       RTDE control script running, speed slider above 1 %            refused otherwise
    5. the controller says the pose is within its safety limits and
       has an inverse-kinematics solution                              refused otherwise
    6. moveL (asynchronous), then poll: stop requested -> stopL; protective stop,
       lost link, or no end within the expected time (+ margin, scaled by the
       speed slider) -> stopL and fail; contact: the TCP force's magnitude risen by
       more than contact_force_limit_n since the motion began -> stopL and fail,
       "stopped by contact" (the sim stand-in's rule and words); at the end the actual
       TCP must be within position/orientation tolerance of the target.

Why the contact stop counts the rise, not the force: the reading has a bias (payload
settings, drift) and a motion may start under load, e.g. a lift with the closed fingers
pressing the object on the table, which the lift relieves. A bias b raises the trip point
by at most 2|b| (a 60 N limit trips between 60 and 60 + 2|b| N of contact); the UR's own
force limit (pendant, Safety > Limits) stays the hard backstop.

Monitoring only: `connect()` may return (None, receive, why) when the control interface
cannot be built (e.g. the pendant is in Local mode for jogging); then poses are read
(flange_pose, for calibration) and every motion request raises ConnectionLost saying so.

Never hang: every RTDE call runs on this connection's own thread and is waited on for
at most `call_timeout_s` (`connect_timeout_s` for connecting); no answer, an exception,
or isConnected() false raise `ConnectionLost` and drop the connection; the next request
(or `connect()`) builds fresh interfaces.
"""
from __future__ import annotations

import concurrent.futures
import dataclasses
import math
import threading
import time
from typing import Callable

import numpy as np

from .ur_arm_settings import URArmSettings
from .ur_controller import (ROBOT_MODE_RUNNING, ROBOT_MODES, SAFETY_MODES, SAFETY_MODES_THAT_MOVE, CallThread,
                            matrix_to_ur_pose, pose_error, ur_pose_to_matrix)


class URArmError(Exception):
    """Base of this module's errors."""


class ConnectionLost(URArmError):
    """The link to the controller failed: not reachable, no answer within the timeout,
    an RTDE call raised, or the interfaces report a lost connection. The connection is
    dropped; the next request or `connect()` builds fresh interfaces."""


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
        self._control = self._receive = self._calls = None
        self._link_lock = threading.Lock()     # connect / drop
        self._motion_lock = threading.Lock()   # a request or a reconnect, one at a time
        self._request_lock = threading.Lock()
        self._request_active = False           # a second request is refused, not queued
        self._stop = threading.Event()
        self._moving = threading.Event()
        self.last_error = "not connected yet"
        self.monitor_only = ""   # why only the receive interface is connected ('' = both or none)

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
            self._drop_locked("reconnecting")
            calls = CallThread()
            try:
                got = self._wait(calls.submit(self._connect), self.settings.connect_timeout_s,
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
        try:
            tcp = [float(v) for v in self.settings.tcp_in_flange]
            if not self._rpc(control.setTcp, tcp):
                raise self._lost("the controller refused setTcp (is the RTDE control script running?)")
            if self.settings.payload_kg > 0:
                if not self._rpc(control.setPayload, float(self.settings.payload_kg),
                                 [float(v) for v in self.settings.payload_cog_m]):
                    raise self._lost("the controller refused setPayload")
            status = self.status_line()
        except ConnectionLost as e:
            self.last_error = str(e)
            raise
        self.last_error = ""
        return status

    def keep_connected(self) -> str | None:
        """Reconnect if the link is down and no request is running (the node calls this
        periodically). Returns the status line after a reconnect, None if nothing was
        done; raises ConnectionLost if reconnecting failed."""
        if self.connected or not self._motion_lock.acquire(blocking=False):
            return None
        try:
            return self.connect()
        finally:
            self._motion_lock.release()

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

    def _drop_locked(self, why: str):
        if self._calls is not None:
            self._calls.close()
        self._control = self._receive = self._calls = None
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

    def _rpc(self, method, *args):
        """One RTDE call on the connection's thread, waited on at most call_timeout_s."""
        calls = self._calls
        if calls is None:
            raise ConnectionLost(f"not connected to the robot ({self.last_error})")
        name = getattr(method, "__name__", "an RTDE call")
        try:
            return self._wait(calls.submit(method, *args), self.settings.call_timeout_s, name)
        except ConnectionLost as e:
            raise self._lost(str(e)) from None

    def _ensure_connected(self):
        if self._control is None:
            self._log(f"not connected ({self.last_error}): connecting")
            self.connect()
        control, receive = self._control, self._receive
        if control is None and receive is not None:
            raise ConnectionLost(f"the RTDE control interface is not connected ({self.monitor_only}): switch the "
                                 "pendant to Remote Control (ur_arm retries), until then it only watches the arm")
        if control is None or not (self._rpc(control.isConnected) and self._rpc(receive.isConnected)):
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
        """Why the robot cannot move now, said so a person at the pendant can fix it."""
        robot = self._rpc(receive.getRobotMode)
        if robot != ROBOT_MODE_RUNNING:
            return (f"robot mode is {ROBOT_MODES.get(robot, robot)}, not RUNNING: power the arm on and "
                    "release the brakes on the teach pendant")
        safety = self._rpc(receive.getSafetyMode)
        if safety not in SAFETY_MODES_THAT_MOVE:
            name = SAFETY_MODES.get(safety, safety)
            if safety == 3:
                return "the robot is in PROTECTIVE_STOP: find what it hit, then unlock it on the teach pendant"
            return f"safety mode is {name}: clear it on the teach pendant (emergency stop released, safeguards closed)"
        if not self._rpc(control.isProgramRunning):
            raise self._lost("the RTDE control script is not running on the controller (a program was started "
                             "or stopped on the pendant, or the robot left remote control)")
        slider = self._rpc(receive.getTargetSpeedFraction)
        if slider < 0.01:
            return "the speed slider on the teach pendant is at 0 %: the arm would not move; raise it"
        return None

    # -- motion ---------------------------------------------------------------------

    def to_base(self, X_task_tcp) -> list:
        return matrix_to_ur_pose(self._X_base_task @ np.asarray(X_task_tcp, float))

    def _box_refusal(self, X_task_tcp) -> str | None:
        p = np.asarray(X_task_tcp, float)[:3, 3]
        lo, hi = np.asarray(self.settings.workspace_min_m), np.asarray(self.settings.workspace_max_m)
        if ((p >= lo) & (p <= hi)).all():
            return None
        axis = int(np.argmax(np.maximum(lo - p, p - hi)))
        by = float(max(lo[axis] - p[axis], p[axis] - hi[axis]))
        return (f"TCP target ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}) m lies outside the protective box "
                f"{np.round(lo, 3).tolist()}..{np.round(hi, 3).tolist()} (task frame) by {by * 1000:.0f} mm "
                f"along {'xyz'[axis]}; nothing moved")

    def speed_for(self, speed_mps: float) -> tuple[float, str]:
        if not math.isfinite(speed_mps) or speed_mps < 0:
            raise ValueError(f"speed_mps {speed_mps} must be >= 0 (0 = default {self.settings.default_speed_mps} m/s)")
        if speed_mps == 0:
            return self.settings.default_speed_mps, ""
        if speed_mps > self.settings.max_speed_mps:
            return self.settings.max_speed_mps, f" (speed {speed_mps:g} m/s capped to {self.settings.max_speed_mps:g} m/s)"
        return float(speed_mps), ""

    def check(self, X_task_tcp) -> MoveResult:
        """Checks 1-5 without moving: refusals come back as reachable=False."""
        refusal = self._box_refusal(X_task_tcp)
        if refusal:
            return MoveResult(False, False, f"refused: {refusal}")
        control, receive = self._ensure_connected()
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

    def move(self, X_task_tcp, speed_mps: float = 0.0, check_only: bool = False) -> MoveResult:
        """Move the TCP to `X_task_tcp` along a straight line, or only check it.

        Refusals (box, robot state, limits) return reachable=False before any motion.
        Raises ConnectionLost when the link fails (before or during the motion) and
        ValueError for a bad speed."""
        speed, speed_note = self.speed_for(speed_mps)
        with self._request_lock:
            if self._request_active:
                return MoveResult(False, False, "refused: another motion is running on this arm")
            self._request_active = True
        # A reconnect in progress (keep_connected) holds the motion lock: wait for it.
        if not self._motion_lock.acquire(timeout=self.settings.connect_timeout_s + 4 * self.settings.call_timeout_s):
            self._request_active = False
            raise ConnectionLost("a reconnect to the controller did not finish in time")
        try:
            self._stop.clear()
            checked = self.check(X_task_tcp)
            if not checked.reachable or check_only:
                return checked
            control, receive = self._control, self._receive
            refusal = self._refusal_for_state(control, receive)
            if refusal:
                return MoveResult(False, False, f"refused: {refusal}; nothing moved", checked.joint_positions)
            return self._run_motion(control, receive, self.to_base(X_task_tcp), speed, speed_note,
                                    checked.joint_positions)
        finally:
            self._moving.clear()
            self._request_active = False
            self._motion_lock.release()

    def _run_motion(self, control, receive, target, speed, speed_note, joints) -> MoveResult:
        s = self.settings
        start = self._rpc(receive.getActualTCPPose)
        distance_m = float(np.linalg.norm(np.subtract(target[:3], start[:3])))
        slider = max(float(self._rpc(receive.getTargetSpeedFraction)), 0.01)
        # Trapezoid profile time at the commanded speed, stretched by the speed slider.
        # (A pure reorientation is bounded by the margin.)
        expected_s = (distance_m / speed + speed / s.acceleration_mps2) / slider
        deadline = self._clock() + expected_s + s.motion_timeout_margin_s
        # getAsyncOperationProgress toggles between negative values (-1/-2) from one async
        # operation to the next: "< 0 and different from before" is this motion's end, even
        # for a motion too short to be seen running (ur_rtde's documented contract).
        before = self._rpc(control.getAsyncOperationProgress)
        limit_n = s.contact_force_limit_n
        force_start_n = self._tcp_force_n(receive) if limit_n > 0 else 0.0
        self._moving.set()
        if self._stop.is_set():
            return MoveResult(True, False, "stopped before the motion started (stop_motion)", joints)
        if not self._rpc(control.moveL, target, float(speed), float(s.acceleration_mps2), True):
            why = self._refusal_for_state(control, receive)
            return MoveResult(True, False, f"the controller did not start the motion{': ' + why if why else ''}", joints)
        while True:
            time.sleep(s.poll_period_s)
            if self._stop.is_set():
                self._rpc(control.stopL, float(s.stop_deceleration_mps2), False)
                where, left_m = self._where(receive, target)
                return MoveResult(True, False, f"motion stopped by stop_motion {where}", joints, False, left_m)
            if not (self._rpc(control.isConnected) and self._rpc(receive.isConnected)):
                raise self._lost("the RTDE connection was lost during a motion: the arm's state is unknown, "
                                 "check it on the teach pendant")
            safety = self._rpc(receive.getSafetyMode)
            if safety not in SAFETY_MODES_THAT_MOVE:
                where, left_m = self._where(receive, target)
                return MoveResult(True, False, f"{SAFETY_MODES.get(safety, safety)} during the motion "
                                  f"{where}: clear it on the teach pendant", joints, False, left_m)
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
            if self._clock() > deadline:
                self._rpc(control.stopL, float(s.stop_deceleration_mps2), False)
                where, left_m = self._where(receive, target)
                return MoveResult(True, False, f"motion did not end within {expected_s + s.motion_timeout_margin_s:.1f} s "
                                  f"(speed slider {100 * slider:.0f} %); stopped {where}", joints, False, left_m)
        if self._stop.is_set():  # stop() halts the arm itself: the end seen may be its stopL
            where, left_m = self._where(receive, target)
            return MoveResult(True, False, f"motion stopped by stop_motion {where}", joints, False, left_m)
        actual = self._rpc(receive.getActualTCPPose)
        dp, da = pose_error(actual, target)
        if dp > s.position_tolerance_m or da > s.orientation_tolerance_deg:
            return MoveResult(True, False, f"motion ended {dp * 1000:.1f} mm / {da:.1f} deg from the target "
                              f"(tolerance {s.position_tolerance_m * 1000:g} mm / {s.orientation_tolerance_deg:g} deg)",
                              joints, False, dp)
        return MoveResult(True, True, f"reached the target ({dp * 1000:.1f} mm, {da:.2f} deg){speed_note}", joints,
                          False, dp)

    def flange_in_task(self) -> np.ndarray:
        """X_task_flange now (from the actual TCP pose and the TCP offset). Raises ConnectionLost."""
        receive = self._receive
        if receive is None:
            raise ConnectionLost(f"not connected to the robot ({self.last_error})")
        X_base_tcp = ur_pose_to_matrix(self._rpc(receive.getActualTCPPose))
        X_flange_tcp = ur_pose_to_matrix(self.settings.tcp_in_flange)
        return np.asarray(self.settings.X_task_base, float) @ X_base_tcp @ np.linalg.inv(X_flange_tcp)

    def _tcp_force_n(self, receive) -> float:
        """|force| of the controller's TCP wrench (payload-compensated), N."""
        return float(np.linalg.norm(np.asarray(self._rpc(receive.getActualTCPForce), float)[:3]))

    def _where(self, receive, target) -> tuple[str, float]:
        """(words, distance [m]): where the TCP stopped, from the target."""
        dp, _ = pose_error(self._rpc(receive.getActualTCPPose), target)
        return f"{dp * 1000:.0f} mm before the target", float(dp)

    def stop(self) -> bool:
        """Halt the running motion (stopL). True if a motion was running; its move()
        then returns success=False."""
        self._stop.set()
        if not self._moving.is_set():
            return False
        control = self._control
        if control is not None:
            try:  # at once from this thread too: the motion loop may be waiting on a call
                self._rpc(control.stopL, float(self.settings.stop_deceleration_mps2), True)
            except ConnectionLost:
                pass  # the motion loop reports the lost link
        return True
