"""The arm stand-in's straight-line TCP motion: translation along a line, rotation along
the geodesic, on a minimum-jerk profile; and its reach (`check_reachable`)."""

from __future__ import annotations

import math
import threading

import numpy as np
from scipy.spatial.transform import Rotation

from ..physics.scenes import TABLE_HEIGHT_M
from .config import WorldSettings, pose


def _rotvec(R) -> np.ndarray:
    return Rotation.from_matrix(R).as_rotvec()


def _exp(w) -> np.ndarray:
    """Rotation matrix of a rotation vector (Rodrigues; scipy's cost 0.25 ms per step)."""
    angle = math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    if angle < 1e-12:
        return np.eye(3)
    x, y, z = w[0] / angle, w[1] / angle, w[2] / angle
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


def _min_jerk(tau):
    """Position and rate (per unit duration) of the minimum-jerk profile at tau in [0,1]."""
    tau = min(max(tau, 0.0), 1.0)
    return 10 * tau**3 - 15 * tau**4 + 6 * tau**5, 30 * tau**2 - 60 * tau**3 + 30 * tau**4


class Motion:
    """One straight-line TCP motion; `done` is set with `result` = (success, message),
    `stopped_by_contact` and `left_m` (from where the TCP stopped to the goal [m])."""

    PEAK_SPEED_FACTOR = 1.875  # peak / mean speed of the minimum-jerk profile

    def __init__(self, X_start, X_goal, t0_s, speed_mps, angular_speed_rad_s):
        self.X_start, self.X_goal, self.t0_s = np.asarray(X_start, float), np.asarray(X_goal, float), t0_s
        self.force_start_n = 0.0  # |net contact force on the hand| when it began
        self.delta_p = self.X_goal[:3, 3] - self.X_start[:3, 3]
        self.delta_w = _rotvec(self.X_start[:3, :3].T @ self.X_goal[:3, :3])  # in the start frame
        self.length_m = float(np.linalg.norm(self.delta_p))
        self.duration_s = max(self.PEAK_SPEED_FACTOR * self.length_m / speed_mps,
                              self.PEAK_SPEED_FACTOR * float(np.linalg.norm(self.delta_w)) / angular_speed_rad_s,
                              1e-3)
        self.done = threading.Event()
        self.result = None
        self.travelled_m = 0.0
        self.stopped_by_contact = False
        self.left_m = math.nan

    def reference(self, t_s):
        """(X_task_tcp 4x4, v_task [3], w_task [3]) at sim time t_s."""
        s, ds = _min_jerk((t_s - self.t0_s) / self.duration_s)
        R0 = self.X_start[:3, :3]
        X = pose(R0 @ _exp(s * self.delta_w), self.X_start[:3, 3] + s * self.delta_p)
        rate = ds / self.duration_s if 0 <= t_s - self.t0_s <= self.duration_s else 0.0
        return X, rate * self.delta_p, rate * (R0 @ self.delta_w)

    def finished(self, t_s) -> bool:
        return t_s >= self.t0_s + self.duration_s

    def finish(self, success, message, X_stopped=None, by_contact=False):
        """End the motion; `X_stopped`: where the TCP stopped (None: at the goal if
        `success`, else unknown or never started: `left_m` stays NaN)."""
        X = self.X_goal if success else X_stopped
        if X is not None:
            self.left_m = float(np.linalg.norm(self.X_goal[:3, 3] - np.asarray(X)[:3, 3]))
        self.stopped_by_contact = bool(by_contact)
        self.result = (bool(success), message)
        self.done.set()


def check_reachable(X_task_tcp, settings: WorldSettings) -> tuple:
    """(reachable, message): the stand-in reaches a TCP pose inside its workspace box
    and not below the table top."""
    X = np.asarray(X_task_tcp, float)
    if X.shape != (4, 4) or not np.isfinite(X).all():
        return False, "target pose is not a finite 4x4 transform"
    R = X[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        return False, "target rotation is not a proper rotation (normalise the quaternion)"
    p = X[:3, 3]
    if p[2] < TABLE_HEIGHT_M:
        return False, f"target TCP z = {p[2]:.3f} m is below the table top ({TABLE_HEIGHT_M} m)"
    lo, hi = np.asarray(settings.workspace_min_m), np.asarray(settings.workspace_max_m)
    if np.any(p < lo) or np.any(p > hi):
        box = "..".join("(" + ", ".join(f"{v:.2f}" for v in b) + ")" for b in (lo, hi))
        return False, (f"target TCP ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}) m is outside the arm "
                       f"stand-in's workspace {box} m")
    return True, "reachable"
