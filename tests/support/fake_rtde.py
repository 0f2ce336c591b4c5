"""A stand-in for a Universal Robots controller behind ur_rtde's two Python interfaces
(RTDEControlInterface, RTDEReceiveInterface; ur-rtde 1.6.5 method names, argument
orders and return types). It records every call and moves its TCP along straight lines
in wall time, so the adapter's own logic (frames, limits, polling, stop, watchdog,
timeouts, reconnects, recovery) runs for real against it.

What each call does in each robot and safety state follows ur_rtde 1.6.5, cited where it
is modelled. The sources: `rtde_control_interface.cpp` (RTDEControlInterface::
sendCommand, isPoseWithinSafetyLimits, stopL, reuploadScript), the control script that
library uploads (`rtde_control.script`, embedded in the installed rtde_control .so:
`cmd == 35` runs `rtde_set_watchdog("input_int_register_0", f, "stop")`), the Python
docstrings of the installed 1.6.5 wheel, and the URScript manual's `rtde_set_watchdog`
("all watchdogs are removed on program stop"). The one rule most calls share,
RTDEControlInterface::sendCommand:

    runtime state STOPPED, or the control script not running   -> false, nothing sent
      ("RTDEControlInterface: RTDE control script is not running!")
    isProtectiveStopped() || isEmergencyStopped()              -> false, nothing sent
    (a link that fails                                          -> RuntimeError here)

Faults are switched on by attributes:

    robot_mode, safety_mode, speed_slider         controller state (UR codes, ur_controller)
    program_running                               ur_rtde's control script runs
    within_safety_limits, has_ik                  answers about a pose (when the script can answer)
    protective_stop_after_s   a motion halts after this long: safety mode 3, the script ends
    emergency_stop_after_s    the same with safety mode 7 (ROBOT_EMERGENCY_STOP), robot mode 3
    lose_link_after_s         after this long into a motion, isConnected() is false and every
                              call raises RuntimeError (as ur_rtde does); nothing the adapter
                              sends arrives, so the watchdog trips if one was set
    never_finish              a motion never reports its end
    arrive_offset_m           a motion ends this far (x) from its target
    tcp_force                 getActualTCPForce's reading at rest (a bias, or a press)
    contact_after_s, contact_force
                              after this long into a motion the TCP meets something:
                              contact_force is added to the reading while it pushes on
    hang                      names of methods that block until `release()`
    refuse_connect            the constructor raises RuntimeError (robot unreachable)
    control_unavailable       the pendant in Local mode: only the receive interface connects,
                              and a re-uploaded script is not run
    controller_tcp            the TCP offset the controller holds (the pendant's, until setTcp);
                              a test sets it to give the pendant a TCP other than tcp_in_flange

getActualQ answers joint angles consistent with the TCP pose: the flange is
tcp_pose @ inv(controller_tcp), and the angles are the nominal UR5e inverse kinematics of
it (ur_kinematics), so FK(q) @ controller_tcp is the TCP pose a real controller reports.

And read back: `watchdog_tripped` (the watchdog stopped the script), `motion_running`,
`clear_protective_stop()` (what unlocking on the pendant does).
"""
from __future__ import annotations

import threading
import time

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from gravgrasp_detector.execution.ur_kinematics import flange_in_base

RUNNING, NORMAL, REDUCED, PROTECTIVE_STOP, ROBOT_EMERGENCY_STOP, SYSTEM_EMERGENCY_STOP = 7, 1, 2, 3, 7, 6


