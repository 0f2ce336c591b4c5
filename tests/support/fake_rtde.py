"""A stand-in for a Universal Robots controller behind ur_rtde's two Python interfaces
(RTDEControlInterface, RTDEReceiveInterface; ur-rtde 1.6.5 method names, argument
orders and return types). It records every call and moves its flange along straight
lines in wall time, so the adapter's own logic (frames, limits, polling, stop, watchdog,
timeouts, reconnects, recovery) runs for real against it.

What each call does in each robot and safety state follows ur_rtde, cited where it is
modelled. The sources: `src/rtde_control_interface.cpp` of ur_rtde 1.5.8 (line numbers
below; 1.6.5's installed librtde.so carries the same reconnect messages, "RTDEControl
Interface: Robot is disconnected, reconnecting..." and "Successfully reconnected!"), the
control script that library uploads (embedded in the installed librtde.so.1.6.5: `cmd ==
35` runs `rtde_set_watchdog("input_int_register_0", f, "stop")`, `cmd == 29` runs
`set_tcp(pose)`), the Python docstrings of the installed 1.6.5 wheel, and the URScript
manual (`rtde_set_watchdog`: "all watchdogs are removed on program stop"; `set_tcp` and
`set_payload` hold while the program runs: a new program starts with the installation's
TCP and payload). The rules most calls share:

RTDEControlInterface::sendCommand (cpp 2138-2296):
    runtime state STOPPED, or the control script not running   -> false, nothing sent
      ("RTDEControlInterface: RTDE control script is not running!")
    isProtectiveStopped() || isEmergencyStopped()              -> false, nothing sent
    the send fails (link lost)   -> disconnect, `reconnect(); return sendCommand(cmd);`
      (cpp 2290-2295): a reconnect that fails throws (RuntimeError in Python); one that
      succeeds re-uploads the control script and sends the same command again
RTDEControlInterface::reconnect (cpp 371-475), and the constructor: a running control
    script is stopped (`stopScript()`) and the script uploaded again; the new program has
    the installation's TCP and payload and no watchdog. receiveCallback (cpp 711-805) also
    reconnects by itself when the link comes back, with no call from the user.
Robot state (getters of both interfaces, isProgramRunning, getAsyncOperationProgress)
    is read from the last state package received (`robot_state_`): during a link loss
    they answer the cached state, they do not raise.
The async-operation register (output_int_register_2) is written only by the control
    script: its move thread (started, finished), exec_stopl_stopj (finished), and
    reset_async_progress() when the script starts. A script that stops mid-move leaves it
    at "running". getAsyncOperationProgress (cpp 291-301): the progress while running,
    else (operation id % 2) - 2, so -1/-2 alternate between operations.

Faults are switched on by attributes:

    robot_mode, safety_mode, speed_slider         controller state (UR codes, ur_controller)
    program_running                               ur_rtde's control script runs
    within_safety_limits, has_ik                  answers about a pose (when the script can answer)
    protective_stop_after_s   a motion halts after this long: safety mode 3, the script ends
    emergency_stop_after_s    the same with safety mode 7 (ROBOT_EMERGENCY_STOP), robot mode 3
    lose_link_after_s         after this long into a motion the network goes down until the
                              next constructor (connect); nothing the adapter sends arrives,
                              so the watchdog trips if one was set
    drop_link(for_s)          the network goes down now for for_s seconds, then ur_rtde
                              reconnects by itself (the silent reconnect)
    reconnect_wait_s          a command sent while the network is down waits this long for
                              it (ur_rtde's reconnect blocking in connect), then is sent again
                              on the new connection if the network came back; 0: fails at once
    link_up                   False: the network is down (until connect)
    never_finish              a motion never reports its end
    arrive_offset_m           a motion ends this far (x) from its target
    tcp_force                 getActualTCPForce's reading at rest (a bias, or a press)
    contact_after_s, contact_force
                              after this long into a motion the TCP meets something:
                              contact_force is added to the reading while it pushes on
    hang                      names of methods that block until `release()`
    delay                     {method name: seconds} a call takes before it acts
    on_call                   {method name: callable()} run when that method is called, before it acts
    refuse_connect            the constructor raises RuntimeError (robot unreachable)
    control_unavailable       the pendant in Local mode: only the receive interface connects,
                              and a re-uploaded script is not run
    controller_tcp            the TCP offset the controller holds now (a test may set it to
                              give the pendant a TCP other than tcp_in_flange)
    installation_tcp, installation_payload
                              the pendant's TCP and payload: what a (re)started program has

The state is the flange pose; getActualTCPPose is flange @ controller_tcp, so a TCP that
reverts moves the reported TCP, not the arm. getActualQ answers joint angles consistent
with it: the nominal UR5e inverse kinematics of the flange (ur_kinematics), so FK(q) @
controller_tcp is the TCP pose a real controller reports.

And read back: `watchdog_tripped` (the watchdog stopped the script), `motion_running`,
`reconnects` (ur_rtde's own reconnects), `motions` (every motion the controller ran:
start, target, its TCP, the flange at its start, who sent it), `travelled_m(motion)`, `payload`, `clear_protective_stop()` (what unlocking on the
pendant does), `press_stop_on_pendant()`.
"""
from __future__ import annotations

