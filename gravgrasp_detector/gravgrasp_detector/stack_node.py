"""`ros2 run gravgrasp_detector stack`: the tsdf, detect and execute nodes in one
process, for deployment (one process to supervise; volumes and grasps still travel
as ROS messages, so each node behaves exactly as when run alone).

Parameters go to a node by name: `--ros-args -p detect:model_path:=models/x.pt
-p execute:gripper_port:=/dev/ttyUSB0 -p tsdf:camera_frame_pose:=[...]`.
"""
import sys

import rclpy
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor

from .detect_node import DetectNode
from .execute_node import ExecuteNode
from .model_file import ModelFileError
from .tsdf import InputError
from .tsdf_node import TSDFNode


def main(args=None):
    rclpy.init(args=args)
    nodes = []
    try:
        for make in (TSDFNode, DetectNode, ExecuteNode):
            nodes.append(make())
    except (InputError, ModelFileError, ValueError, OSError) as err:
        print(f"stack: cannot start: {err}", file=sys.stderr)
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
        return 2
    executor = MultiThreadedExecutor(num_threads=6)
    for node in nodes:
        executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
