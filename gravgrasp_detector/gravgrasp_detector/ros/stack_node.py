"""`ros2 run gravgrasp_detector stack`: the tsdf, detect and execute nodes (and, for a
UR arm, ur_arm) in one process, for deployment (one process to supervise; volumes and
grasps still travel as ROS messages, so each node behaves exactly as when run alone).

    ros2 run gravgrasp_detector stack --ros-args --params-file cell.yaml

One parameter file describes the cell (samples: share/gravgrasp_detector/cells/); its
`stack` section holds what concerns several nodes (see cell_config.py):

| parameter | |
| --- | --- |
| `arm_adapter` | `service` (default: move_to_pose comes from another process, e.g. the sim bridge) or `ur` (ur_arm runs in this process) |
| `workspace_origin_in_base` | [x, y, z, yaw] of the task frame's origin in the robot base frame (all zeros = not given); sets execute.arm_base_xyz_yaw and ur_arm.base_xyz_yaw |
| `object_mass_kg` | heaviest object expected (0 = not given); sets detect.min_score_n = mass x 9.81 x `score_safety_factor` |
| `score_safety_factor` | 1.5 |
| `check_parameters` | true: a parameter in the file that its node does not declare (a typo) stops the start |

A fixed camera's calibration, `ur_arm.camera_in_base` (robot base frame), becomes the
tsdf node's `camera_pose` in the task frame through `workspace_origin_in_base`, here at
start-up; a file with the old `tsdf.camera_pose` form starts with one warning saying how
to convert it.

Parameters also go to a node by name on the command line: `--ros-args -p
detect:model_path:=models/x.pt -p execute:gripper_port:=/dev/ttyUSB0`.
"""
import os
import sys

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.node import Node

from ..perception.model_file import ModelFileError
from ..perception.tsdf import InputError
from .cell_config import CellConfigError, check_consistency, load_sections, params_files, plan, unknown_parameters
from .detect_node import DetectNode
from .execute_node import ExecuteNode
from .interface import described, shut_down, spin
from .tsdf_node import TSDFNode
from .ur_arm_node import URArmNode

STACK_PARAMETERS = {
    "arm_adapter": ("service", "'service': move_to_pose is served by another process (sim bridge, your adapter); "
                               "'ur': the UR adapter (ur_arm) runs in this process"),
    "workspace_origin_in_base": ([0.0, 0.0, 0.0, 0.0], "task frame origin (workspace corner) in the robot base frame: "
                                                       "x, y, z [m], yaw [rad]; all zeros = not given"),
    "object_mass_kg": (0.0, "heaviest object expected, kg; > 0 sets detect.min_score_n"),
    "score_safety_factor": (1.5, "detect.min_score_n = object_mass_kg x 9.81 x this"),
    "check_parameters": (True, "refuse to start when the parameter file gives a node a parameter it does not declare"),
}


def stack_settings(args):
    """The `stack` section's values, read by a short-lived node in its own context."""
    context = rclpy.Context()
    rclpy.init(args=args, context=context)
    try:
        node = Node("stack", context=context)
        values = {name: node.declare_parameter(name, default, described(text)).value
                  for name, (default, text) in STACK_PARAMETERS.items()}
        node.destroy_node()
        return values
    finally:
        context.try_shutdown()


def main(args=None):
    args = list(sys.argv if args is None else args)
    nodes = []
    try:
        files = params_files(args)
        sections = load_sections(files)
        stack = stack_settings(args)
        cell = plan(stack, sections, str(files[-1]) if files else "cell.yaml")
        # Derived parameters go last on the command line, where they win over the file.
        rclpy.init(args=args + (["--ros-args"] + cell.overrides if cell.overrides else []))
        makers = [TSDFNode, DetectNode, ExecuteNode]
        if cell.arm_adapter == "ur":
            makers.append(URArmNode)
        for make in makers:
            nodes.append(make())
        by_name = {node.get_name(): node for node in nodes}
        declared = {name: set(node.get_parameters_by_prefix("")) for name, node in by_name.items()}
        unknown = unknown_parameters(sections, declared)
        if unknown and stack["check_parameters"]:
            raise CellConfigError(f"the parameter file gives {', '.join(unknown)}, which no node of the stack declares "
                                  "(a typo?); fix the name, or set stack.check_parameters: false")
        execute = by_name["execute"]
        ur = by_name.get("ur_arm")
        check_consistency({n: execute.get_parameter(n).value for n in ("arm_base_xyz_yaw", "tcp_offset_m")},
                          None if ur is None else {n: ur.get_parameter(n).value for n in ("base_xyz_yaw", "tcp_in_flange")})
    except (CellConfigError, InputError, ModelFileError, ValueError, OSError, ParameterException) as err:
        print(f"stack: cannot start: {err}", file=sys.stderr, flush=True)
        shut_down(nodes)
        return 2
    log = nodes[0].get_logger()
    for note in cell.notes:
        log.info(f"cell: {note}")
    for warning in cell.warnings:
        log.warn(f"cell: {warning}")
    port = execute.get_parameter("gripper_port").value
    if not os.path.exists(port):
        execute.get_logger().warn(
            f"gripper_port {port} does not exist (yet): plug in the 2F-85's USB-RS485 adapter and check "
            "'ls -l /dev/serial/by-id/' (use that stable path), and that this user is in the dialout group")
    return spin(nodes, threads=6 + (2 if cell.arm_adapter == "ur" else 0))


if __name__ == "__main__":
    sys.exit(main())