class FakeURController:
    def __init__(self, tcp_pose=(0.4, 0.0, 0.4, np.pi, 0.0, 0.0)):
        self.calls: list[tuple[str, tuple]] = []
        self.connects = 0
        self.tcp_pose = [float(v) for v in tcp_pose]
        self.controller_tcp = [0.0] * 6
        self.robot_mode, self.safety_mode, self.speed_slider = RUNNING, NORMAL, 1.0
        self.program_running = True
        self.within_safety_limits = True
        self.has_ik = True
        self.protective_stop_after_s = None
        self.emergency_stop_after_s = None
        self.lose_link_after_s = None
        self.never_finish = False
        self.arrive_offset_m = 0.0
        self.tcp_force = [0.0] * 6
        self.contact_after_s = None
        self.contact_force = [0.0] * 6
        self._in_contact = False
        self.hang: set[str] = set()
        self.refuse_connect = False
        self.control_unavailable = False
        self.time_scale = 1.0        # < 1: motions take that fraction of distance / speed
        self.link_up = True
        self.watchdog_period_s = None  # set by setWatchdog(f) = 1 / f; None: no watchdog
        self.watchdog_tripped = False
        self._last_command_t = time.monotonic()
        self._released = threading.Event()
        self._lock = threading.RLock()
        self._motion = None          # (start, target, t0, duration_s)
        self._progress = -1          # ur_rtde: toggles -1/-2 between async operations, >= 0 while running
        self._last_end = -1
        self._q = (None, np.array([0.0, -1.57, 1.57, -1.57, -1.57, 0.0]))  # (for which flange, joint angles)

    # -- what the adapter's connect() gets ---------------------------------------------

    def connect(self, receive=None):
        """The adapter's connect(receive): a live receive interface passed in is kept."""
        self.connects += 1
        self._record("connect", ())
        if self.refuse_connect:
            raise RuntimeError("Error: Could not connect to: 192.0.2.1 at 30004, verify the IP")
        self.link_up = True
        receive = receive or FakeReceive(self)
        if self.control_unavailable:  # the constructor's remote-control check (PolyScope >= 5.6)
            return None, receive, "ur_rtde: Please enable remote control on the robot!"
        # The constructor uploads the script and waits for it (waitForProgramRunning: it
        # throws "ur_rtde: Failed to start control script, before timeout" after 5 s); the
        # node's connect() then watches only.
        with self._lock:
            if not self._can_run_script():
                return None, receive, "ur_rtde: Failed to start control script, before timeout"
            self._start_script()
        return FakeControl(self), receive

    def release(self):
        self._released.set()

    def called(self, name):
        return [args for n, args in self.calls if n == name]

    @property
    def motion_running(self) -> bool:
        self._update()
        return self._motion is not None

    def clear_protective_stop(self):
        """Unlock on the pendant: safety NORMAL; the control script stays ended."""
        with self._lock:
            self.safety_mode = NORMAL

    def joint_angles(self) -> list:
        """The UR5e's joint angles for the flange at tcp_pose @ inv(controller_tcp)."""
        with self._lock:
            X = _matrix(self.tcp_pose) @ np.linalg.inv(_matrix(self.controller_tcp))
            key = tuple(np.round(X, 9).ravel())
            if self._q[0] != key:  # solved from the last answer: the arm moves continuously
                fit = least_squares(lambda q: (flange_in_base(q) - X)[:3].ravel(), self._q[1], xtol=1e-12, ftol=1e-12)
                if np.abs(flange_in_base(fit.x) - X).max() > 1e-7:
                    raise AssertionError(f"fake_rtde: no UR5e joint angles for the flange {X[:3, 3]}: out of reach")
                self._q = (key, np.mod(fit.x + np.pi, 2 * np.pi) - np.pi)  # within the joints' range
            return [float(v) for v in self._q[1]]

    # -- internals ----------------------------------------------------------------------

    def _record(self, name, args):
        with self._lock:
            self.calls.append((name, args))
        if name in self.hang:
            self._released.wait()
        if not self.link_up and name not in ("connect", "isConnected", "disconnect"):
            raise RuntimeError("read: End of file")

    def _can_run_script(self) -> bool:
        return self.robot_mode == RUNNING and self.safety_mode in (NORMAL, REDUCED)

    def _start_script(self):
        self.program_running = True
        self.watchdog_period_s = None
        self._last_command_t = time.monotonic()

    def _end_script(self, at_s=None):
        """The program stops: its motion halts, and the URScript manual: "all watchdogs
        are removed on program stop"."""
        if self._motion is not None:
            start, target, t0, duration = self._motion
            self._freeze(start, target, ((time.monotonic() if at_s is None else at_s) - t0) / duration)
        self.program_running = False
        self.watchdog_period_s = None

    def _send_command(self, kick=True) -> bool:
        """RTDEControlInterface::sendCommand's refusals (see the module docstring). A command
        that is sent writes input_int_register_0, the register the watchdog watches, so
        every command counts as a kick."""
        self._update()
        with self._lock:
            if not self.program_running:
                return False
            if self.safety_mode in (PROTECTIVE_STOP, ROBOT_EMERGENCY_STOP, SYSTEM_EMERGENCY_STOP):
                return False
            if kick:
                self._last_command_t = time.monotonic()
            return True

    def _update(self):
        """Advance the controller to now: the watchdog, then the simulated motion."""
        with self._lock:
            now = time.monotonic()
            if self.program_running and self.watchdog_period_s is not None:
                # rtde_set_watchdog(..., "stop"): no update of the register for one period stops the program
                trip_t = self._last_command_t + self.watchdog_period_s
                if now > trip_t:
                    self.watchdog_tripped = True
                    self._end_script(at_s=trip_t)
            if self._motion is None:
                return
            start, target, t0, duration = self._motion
            elapsed = now - t0
            if self.lose_link_after_s is not None and elapsed >= self.lose_link_after_s:
                self.link_up = False
            if self.contact_after_s is not None and elapsed >= self.contact_after_s:
                self._in_contact = True
            for after_s, safety, robot in ((self.protective_stop_after_s, PROTECTIVE_STOP, RUNNING),
                                          (self.emergency_stop_after_s, ROBOT_EMERGENCY_STOP, 3)):
                if after_s is not None and elapsed >= after_s:
                    self.safety_mode, self.robot_mode = safety, robot
                    self._end_script(at_s=t0 + after_s)
                    return
            if elapsed >= duration and not self.never_finish:
                end = list(target)
                end[0] += self.arrive_offset_m
                self.tcp_pose = end
                self._finish()
            else:
                f = min(elapsed / duration, 1.0)
                self.tcp_pose = list(np.add(start[:3], f * np.subtract(target[:3], start[:3]))) + list(start[3:])

    def _freeze(self, start, target, fraction):
        f = min(max(fraction, 0.0), 1.0)
        self.tcp_pose = list(np.add(start[:3], f * np.subtract(target[:3], start[:3]))) + list(start[3:])
        self._finish()

    def _finish(self):
        self._motion = None
        self._last_end = -2 if self._last_end == -1 else -1
        self._progress = self._last_end

    def _start_motion(self, target, speed):
        with self._lock:
            start = list(self.tcp_pose)
            distance = np.linalg.norm(np.subtract(target[:3], start[:3]))
            duration = max(self.time_scale * distance / speed / max(self.speed_slider, 1e-3), 0.01)
            self._motion = (start, list(target), time.monotonic(), duration)
            self._progress = 0

    def _stop_motion(self):
        with self._lock:
            if self._motion is not None:
                start, target, t0, duration = self._motion
                self._freeze(start, target, (time.monotonic() - t0) / duration)