import threading
import time

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation, Slerp

from gravgrasp_detector.execution.ur_kinematics import flange_in_base

RUNNING, NORMAL, REDUCED, PROTECTIVE_STOP, ROBOT_EMERGENCY_STOP, SYSTEM_EMERGENCY_STOP = 7, 1, 2, 3, 7, 6
TCP_2F85 = (0.0, 0.0, 0.1558, 0.0, 0.0, 0.0)


class FakeURController:
    def __init__(self, tcp_pose=(0.4, 0.0, 0.4, np.pi, 0.0, 0.0), tcp_in_flange=TCP_2F85):
        """`tcp_pose`: where the 2F-85's TCP (`tcp_in_flange`) starts, in the base frame;
        the controller's own TCP is the installation's (the flange) until setTcp."""
        self.calls: list[tuple[str, tuple]] = []
        self.connects = 0
        self.reconnects = 0
        self.installation_tcp = [0.0] * 6
        self.installation_payload = (0.0, [0.0, 0.0, 0.0])
        self.controller_tcp = list(self.installation_tcp)
        self.payload = self.installation_payload
        self.flange = _matrix(tcp_pose) @ np.linalg.inv(_matrix(tcp_in_flange))
        self.robot_mode, self.safety_mode, self.speed_slider = RUNNING, NORMAL, 1.0
        self.program_running = True
        self.within_safety_limits = True
        self.has_ik = True
        self.protective_stop_after_s = None
        self.emergency_stop_after_s = None
        self.lose_link_after_s = None
        self.reconnect_wait_s = 0.0
        self.reconnect_takes_s = 0.0  # ur_rtde's reconnect once the network is back (sync, script upload)
        self.never_finish = False
        self.arrive_offset_m = 0.0
        self.tcp_force = [0.0] * 6
        self.contact_after_s = None
        self.contact_force = [0.0] * 6
        self._in_contact = False
        self.hang: set[str] = set()
        self.delay: dict[str, float] = {}
        self.on_call: dict = {}
        self.refuse_connect = False
        self.control_unavailable = False
        self.time_scale = 1.0        # < 1: motions take that fraction of distance / speed
        self._link_up = True
        self._link_back_t = None     # drop_link: when the network returns
        self._cached = None          # the last state package before the link went down
        self.watchdog_period_s = None  # set by setWatchdog(f) = 1 / f; None: no watchdog
        self.watchdog_tripped = False
        self.motions: list[dict] = []
        self._last_command_t = time.monotonic()
        self._released = threading.Event()
        self._lock = threading.RLock()
        self._motion = None          # dict: start, target (TCP poses), tcp (offset at start), t0, duration
        self._op_id = 0              # the script's async_op_id
        self._op_running = False     # the running bit of output_int_register_2
        self._q = (None, np.array([0.0, -1.57, 1.57, -1.57, -1.57, 0.0]))  # (for which flange, joint angles)
        self._controls: list[FakeControl] = []

    # -- what the adapter's connect() gets ---------------------------------------------

    def connect(self, receive=None):
        """The adapter's connect(receive): a live receive interface passed in is kept."""
        self.connects += 1
        self._record("connect", ())
        if self.refuse_connect:
            raise RuntimeError("Error: Could not connect to: 192.0.2.1 at 30004, verify the IP")
        with self._lock:
            if self._link_back_t is not None and time.monotonic() < self._link_back_t:
                raise RuntimeError("Error: Could not connect to: 192.0.2.1 at 30004, verify the IP (No route to host)")
            self._link_back_t = None
            self._set_link(True)
        receive = receive or FakeReceive(self)
        if self.control_unavailable:  # the constructor's remote-control check (PolyScope >= 5.6)
            return None, receive, "ur_rtde: Please enable remote control on the robot!"
        # The constructor uploads the script, stopping a running one first (cpp 445-474), and
        # waits for it (waitForProgramRunning: "ur_rtde: Failed to start control script, before
        # timeout" after 5 s); the node's connect() then watches only.
        with self._lock:
            if not self._can_run_script():
                return None, receive, "ur_rtde: Failed to start control script, before timeout"
            self._end_script()
            self._start_script()
        control = FakeControl(self)
        self._controls.append(control)
        return control, receive

    def release(self):
        self._released.set()

    def called(self, name):
        return [args for n, args in self.calls if n == name]

    @property
    def tcp_pose(self) -> list:
        """The actual TCP pose in the controller's current TCP (getActualTCPPose)."""
        with self._lock:
            return _ur_pose(self.flange @ _matrix(self.controller_tcp))

    @tcp_pose.setter
    def tcp_pose(self, pose):
        with self._lock:
            self.flange = _matrix(pose) @ np.linalg.inv(_matrix(self.controller_tcp))

    def tcp_pose_in(self, tcp_offset) -> list:
        """Where a TCP at `tcp_offset` (e.g. tcp_in_flange) is now, whatever the controller's TCP."""
        self._update()
        with self._lock:
            return _ur_pose(self.flange @ _matrix(tcp_offset))

    def travelled_m(self, motion) -> float:
        """How far the flange is now from where `motion` (an entry of `motions`) started."""
        self._update()
        with self._lock:
            return float(np.linalg.norm(self.flange[:3, 3] - motion["flange"][:3, 3]))

    @property
    def motion_running(self) -> bool:
        self._update()
        return self._motion is not None

    def clear_protective_stop(self):
        """Unlock on the pendant: safety NORMAL; the control script stays ended."""
        with self._lock:
            self.safety_mode = NORMAL

    def press_stop_on_pendant(self):
        """The operator's Stop on the pendant: the program (ur_rtde's script) stops, and its
        motion with it; the safety mode stays NORMAL."""
        with self._lock:
            self._update()
            self._end_script()

    def drop_link(self, for_s=None):
        """The network goes down now; it comes back after `for_s` s (None: at the next connect)."""
        with self._lock:
            self._update()
            self._set_link(False)
            self._link_back_t = None if for_s is None else time.monotonic() + for_s

    def joint_angles(self) -> list:
        """The UR5e's joint angles for the flange now."""
        with self._lock:
            X = self.flange
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
        if name in self.on_call:
            self.on_call[name]()
        if self.delay.get(name):
            time.sleep(self.delay[name])

    @property
    def link_up(self) -> bool:
        return self._link_up

    @link_up.setter
    def link_up(self, up: bool):
        with self._lock:
            self._set_link(up)

    def _set_link(self, up: bool):
        if up == self._link_up:
            return
        if not up:
            self._cached = self._snapshot()
        self._link_up = up

    def _snapshot(self) -> dict:
        return {"robot_mode": self.robot_mode, "safety_mode": self.safety_mode, "program_running": self.program_running,
                "tcp_pose": self.tcp_pose, "q": self.joint_angles(), "progress": self._progress(),
                "force": self._force(), "speed_slider": self.speed_slider}

    def _state(self, key):
        """A value of the last state package: live while the link is up, cached during a loss."""
        self._update()
        with self._lock:
            if self.link_up:
                return self._live(key)
            return self._cached[key]

    def _live(self, key):
        return {"robot_mode": lambda: self.robot_mode, "safety_mode": lambda: self.safety_mode,
                "program_running": lambda: self.program_running, "tcp_pose": lambda: self.tcp_pose,
                "progress": self._progress, "force": self._force, "speed_slider": lambda: self.speed_slider,
                "q": self.joint_angles}[key]()

    def _force(self):
        return list(np.add(self.tcp_force, self.contact_force if self._in_contact else 0.0))

    def _progress(self) -> int:
        # getAsyncOperationProgress (cpp 291-301)
        return 0 if self._op_running else self._op_id % 2 - 2

    def _can_run_script(self) -> bool:
        return self.robot_mode == RUNNING and self.safety_mode in (NORMAL, REDUCED)

    def _start_script(self):
        """A new program: the installation's TCP and payload, no watchdog, and the script's
        reset_async_progress() (async_op_id starts at 0, finished)."""
        self.program_running = True
        self.watchdog_period_s = None
        self.controller_tcp = list(self.installation_tcp)
        self.payload = self.installation_payload
        self._op_id, self._op_running = 0, False
        self._last_command_t = time.monotonic()

    def _end_script(self, at_s=None):
        """The program stops: its motion halts, and the URScript manual: "all watchdogs
        are removed on program stop". The async register is left as it was."""
        self._halt(at_s)
        self.program_running = False
        self.watchdog_period_s = None

    def _reconnect(self):
        """ur_rtde's reconnect() with the network back (cpp 371-475): the script is stopped
        and uploaded again."""
        self.reconnects += 1
        self._record("(ur_rtde reconnects by itself)", ())
        if self._can_run_script() and not self.control_unavailable:
            self._end_script()
            self._start_script()

    def _send_command(self, control=None, kick=True) -> bool:
        """RTDEControlInterface::sendCommand (see the module docstring): its refusals, and its
        reconnect-and-resend when the link is down. A command that is sent writes
        input_int_register_0, the register the watchdog watches, so every command counts
        as a kick."""
        self._update()
        if not self.link_up:
            waited_until = time.monotonic() + self.reconnect_wait_s
            reconnects = self.reconnects
            while not self.link_up and time.monotonic() < waited_until:
                time.sleep(0.01)
                self._update()
            if not self.link_up:
                raise RuntimeError("RTDEControlInterface: Robot is disconnected, reconnecting... "
                                   "connect: No route to host")
            # This command's own `reconnect(); return sendCommand(cmd);` (cpp 2290-2295),
            # unless the receive thread reconnected meanwhile.
            time.sleep(self.reconnect_takes_s)
            with self._lock:
                if self.reconnects == reconnects:
                    self._reconnect()
        with self._lock:
            if not self.program_running:
                return False
            if self.safety_mode in (PROTECTIVE_STOP, ROBOT_EMERGENCY_STOP, SYSTEM_EMERGENCY_STOP):
                return False
            if kick:
                self._last_command_t = time.monotonic()
            return True

    def _update(self):
        """Advance the controller to now: the link, the watchdog, then the simulated motion."""
        with self._lock:
            now = time.monotonic()
            if not self.link_up and self._link_back_t is not None and now >= self._link_back_t:
                self._link_back_t = None
                self._set_link(True)
                if any(not c.disconnected for c in self._controls):
                    self._reconnect()  # receiveCallback's own reconnect (cpp 771-790)
            if self.program_running and self.watchdog_period_s is not None:
                # rtde_set_watchdog(..., "stop"): no update of the register for one period stops the program
                trip_t = self._last_command_t + self.watchdog_period_s
                if now > trip_t:
                    self.watchdog_tripped = True
                    self._end_script(at_s=trip_t)
            if self._motion is None:
                return
            m = self._motion
            elapsed = now - m["t0"]
            if self.lose_link_after_s is not None and elapsed >= self.lose_link_after_s:
                self._set_link(False)
                self._link_back_t = None
            if self.contact_after_s is not None and elapsed >= self.contact_after_s:
                self._in_contact = True
            for after_s, safety, robot in ((self.protective_stop_after_s, PROTECTIVE_STOP, RUNNING),
                                          (self.emergency_stop_after_s, ROBOT_EMERGENCY_STOP, 3)):
                if after_s is not None and elapsed >= after_s:
                    self.safety_mode, self.robot_mode = safety, robot
                    self._end_script(at_s=m["t0"] + after_s)
                    return
            if elapsed >= m["duration"] and not self.never_finish:
                end = list(m["target"])
                end[0] += self.arrive_offset_m
                self._place(end, m["tcp"])
                self._motion = None
                self._op_running = False  # the move thread: signal_async_operation_finished()
            else:
                self._place(self._along(m, elapsed / m["duration"]), m["tcp"])

    def _along(self, m, fraction) -> list:
        f = min(max(fraction, 0.0), 1.0)
        p = np.add(m["start"][:3], f * np.subtract(m["target"][:3], m["start"][:3]))
        R = Slerp([0.0, 1.0], Rotation.from_rotvec([m["start"][3:], m["target"][3:]]))(f)
        return list(p) + list(R.as_rotvec())

    def _place(self, tcp_pose, tcp_offset):
        self.flange = _matrix(tcp_pose) @ np.linalg.inv(_matrix(tcp_offset))

    def _halt(self, at_s=None):
        """The motion stops where it is (or was at `at_s`); the register is not written."""
        if self._motion is not None:
            m = self._motion
            t = time.monotonic() if at_s is None else at_s
            self._place(self._along(m, (t - m["t0"]) / m["duration"]), m["tcp"])
            self._motion = None

    def _start_motion(self, target, speed, by):
        with self._lock:
            start = self.tcp_pose
            distance = np.linalg.norm(np.subtract(target[:3], start[:3]))
            duration = max(self.time_scale * distance / speed / max(self.speed_slider, 1e-3), 0.01)
            self._motion = {"start": start, "target": list(target), "tcp": list(self.controller_tcp),
                            "t0": time.monotonic(), "duration": duration}
            self.motions.append({"start": start, "target": list(target), "tcp": list(self.controller_tcp),
                                 "flange": self.flange.copy(), "by": by, "t0": time.monotonic()})
            self._op_id, self._op_running = (self._op_id + 1) % 128, True  # signal_async_operation_started()

    def _stop_motion(self):
        with self._lock:
            self._halt()
            self._op_running = False  # exec_stopl_stopj: signal_async_operation_finished()


