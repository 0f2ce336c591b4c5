"""UR5e forward kinematics from its nominal Denavit-Hartenberg table. numpy only (no Drake,
no rclpy), so ur_arm can ask it at the state rate.

The table is Universal Robots' published one ("DH parameters for calculations of
kinematics and dynamics"); its frames are the controller's: frame 0 is the robot base as
the pendant shows it (feature Base), frame 6 the tool flange (the TCP with a zero offset).
reachability's Drake model (MuJoCo Menagerie's UR5e) gives the same flange pose to
~1 mm (tests/gravgrasp_detector/test_ur_kinematics.py).

Nominal: every UR is calibrated in the factory and its controller uses that calibration
(getActualTCPPose does); the nominal table can differ from it by millimetres (Universal
Robots' ROS driver docs warn of up to centimetres at the end effector). So this is good for
telling a wrong TCP (centimetres, or a turn) from a right one, not for measuring with.
"""
from __future__ import annotations

import numpy as np

# Per joint: d [m], a [m], alpha [rad] (classic DH: Rz(q) Tz(d) Tx(a) Rx(alpha)).
UR5E_DH = ((0.1625, 0.0, np.pi / 2), (0.0, -0.425, 0.0), (0.0, -0.3922, 0.0),
           (0.1333, 0.0, np.pi / 2), (0.0997, 0.0, -np.pi / 2), (0.0996, 0.0, 0.0))


def flange_in_base(q_rad) -> np.ndarray:
    """Joint positions [rad] (getActualQ) -> X_base_flange (4x4)."""
    q = np.asarray(q_rad, float)
    if q.shape != (6,) or not np.isfinite(q).all():
        raise ValueError(f"a UR5e has 6 joints: got joint positions {np.asarray(q_rad).tolist()}")
    X = np.eye(4)
    for theta, (d, a, alpha) in zip(q, UR5E_DH):
        ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
        X = X @ np.array([[ct, -st * ca, st * sa, a * ct],
                          [st, ct * ca, -ct * sa, a * st],
                          [0.0, sa, ca, d],
                          [0.0, 0.0, 0.0, 1.0]])
    return X
