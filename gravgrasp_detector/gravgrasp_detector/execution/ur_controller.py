"""The UR controller as ur_rtde presents it (ur-rtde 1.6.5): its robot and safety mode
codes, its pose format [x, y, z, rx, ry, rz] (metres, rotation vector in radians) with
the conversions to 4x4 transforms and the error between two poses, and `CallThread`,
which runs one connection's RTDE calls so that a call that never returns cannot hang
the caller. No rclpy, no ur_rtde import.
"""
from __future__ import annotations

import concurrent.futures
import itertools
import queue
import threading

import numpy as np
from scipy.spatial.transform import Rotation

# ur_rtde's RTDEReceiveInterface.getRobotMode() and getSafetyMode() values (UR manual).
ROBOT_MODES = {-1: "NO_CONTROLLER", 0: "DISCONNECTED", 1: "CONFIRM_SAFETY", 2: "BOOTING", 3: "POWER_OFF",
               4: "POWER_ON", 5: "IDLE", 6: "BACKDRIVE", 7: "RUNNING", 8: "UPDATING_FIRMWARE"}
ROBOT_MODE_RUNNING = 7
SAFETY_MODES = {1: "NORMAL", 2: "REDUCED", 3: "PROTECTIVE_STOP", 4: "RECOVERY", 5: "SAFEGUARD_STOP",
                6: "SYSTEM_EMERGENCY_STOP", 7: "ROBOT_EMERGENCY_STOP", 8: "VIOLATION", 9: "FAULT",
                10: "VALIDATE_JOINT_ID", 11: "UNDEFINED_SAFETY_MODE", 12: "AUTOMATIC_MODE_SAFEGUARD_STOP",
                13: "SYSTEM_THREE_POSITION_ENABLING_STOP"}
SAFETY_MODES_THAT_MOVE = (1, 2)  # NORMAL, REDUCED (reduced limits still allow motion)
PROTECTIVE_STOP = 3

# What a person at the pendant does about each stop: the safety mode is the cause (an
# emergency stop also powers the arm off, so the robot mode alone would hide it).
_SAFETY_ACTIONS = {
    3: "protective stop: find what the arm hit or why it stopped (the pendant's log), unlock it on the teach "
       "pendant, then send the request again (ur_arm restarts its control script by itself)",
    4: "safety RECOVERY mode: the arm is beyond a safety limit; jog it back inside the limits on the teach pendant",
    5: "safeguard stop: a safeguard input is open (door, light curtain); close it and reset it on the teach pendant",
    6: "system emergency stop: make the cell safe, release the emergency stop, reset it on the teach pendant, power "
       "the arm on and release the brakes (ur_arm restarts its control script by itself)",
    7: "robot emergency stop: make the cell safe, release the emergency stop button, reset it on the teach pendant, "
       "power the arm on and release the brakes (ur_arm restarts its control script by itself)",
    8: "safety VIOLATION: the safety system found a limit or checksum violation; read the pendant's log, fix the "
       "cause and restart the safety system as the pendant says",
    9: "safety FAULT: the safety system reports a fault; read the pendant's log, power-cycle the controller if it says so",
    12: "automatic-mode safeguard stop: close the safeguard and reset it on the teach pendant",
    13: "three-position enabling stop: hold the enabling device in its middle position, or leave manual mode",
}
_ROBOT_ACTIONS = {
    -1: "no controller: the controller is not running; start it", 0: "the controller is disconnected from the arm",
    1: "confirm the safety configuration on the teach pendant", 2: "the controller is booting: wait",
    3: "power the arm on and release the brakes on the teach pendant",
    4: "the arm is powering on: release the brakes on the teach pendant",
    5: "release the brakes on the teach pendant", 6: "leave backdrive mode on the teach pendant",
    8: "the controller is updating firmware: wait",
}


def safety_action(safety_mode: int) -> str:
    """What a person does about a safety mode that stops the arm."""
    return _SAFETY_ACTIONS.get(safety_mode, "clear it on the teach pendant")


def state_refusal(robot_mode: int, safety_mode: int) -> str | None:
    """Why a UR in this robot and safety mode cannot move, and what a person must do; None
    if it can. The safety cause first: an emergency stop is also a powered-off arm."""
    if safety_mode not in SAFETY_MODES_THAT_MOVE:
        return f"{SAFETY_MODES.get(safety_mode, safety_mode)}: {safety_action(safety_mode)}"
    if robot_mode != ROBOT_MODE_RUNNING:
        action = _ROBOT_ACTIONS.get(robot_mode, "make it RUNNING on the teach pendant")
        return f"robot mode is {ROBOT_MODES.get(robot_mode, robot_mode)}, not RUNNING: {action}"
    return None


def matrix_to_ur_pose(X) -> list:
    """4x4 -> [x, y, z, rx, ry, rz] (rotation vector), as ur_rtde takes poses."""
    return [float(v) for v in X[:3, 3]] + [float(v) for v in Rotation.from_matrix(X[:3, :3]).as_rotvec()]


def ur_pose_to_matrix(pose) -> np.ndarray:
    X = np.eye(4)
    X[:3, :3] = Rotation.from_rotvec(pose[3:6]).as_matrix()
    X[:3, 3] = pose[:3]
    return X


def pose_error(actual, target) -> tuple[float, float]:
    """(position error m, orientation error deg) between two UR poses."""
    dp = float(np.linalg.norm(np.subtract(actual[:3], target[:3])))
    R = Rotation.from_rotvec(actual[3:6]).inv() * Rotation.from_rotvec(target[3:6])
    return dp, float(np.degrees(R.magnitude()))


class CallThread:
    """One daemon thread per connection running the RTDE calls in order, except that an
    urgent call (the watchdog's kick) goes ahead of every call still waiting: ur_rtde's
    interfaces take one call at a time, so a kick cannot overtake a call in flight, only
    the queue. A call that never returns leaves only this thread blocked (abandoned with
    the connection); a daemon thread does not keep the process alive."""

    def __init__(self):
        self._calls = queue.PriorityQueue()
        self._order = itertools.count()
        threading.Thread(target=self._run, name="rtde-calls", daemon=True).start()

    def _run(self):
        while True:
            _, _, item = self._calls.get()
            if item is None:
                return
            future, fn, args = item
            if not future.set_running_or_notify_cancel():
                continue
            try:
                future.set_result(fn(*args))
            except BaseException as e:  # handed to the caller
                future.set_exception(e)

    def submit(self, fn, *args, urgent: bool = False) -> concurrent.futures.Future:
        future = concurrent.futures.Future()
        self._calls.put((0 if urgent else 1, next(self._order), (future, fn, args)))
        return future

    def close(self):
        self._calls.put((2, next(self._order), None))
