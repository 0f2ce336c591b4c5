"""The ROS edge every node of the project shares: geometry_msgs poses <-> 4x4 matrices,
a request's deadline on the monotonic clock, parameter descriptors, and (from robotiq_driver.node_process, the one copy every package's
nodes use) `run_node`, which starts, spins and shuts a node down.
"""

from __future__ import annotations

import time

from geometry_msgs.msg import Pose, PoseStamped
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from robotiq_driver.node_process import run_node, shut_down, spin  # noqa: F401  (re-exported for the nodes)

from ..poses import matrix_from_pose, pose_from_matrix

# -- poses ---------------------------------------------------------------------------


def matrix_from_pose_msg(pose: Pose):
    """geometry_msgs/Pose -> 4x4; raises poses.PoseError (not finite, not a unit quaternion)."""
    p, q = pose.position, pose.orientation
    return matrix_from_pose((p.x, p.y, p.z), (q.x, q.y, q.z, q.w))


def pose_msg_from_matrix(X, pose: Pose | None = None) -> Pose:
    """4x4 -> geometry_msgs/Pose (filled in place when `pose` is given)."""
    pose = Pose() if pose is None else pose
    (pose.position.x, pose.position.y, pose.position.z), (
        pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w) = pose_from_matrix(X)
    return pose


def pose_stamped_from_matrix(X, stamp, frame_id: str) -> PoseStamped:
    msg = PoseStamped()
    msg.header.stamp, msg.header.frame_id = stamp, frame_id
    pose_msg_from_matrix(X, msg.pose)
    return msg


def stamp_s(stamp) -> float:
    """builtin_interfaces/Time -> seconds."""
    return stamp.sec + stamp.nanosec * 1e-9


def monotonic_deadline(stamp, clock) -> float | None:
    """A request's deadline (a builtin_interfaces/Time on `clock`, the node's ROS clock;
    0 = none) on time.monotonic's clock, or None: what the arm services compare against."""
    deadline_ns = stamp.sec * 1_000_000_000 + stamp.nanosec
    if deadline_ns == 0:
        return None
    return time.monotonic() + (deadline_ns - clock.now().nanoseconds) * 1e-9


# -- parameters ----------------------------------------------------------------------


def described(description: str, read_only: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(description=description, read_only=read_only)


def float_range(description: str, low: float, high: float, read_only: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(description=description, read_only=read_only,
                               floating_point_range=[FloatingPointRange(from_value=float(low), to_value=float(high))])


def int_range(description: str, low: int, high: int, step: int = 1, read_only: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(description=description, read_only=read_only,
                               integer_range=[IntegerRange(from_value=int(low), to_value=int(high), step=int(step))])