class FakeControl:
    """RTDEControlInterface's methods the adapter uses."""

    def __init__(self, ur: FakeURController):
        self.ur = ur
        self.disconnected = False

    def _command(self, name, args, kick=True) -> bool:
        self.ur._record(name, args)
        if self.disconnected:
            return False
        return self.ur._send_command(self, kick)

    def isConnected(self):
        self.ur._record("isConnected", ())
        self.ur._update()
        return self.ur.link_up and not self.disconnected

    def disconnect(self):
        self.ur._record("disconnect", ())
        self.disconnected = True

    def isProgramRunning(self):
        # Reads the "program running" bit of robot_status_bits; sends no command.
        self.ur._record("isProgramRunning", ())
        return self.ur._state("program_running")

    def reuploadScript(self):
        # rtde_control_interface.cpp 850-875: a running script is stopped first, then
        # script_client_->sendScript(); it returns whether the script was *sent* and does
        # not wait for it to run. A controller that cannot run programs does not start it.
        self.ur._record("reuploadScript", ())
        if not self.ur.link_up:
            raise RuntimeError("Please connect to the controller before calling sendScript()")
        with self.ur._lock:  # in Local mode the controller ignores scripts sent over the network
            self.ur._end_script()
            if self.ur._can_run_script() and not self.ur.control_unavailable:
                self.ur._start_script()
        return True

    def setTcp(self, pose):
        if not self._command("setTcp", (list(pose),)):
            return False
        with self.ur._lock:
            self.ur.controller_tcp = list(pose)  # the flange stays: the reported TCP pose moves
        return True

    def getTCPOffset(self):
        # 1.6.5 throws "getTCPOffset() function did not succeed!" when its command is not
        # answered (the string is in the installed rtde_control .so).
        if not self._command("getTCPOffset", ()):
            raise RuntimeError("getTCPOffset() function did not succeed!")
        return list(self.ur.controller_tcp)

    def setPayload(self, mass, cog):
        if not self._command("setPayload", (mass, list(cog))):
            return False
        self.ur.payload = (float(mass), [float(v) for v in cog])
        return True

    def setWatchdog(self, min_frequency=10.0):
        # Script cmd 35: rtde_set_watchdog("input_int_register_0", min_frequency, "stop").
        if not self._command("setWatchdog", (min_frequency,)):
            return False
        self.ur.watchdog_period_s = 1.0 / float(min_frequency)
        return True

    def kickWatchdog(self):
        # A WATCHDOG command: sendCommand sends it without waiting (a "continuous" command),
        # after the same refusals, and reconnects and resends it like any other.
        return self._command("kickWatchdog", ())

    def isPoseWithinSafetyLimits(self, pose):
        # rtde_control_interface.cpp: `if (sendCommand(robot_cmd)) return getOutputIntReg(1) == 1;
        # else return false;` - false whenever the command cannot be sent, whatever the pose.
        return self._command("isPoseWithinSafetyLimits", (list(pose),)) and self.ur.within_safety_limits

    def getInverseKinematicsHasSolution(self, pose, qnear=(), max_position_error=1e-10, max_orientation_error=1e-10):
        # 1.6.5 throws "getInverseKinematicsHasSolution() function did not succeed!" when the
        # command fails (string in the installed .so).
        if not self._command("getInverseKinematicsHasSolution", (list(pose),)):
            raise RuntimeError("getInverseKinematicsHasSolution() function did not succeed!")
        return self.ur.has_ik

    def getInverseKinematics(self, pose, qnear=(), max_position_error=1e-10, max_orientation_error=1e-10):
        # rtde_control_interface.cpp: an empty vector when sendCommand fails.
        if not self._command("getInverseKinematics", (list(pose),)) or not self.ur.has_ik:
            return []
        return [0.1, -1.2, 1.5, -1.9, -1.57, 0.0]

    def getAsyncOperationProgress(self):
        # Reads output_int_register_2 from the robot state; sends no command.
        self.ur._record("getAsyncOperationProgress", ())
        return self.ur._state("progress")

    def moveL(self, pose, speed=0.25, acceleration=1.2, asynchronous=False):
        # A MOVEL command through sendCommand: false in every state it refuses; sent again
        # after ur_rtde's own reconnect.
        if not self._command("moveL", (list(pose), speed, acceleration, asynchronous)) \
                or self.ur.robot_mode != RUNNING:
            return False
        self.ur._start_motion(pose, speed, self)
        return True

    def stopL(self, a=10.0, asynchronous=False):
        # `void stopL(double a, bool asynchronous)`: a STOPL command through sendCommand,
        # its result dropped: without a running script nothing is sent and nothing happens.
        if self._command("stopL", (a, asynchronous)):
            self.ur._stop_motion()


class FakeReceive:
    """RTDEReceiveInterface's methods the adapter uses: robot state, no commands, so they
    answer in every robot and safety state, from the cached state during a link loss."""

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
        return self.ur._state("force")

    def getActualTCPPose(self):
        self.ur._record("getActualTCPPose", ())
        return self.ur._state("tcp_pose")

    def getActualQ(self):
        self.ur._record("getActualQ", ())
        return self.ur._state("q")

    def getRobotMode(self):
        self.ur._record("getRobotMode", ())
        return self.ur._state("robot_mode")

    def getSafetyMode(self):
        self.ur._record("getSafetyMode", ())
        return self.ur._state("safety_mode")

    def getTargetSpeedFraction(self):
        self.ur._record("getTargetSpeedFraction", ())
        return self.ur._state("speed_slider")


def _matrix(ur_pose) -> np.ndarray:
    X = np.eye(4)
    X[:3, :3] = Rotation.from_rotvec(ur_pose[3:6]).as_matrix()
    X[:3, 3] = ur_pose[:3]
    return X


def _ur_pose(X) -> list:
    return [float(v) for v in X[:3, 3]] + [float(v) for v in Rotation.from_matrix(X[:3, :3]).as_rotvec()]