class FakeControl:
    """RTDEControlInterface's methods the adapter uses."""

    def __init__(self, ur: FakeURController):
        self.ur = ur

    def isConnected(self):
        self.ur._record("isConnected", ())
        self.ur._update()
        return self.ur.link_up

    def disconnect(self):
        self.ur._record("disconnect", ())

    def isProgramRunning(self):
        # Reads the "program running" bit of robot_status_bits; sends no command.
        self.ur._record("isProgramRunning", ())
        self.ur._update()
        return self.ur.program_running

    def reuploadScript(self):
        # rtde_control_interface.cpp: a running script is stopped first, then
        # script_client_->sendScript(); it returns whether the script was *sent* and does
        # not wait for it to run (docstring: "resume operation by reuploading the RTDE
        # control script"). A controller that cannot run programs does not start it.
        self.ur._record("reuploadScript", ())
        with self.ur._lock:  # in Local mode the controller ignores scripts sent over the network
            if self.ur._can_run_script() and not self.ur.control_unavailable:
                self.ur._start_script()
        return True

    def setTcp(self, pose):
        self.ur._record("setTcp", (list(pose),))
        if not self.ur._send_command():
            return False
        self.ur.controller_tcp = list(pose)
        return True

    def getTCPOffset(self):
        # 1.6.5 throws "getTCPOffset() function did not succeed!" when its command is not
        # answered (the string is in the installed rtde_control .so).
        self.ur._record("getTCPOffset", ())
        if not self.ur._send_command():
            raise RuntimeError("getTCPOffset() function did not succeed!")
        return list(self.ur.controller_tcp)

    def setPayload(self, mass, cog):
        self.ur._record("setPayload", (mass, list(cog)))
        return self.ur._send_command()

    def setWatchdog(self, min_frequency=10.0):
        # Script cmd 35: rtde_set_watchdog("input_int_register_0", min_frequency, "stop").
        self.ur._record("setWatchdog", (min_frequency,))
        if not self.ur._send_command():
            return False
        self.ur.watchdog_period_s = 1.0 / float(min_frequency)
        return True

    def kickWatchdog(self):
        # A WATCHDOG command: sendCommand sends it without waiting (a "continuous" command),
        # after the same refusals.
        self.ur._record("kickWatchdog", ())
        return self.ur._send_command()

    def isPoseWithinSafetyLimits(self, pose):
        # rtde_control_interface.cpp: `if (sendCommand(robot_cmd)) return getOutputIntReg(1) == 1;
        # else return false;` - false whenever the command cannot be sent, whatever the pose.
        self.ur._record("isPoseWithinSafetyLimits", (list(pose),))
        return self.ur._send_command() and self.ur.within_safety_limits

    def getInverseKinematicsHasSolution(self, pose, qnear=(), max_position_error=1e-10, max_orientation_error=1e-10):
        # 1.6.5 throws "getInverseKinematicsHasSolution() function did not succeed!" when the
        # command fails (string in the installed .so).
        self.ur._record("getInverseKinematicsHasSolution", (list(pose),))
        if not self.ur._send_command():
            raise RuntimeError("getInverseKinematicsHasSolution() function did not succeed!")
        return self.ur.has_ik

    def getInverseKinematics(self, pose, qnear=(), max_position_error=1e-10, max_orientation_error=1e-10):
        # rtde_control_interface.cpp: an empty vector when sendCommand fails.
        self.ur._record("getInverseKinematics", (list(pose),))
        if not self.ur._send_command() or not self.ur.has_ik:
            return []
        return [0.1, -1.2, 1.5, -1.9, -1.57, 0.0]

    def getAsyncOperationProgress(self):
        # Reads output_int_register_2 from the robot state; sends no command.
        self.ur._record("getAsyncOperationProgress", ())
        self.ur._update()
        return self.ur._progress

    def moveL(self, pose, speed=0.25, acceleration=1.2, asynchronous=False):
        # A MOVEL command through sendCommand: false in every state it refuses.
        self.ur._record("moveL", (list(pose), speed, acceleration, asynchronous))
        if self.ur.robot_mode != RUNNING or not self.ur._send_command():
            return False
        self.ur._start_motion(pose, speed)
        return True

    def stopL(self, a=10.0, asynchronous=False):
        # `void stopL(double a, bool asynchronous)`: a STOPL command through sendCommand,
        # its result dropped: without a running script nothing is sent and nothing happens.
        self.ur._record("stopL", (a, asynchronous))
        if self.ur._send_command():
            self.ur._stop_motion()


