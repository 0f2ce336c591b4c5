"""The ROS edge every node of the project shares: geometry_msgs poses <-> 4x4 matrices,
parameter descriptors, and `run_node`, which starts, spins and shuts a node down.

A node's `main` is one line, e.g. `return run_node("tsdf", TSDFNode, InputError)`
(`spin` alone for a process that builds several nodes itself, as `stack` does):
a start-up error in the node's constructor (bad parameter, missing model file) prints one
line, "[FATAL] [<node>]: cannot start: <why>", and the process exits 2; Ctrl-C and an
external shutdown end it with 0 after `node.close()` (if the node has one).
"""

from __future__ import annotations

from geometry_msgs.msg import Pose, PoseStamped
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

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


# -- parameters ----------------------------------------------------------------------


def described(description: str, read_only: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(description=description, read_only=read_only)


def float_range(description: str, low: float, high: float, read_only: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(description=description, read_only=read_only,
                               floating_point_range=[FloatingPointRange(from_value=float(low), to_value=float(high))])


def int_range(description: str, low: int, high: int, step: int = 1, read_only: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(description=description, read_only=read_only,
                               integer_range=[IntegerRange(from_value=int(low), to_value=int(high), step=int(step))])


# -- start-up and shut-down ----------------------------------------------------------


def run_node(name: str, make_node, start_errors=(ValueError,), threads: int | None = None, args=None) -> int:
    """rclpy.init, `make_node()`, spin until Ctrl-C or shutdown, clean up; -> exit code.

    `start_errors`: the exceptions the constructor raises for a bad configuration; they
    end the process with one line and code 2 (anything else is a bug: traceback).
    `threads`: None spins a single-threaded executor, else a MultiThreadedExecutor.
    """
    import rclpy  # lazy: see spin

    rclpy.init(args=args)
    try:
        node = make_node()
    except start_errors as err:
        rclpy.logging.get_logger(name).fatal(f"cannot start: {err}")
        rclpy.try_shutdown()
        return 2
    return spin([node], threads)


def spin(nodes, threads: int | None = None) -> int:
    """Spin `nodes` (rclpy already initialised) until Ctrl-C or shutdown; then
    `close()` each node that has one, destroy them and shut rclpy down; -> 0."""
    # lazy: rclpy; the message conversions above also serve modules that
    # stay rclpy-free (markers).
    import rclpy
    from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor

    executor = SingleThreadedExecutor() if threads is None else MultiThreadedExecutor(num_threads=threads)
    for node in nodes:
        executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        for node in nodes:
            if hasattr(node, "close"):
                node.close()
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
