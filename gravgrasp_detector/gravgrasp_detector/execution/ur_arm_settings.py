"""What a UR arm adapter (`ur_arm.URArm`) is set up with: where the robot's base sits in
the task frame, the TCP in the flange frame, the protective TCP box, speeds,
accelerations, timeouts, the watchdog, arrival tolerances and the contact stop (`URArmSettings`), and the base pose
parameter `[x, y, z, yaw]` as a transform (`xyz_yaw_to_matrix`). No rclpy, no ur_rtde.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.spatial.transform import Rotation

FLANGE_TO_TCP_2F85_M = 0.1558  # robotiq_driver.hand_geometry.FLANGE_TO_TCP_M (kept in sync by a test)


@dataclasses.dataclass
class URArmSettings:
    X_task_base: np.ndarray = dataclasses.field(default_factory=lambda: np.eye(4))
    tcp_in_flange: tuple = (0.0, 0.0, FLANGE_TO_TCP_2F85_M, 0.0, 0.0, 0.0)  # UR pose, set with setTcp
    # Protective box, task frame: the hand (TCP, flange, the open 2F-85's hull) must stay in it
    # at the start, along moveL's straight line and at the target.
    workspace_min_m: tuple = (-0.10, -0.10, 0.0)
    workspace_max_m: tuple = (0.40, 0.40, 0.80)
    default_speed_mps: float = 0.05     # a request's speed 0 means this
    max_speed_mps: float = 0.25         # faster requests are capped to this
    acceleration_mps2: float = 0.5      # moveL tool acceleration
    stop_deceleration_mps2: float = 2.0  # stopL tool deceleration
    call_timeout_s: float = 2.0          # any single RTDE call
    connect_timeout_s: float = 15.0      # building the interfaces (uploads the control script)
    motion_timeout_margin_s: float = 5.0  # on top of the expected motion time
    position_tolerance_m: float = 0.002   # arrived = this close to the target ...
    orientation_tolerance_deg: float = 1.0  # ... and this well aligned
    poll_period_s: float = 0.02          # motion polling, and the watchdog kicks
    # RTDE watchdog (setWatchdog before every motion, kicked every poll_period_s): when the
    # controller hears nothing for this long, it stops ur_rtde's control script and with
    # it the motion. 0.5 s is 2.5 cm at 0.05 m/s; 25 kicks fit in it, so a Python process
    # that shares its cores (a GIL handoff, a call ahead of the kick) does not trip it.
    watchdog_period_s: float = 0.5
    # Between requests the TCP may drift this much before ur_arm calls it a motion nobody
    # asked for (a command ur_rtde sent again after its own reconnect): stopL and latch.
    idle_motion_limit_m: float = 0.002
    payload_kg: float = 0.0              # > 0: setPayload(payload_kg, payload_cog_m) on connect
    payload_cog_m: tuple = (0.0, 0.0, 0.0)
    # A motion stops when the magnitude of the controller's TCP force (getActualTCPForce)
    # rises this much above its value when the motion began: the sim stand-in's
    # max_contact_force_n, the limit the benchmark's attempts ran under. 0 = off.
    contact_force_limit_n: float = 60.0
    # Monitoring only (no setTcp): the controller's TCP, from the nominal kinematics of the
    # joint angles, must be within this of tcp_in_flange for a flange pose to be given. A
    # wrong TCP is centimetres or a turn off; the nominal kinematics are millimetres off the
    # robot's calibrated ones, so not tighter.
    tcp_check_tolerance_m: float = 0.005
    tcp_check_tolerance_deg: float = 1.0

    def check(self):
        """Raise ValueError naming the first bad setting."""
        X = np.asarray(self.X_task_base, float)
        if X.shape != (4, 4) or not np.isfinite(X).all() or not np.allclose(X[:3, :3] @ X[:3, :3].T, np.eye(3), atol=1e-6):
            raise ValueError("X_task_base must be a finite 4x4 rigid transform")
        if len(self.tcp_in_flange) != 6 or not all(math.isfinite(v) for v in self.tcp_in_flange):
            raise ValueError(f"tcp_in_flange must be 6 finite numbers [x, y, z, rx, ry, rz], got {list(self.tcp_in_flange)}")
        lo, hi = np.asarray(self.workspace_min_m, float), np.asarray(self.workspace_max_m, float)
        if lo.shape != (3,) or hi.shape != (3,) or not (np.isfinite(lo).all() and np.isfinite(hi).all()) or (lo >= hi).any():
            raise ValueError(f"protective box: workspace_min_m {list(lo)} must be below workspace_max_m {list(hi)} on every axis (3 numbers each, m)")
        for name in ("default_speed_mps", "max_speed_mps", "acceleration_mps2", "stop_deceleration_mps2",
                     "call_timeout_s", "connect_timeout_s", "position_tolerance_m", "orientation_tolerance_deg",
                     "poll_period_s", "watchdog_period_s", "tcp_check_tolerance_m", "tcp_check_tolerance_deg",
                     "idle_motion_limit_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be > 0, got {value}")
        if self.default_speed_mps > self.max_speed_mps:
            raise ValueError(f"default_speed_mps {self.default_speed_mps} exceeds max_speed_mps {self.max_speed_mps}")
        if self.watchdog_period_s < 3 * self.poll_period_s:
            raise ValueError(f"watchdog_period_s {self.watchdog_period_s} must be at least 3 poll periods "
                             f"({3 * self.poll_period_s:g} s): the watchdog would trip between kicks")
        if self.motion_timeout_margin_s < 0:
            raise ValueError("motion_timeout_margin_s must be >= 0")
        if not (math.isfinite(self.contact_force_limit_n) and self.contact_force_limit_n >= 0):
            raise ValueError(f"contact_force_limit_n must be >= 0 N (0 = off), got {self.contact_force_limit_n}")


def xyz_yaw_to_matrix(xyz_yaw) -> np.ndarray:
    """[x, y, z, yaw] (the executor's `arm_base_xyz_yaw`) -> 4x4: a base mounted upright."""
    if len(xyz_yaw) != 4 or not all(math.isfinite(v) for v in xyz_yaw):
        raise ValueError(f"base pose must be 4 finite numbers [x, y, z (m), yaw (rad)], got {list(xyz_yaw)}")
    x, y, z, yaw = (float(v) for v in xyz_yaw)
    X = np.eye(4)
    X[:3, :3] = Rotation.from_euler("z", yaw).as_matrix()
    X[:3, 3] = (x, y, z)
    return X