class FakeReceive:
    """RTDEReceiveInterface's methods the adapter uses: robot state, no commands, so they
    answer in every robot and safety state while the link is up."""

    def __init__(self, ur: FakeURController):
        self.ur = ur

    def isConnected(self):
        self.ur._record("isConnected", ())
        self.ur._update()
        return self.ur.link_up

    def disconnect(self):
        self.ur._record("disconnect", ())

    def getActualTCPForce(self):
        self.ur._record("getActualTCPForce", ())
        self.ur._update()
        return list(np.add(self.ur.tcp_force, self.ur.contact_force if self.ur._in_contact else 0.0))

    def getActualTCPPose(self):
        self.ur._record("getActualTCPPose", ())
        self.ur._update()
        return list(self.ur.tcp_pose)

    def getActualQ(self):
        self.ur._record("getActualQ", ())
        self.ur._update()
        return self.ur.joint_angles()

    def getRobotMode(self):
        self.ur._record("getRobotMode", ())
        self.ur._update()
        return self.ur.robot_mode

    def getSafetyMode(self):
        self.ur._record("getSafetyMode", ())
        self.ur._update()
        return self.ur.safety_mode

    def getTargetSpeedFraction(self):
        self.ur._record("getTargetSpeedFraction", ())
        return self.ur.speed_slider


def _matrix(ur_pose) -> np.ndarray:
    X = np.eye(4)
    X[:3, :3] = Rotation.from_rotvec(ur_pose[3:6]).as_matrix()
    X[:3, 3] = ur_pose[:3]
    return X
