"""A stand-in for a Universal Robots controller behind ur_rtde's two Python interfaces
(RTDEControlInterface, RTDEReceiveInterface; ur-rtde 1.6.5 method names and argument
orders). It records every call and moves its TCP along straight lines in wall time,
so the adapter's own logic (frames, limits, polling, stop, timeouts, reconnects) runs
for real against it. Faults are switched on by attributes:

    robot_mode, safety_mode, speed_slider, program_running   controller state
    within_safety_limits, has_ik                             answers about a pose
    protective_stop_after_s   a motion halts after this long, safety mode 3
    lose_link_after_s         after this long into a motion, isConnected() is false and
                              every call raises RuntimeError (as ur_rtde does)
    never_finish              a motion never reports its end
    arrive_offset_m           a motion ends this far (x) from its target
    tcp_force                 getActualTCPForce's reading at rest (a bias, or a press)
    contact_after_s, contact_force
                              after this long into a motion the TCP meets something:
                              contact_force is added to the reading while it pushes on
    hang                      names of methods that block until `release()`
    refuse_connect            the constructor raises RuntimeError (robot unreachable)
    control_unavailable       only the receive interface connects (pendant in Local mode)
"""
from __future__ import annotations

import threading
import time

import numpy as np


class FakeURController:
    def __init__(self, tcp_pose=(0.4, 0.0, 0.4, np.pi, 0.0, 0.0)):
        self.calls: list[tuple[str, tuple]] = []
        self.connects = 0
        self.tcp_pose = [float(v) for v in tcp_pose]
        self.tcp_offset = [0.0] * 6
        self.robot_mode, self.safety_mode, self.speed_slider = 7, 1, 1.0
        self.program_running = True
        self.within_safety_limits = True
        self.has_ik = True
        self.protective_stop_after_s = None
        self.lose_link_after_s = None
        self.never_finish = False
        self.arrive_offset_m = 0.0
        self.tcp_force = [0.0] * 6
        self.contact_after_s = None
        self.contact_force = [0.0] * 6
        self._in_contact = False
        self.hang: set[str] = set()
        self.refuse_connect = False
        self.control_unavailable = False  # the pendant in Local mode: only the receive interface connects
        self.time_scale = 1.0        # < 1: motions take that fraction of distance / speed
        self.link_up = True
        self._released = threading.Event()
        self._lock = threading.RLock()
        self._motion = None          # (start, target, t0, duration_s)
        self._progress = -1          # ur_rtde: toggles -1/-2 between async operations, >= 0 while running
        self._last_end = -1

    # -- what the adapter's connect() gets ---------------------------------------------

    def connect(self):
        self.connects += 1
        self._record("connect", ())
        if self.refuse_connect:
            raise RuntimeError("Error: Could not connect to: 192.0.2.1 at 30004, verify the IP")
        self.link_up = True
        if self.control_unavailable:
            return None, FakeReceive(self), "ur_rtde: Please enable remote control on the robot!"
        return FakeControl(self), FakeReceive(self)

    def release(self):
        self._released.set()

    def called(self, name):
        return [args for n, args in self.calls if n == name]

    # -- internals ----------------------------------------------------------------------

    def _record(self, name, args):
        with self._lock:
            self.calls.append((name, args))
        if name in self.hang:
            self._released.wait()
        if not self.link_up and name not in ("connect", "isConnected", "disconnect"):
            raise RuntimeError("read: End of file")

    def _update(self):
        """Advance the simulated motion to now."""
        with self._lock:
            if self._motion is None:
                return
            start, target, t0, duration = self._motion
            elapsed = time.monotonic() - t0
            if self.lose_link_after_s is not None and elapsed >= self.lose_link_after_s:
                self.link_up = False
            if self.contact_after_s is not None and elapsed >= self.contact_after_s:
                self._in_contact = True
            if self.protective_stop_after_s is not None and elapsed >= self.protective_stop_after_s:
                self._freeze(start, target, self.protective_stop_after_s / duration)
                self.safety_mode = 3
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

    def setTcp(self, pose):
        self.ur._record("setTcp", (list(pose),))
        self.ur.tcp_offset = list(pose)
        return True

    def setPayload(self, mass, cog):
        self.ur._record("setPayload", (mass, list(cog)))
        return True

    def isProgramRunning(self):
        self.ur._record("isProgramRunning", ())
        return self.ur.program_running

    def isPoseWithinSafetyLimits(self, pose):
        self.ur._record("isPoseWithinSafetyLimits", (list(pose),))
        return self.ur.within_safety_limits

    def getInverseKinematicsHasSolution(self, pose, qnear=(), max_position_error=1e-10, max_orientation_error=1e-10):
        self.ur._record("getInverseKinematicsHasSolution", (list(pose),))
        return self.ur.has_ik

    def getInverseKinematics(self, pose, qnear=(), max_position_error=1e-10, max_orientation_error=1e-10):
        self.ur._record("getInverseKinematics", (list(pose),))
        if not self.ur.has_ik:
            raise RuntimeError("getInverseKinematics: no solution")
        return [0.1, -1.2, 1.5, -1.9, -1.57, 0.0]

    def getAsyncOperationProgress(self):
        self.ur._record("getAsyncOperationProgress", ())
        self.ur._update()
        return self.ur._progress

    def moveL(self, pose, speed=0.25, acceleration=1.2, asynchronous=False):
        self.ur._record("moveL", (list(pose), speed, acceleration, asynchronous))
        if self.ur.robot_mode != 7 or self.ur.safety_mode not in (1, 2):
            return False
        self.ur._start_motion(pose, speed)
        return True

    def stopL(self, a=10.0, asynchronous=False):
        self.ur._record("stopL", (a, asynchronous))
        self.ur._stop_motion()


class FakeReceive:
    """RTDEReceiveInterface's methods the adapter uses."""

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

    def getRobotMode(self):
        self.ur._record("getRobotMode", ())
        return self.ur.robot_mode

    def getSafetyMode(self):
        self.ur._record("getSafetyMode", ())
        self.ur._update()
        return self.ur.safety_mode

    def getTargetSpeedFraction(self):
        self.ur._record("getTargetSpeedFraction", ())
        return self.ur.speed_slider
