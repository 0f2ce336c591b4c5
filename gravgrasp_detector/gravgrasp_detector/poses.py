"""Rigid poses: 4x4 homogeneous matrices <-> (position m, unit quaternion x, y, z, w), as a
pair or as the cell files' list [x, y, z, qx, qy, qz, qw].

The one place the project converts between them; `ros.interface` adds the
geometry_msgs side. Bad input raises `PoseError` with what is wrong; each caller wraps it
in its own error type (a node input problem, a rejected request). No ROS.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

UNIT_QUATERNION_TOLERANCE = 1e-3  # | |q| - 1 | accepted (float32 messages, rounded YAML)


class PoseError(ValueError):
    """A pose that is not finite or whose quaternion is not a unit quaternion."""


def rotation_from_quaternion(quaternion_xyzw) -> np.ndarray:
    """Unit quaternion (x, y, z, w) -> 3x3 rotation; raises PoseError."""
    q = np.asarray(quaternion_xyzw, float)
    if q.shape != (4,) or not np.isfinite(q).all():
        raise PoseError(f"quaternion {np.round(q, 4).tolist()} is not 4 values without NaN or infinite ones (x, y, z, w)")
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > UNIT_QUATERNION_TOLERANCE:
        raise PoseError(f"quaternion {np.round(q, 4).tolist()} has norm {norm:.4f}: not a unit quaternion (x, y, z, w)")
    return Rotation.from_quat(q / norm).as_matrix()


def matrix_from_pose(position_m, quaternion_xyzw) -> np.ndarray:
    """(position, unit quaternion x, y, z, w) -> 4x4; raises PoseError."""
    p = np.asarray(position_m, float)
    if p.shape != (3,) or not np.isfinite(p).all():
        raise PoseError(f"position {np.round(p, 4).tolist()} is not 3 values without NaN or infinite ones")
    X = np.eye(4)
    X[:3, :3] = rotation_from_quaternion(quaternion_xyzw)
    X[:3, 3] = p
    return X


def pose_from_matrix(X) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
    """4x4 -> (position (x, y, z), quaternion (x, y, z, w)) as Python floats."""
    X = np.asarray(X, float)
    q = Rotation.from_matrix(X[:3, :3]).as_quat()
    return tuple(float(v) for v in X[:3, 3]), tuple(float(v) for v in q)


def xyz_quat_to_matrix(values) -> np.ndarray:
    """[x, y, z (m), qx, qy, qz, qw] (a cell file's pose, a calibration result) -> 4x4; raises PoseError."""
    values = list(values)
    if len(values) != 7:
        raise PoseError(f"pose {values} is not 7 values [x, y, z (m), qx, qy, qz, qw]")
    return matrix_from_pose(values[:3], values[3:])


def matrix_to_xyz_quat(X) -> list:
    """4x4 -> [x, y, z (m), qx, qy, qz, qw] as Python floats."""
    position, quaternion = pose_from_matrix(X)
    return [*position, *quaternion]
