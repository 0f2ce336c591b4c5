"""`ros2 run gravgrasp_detector stack`: the tsdf, detect and execute nodes in one process,
for deployment (one process to supervise; volumes and grasps still travel as ROS
messages, so each node behaves exactly as when run alone), and, for a UR arm, ur_arm as a
child process the stack supervises (arm_process.py): a crash of ur_rtde's native library
ends only it; the executor is told at once, disarms, and the stack starts ur_arm again.

    ros2 run gravgrasp_detector stack --ros-args --params-file cell.yaml

One parameter file describes the cell (samples: share/gravgrasp_detector/cells/); its
`stack` section holds what concerns several nodes (see cell_config.py):

| parameter | |
| --- | --- |
| `arm_adapter` | `service` (default: move_to_pose comes from another process, e.g. the sim bridge) or `ur` (the stack runs ur_arm as its own child process) |
| `arm_command` | the arm adapter's command for `arm_adapter: ur` (empty: the installed `ur_arm`); it gets the stack's ROS arguments |
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
from .arm_process import ArmProcess, exit_words
from .cell_config import CellConfigError, check_consistency, load_sections, params_files, plan, unknown_parameters
from .detect_node import DetectNode
from .execute_node import ExecuteNode
from .interface import described, shut_down, spin
from .tsdf_node import TSDFNode
from .ur_arm_node import URArmNode

STACK_PARAMETERS = {
    "arm_adapter": ("service", "'service': move_to_pose is served by another process (sim bridge, your adapter); "
                               "'ur': the UR adapter (ur_arm) runs as a child process of the stack"),
    "workspace_origin_in_base": ([0.0, 0.0, 0.0, 0.0], "task frame origin (workspace corner) in the robot base frame: "
                                                       "x, y, z [m], yaw [rad]; all zeros = not given"),
    "object_mass_kg": (0.0, "heaviest object expected, kg; > 0 sets detect.min_score_n"),
    "score_safety_factor": (1.5, "detect.min_score_n = object_mass_kg x 9.81 x this"),
    "check_parameters": (True, "refuse to start when the parameter file gives a node a parameter it does not declare"),
    "arm_command": ("", "for arm_adapter 'ur': the arm adapter's command line (words separated by spaces); empty = "
                        "the installed ur_arm; it gets the stack's ROS arguments"),
}


def arm_command(stack, args, overrides) -> list[str]:
    """The child's command line: the adapter, then the stack's ROS arguments (the cell file
    reaches it under its node name, ur_arm) and the derived parameters."""
    command = stack["arm_command"].split()
    if not command:
        from ament_index_python.packages import get_package_prefix  # lazy: only a UR cell needs it
        command = [os.path.join(get_package_prefix("gravgrasp_detector"), "lib", "gravgrasp_detector", "ur_arm")]
    ros_args = list(args[1:])
    if overrides:
        ros_args += ["--ros-args"] + list(overrides)
    return command + ros_args


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
    nodes, arm = [], None
    try:
        files = params_files(args)
        sections = load_sections(files)
        stack = stack_settings(args)
        cell = plan(stack, sections, str(files[-1]) if files else "cell.yaml")
        # Derived parameters go last on the command line, where they win over the file.
        rclpy.init(args=args + (["--ros-args"] + cell.overrides if cell.overrides else []))
        for make in (TSDFNode, DetectNode, ExecuteNode):
            nodes.append(make())
        by_name = {node.get_name(): node for node in nodes}
        declared = {name: set(node.get_parameters_by_prefix("")) for name, node in by_name.items()}
        if cell.arm_adapter == "ur":
            # Built here only to check its parameters (a bad one stops the start with one line,
            # as before); it runs in its own process.
            checked = URArmNode(connect=lambda receive=None: (None, receive, "parameter check only"),
                                parameters_only=True)
            nodes.append(checked)
            declared["ur_arm"] = set(checked.get_parameters_by_prefix(""))
            by_name["ur_arm"] = checked
            if not stack["arm_command"] and not checked.robot_ip:
                raise ValueError("ur_arm.robot_ip is empty: set it to the UR controller's address in the cell file")
        unknown = unknown_parameters(sections, declared)
        if unknown and stack["check_parameters"]:
            raise CellConfigError(f"the parameter file gives {', '.join(unknown)}, which no node of the stack declares "
                                  "(a typo?); fix the name, or set stack.check_parameters: false")
        execute = by_name["execute"]
        ur = by_name.get("ur_arm")
        check_consistency({n: execute.get_parameter(n).value for n in ("arm_base_xyz_yaw", "tcp_offset_m")},
                          None if ur is None else {n: ur.get_parameter(n).value for n in ("base_xyz_yaw", "tcp_in_flange")})
        if ur is not None:
            nodes.remove(ur)
            ur.close()
            ur.destroy_node()
            arm = ArmProcess(arm_command(stack, args, cell.overrides), execute.arm_started,
                             lambda pid, code: execute.arm_exited(pid, exit_words(code)))
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
    if arm is not None:
        arm.start()
    try:
        return spin(nodes, threads=6)
    finally:
        if arm is not None:
            arm.stop()


if __name__ == "__main__":
    sys.exit(main())
