"""One parameter file for the cell: what `stack` derives from it and checks in it. No rclpy.

A cell file is an ordinary ROS 2 `--params-file` YAML with a section per node (`tsdf`,
`detect`, `execute`, `ur_arm`, `sim`, `calibrate_camera`, ...) plus a `stack` section
for what concerns several nodes at once:

    stack:
      ros__parameters:
        arm_adapter: ur                # 'service' (move_to_pose served by another process:
                                       # the sim bridge, your own adapter) or 'ur' (ur_arm in the stack)
        workspace_origin_in_base: [0.35, -0.15, 0.02, 1.5708]   # the task frame's origin (the
                                       # workspace corner) in the robot base frame: x, y, z [m],
                                       # yaw [rad], as the pendant shows the TCP touching it
        object_mass_kg: 0.5            # heaviest object expected -> detect.min_score_n
        score_safety_factor: 1.5       # min_score_n = mass x g x factor

Derived: `workspace_origin_in_base` -> `execute.arm_base_xyz_yaw` and
`ur_arm.base_xyz_yaw` (the robot base in the task frame, its inverse), so the one
measurement feeds both; `object_mass_kg` -> `detect.min_score_n`. Giving a derived
parameter directly as well is a conflict, refused with a sentence.

The camera: calibrate_camera stores a fixed (eye-to-hand) camera in the robot base frame,
`ur_arm.camera_in_base`, which no re-measuring of the workspace origin changes; the stack
composes the tsdf node's `camera_pose` (task frame) from it and `workspace_origin_in_base`
at start-up. A file with the old form, `tsdf.camera_pose` written by hand or by an older
calibrate_camera, still works, with one warning saying how to convert it
(`convert_camera_pose`, run by `calibrate_camera -p convert:=true`).
"""
from __future__ import annotations

import dataclasses
import math
import pathlib

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from ..execution.ur_arm_settings import xyz_yaw_to_matrix  # X_base_task from workspace_origin_in_base
from ..poses import PoseError, xyz_quat_to_matrix

G_MPS2 = 9.81
ARM_ADAPTERS = ("service", "ur")


class CellConfigError(ValueError):
    """A cell file problem; the message says what to change."""


def params_files(argv) -> list[pathlib.Path]:
    """The --params-file paths among ROS arguments."""
    out, ros = [], False
    for i, arg in enumerate(argv):
        if arg == "--ros-args":
            ros = True
        elif arg == "--":
            ros = False
        elif ros and arg == "--params-file" and i + 1 < len(argv):
            out.append(pathlib.Path(argv[i + 1]))
    return out


def _flatten(values: dict, prefix: str = "") -> dict:
    out = {}
    for key, value in values.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(_flatten(value, name + "."))
        else:
            out[name] = value
    return out


def load_sections(paths) -> dict:
    """{node name: {parameter: value}} over all files (later files win), node names
    without a leading '/'; wildcard sections ('/**') are kept under '**'."""
    sections: dict = {}
    for path in paths:
        try:
            data = yaml.safe_load(pathlib.Path(path).read_text()) or {}
        except FileNotFoundError:
            raise CellConfigError(f"parameter file {path} does not exist") from None
        except yaml.YAMLError as e:
            raise CellConfigError(f"parameter file {path} is not valid YAML: {e}") from None
        if not isinstance(data, dict):
            raise CellConfigError(f"parameter file {path}: expected 'node_name: ros__parameters: ...' sections")
        for node, body in data.items():
            name = str(node).lstrip("/")
            params = (body or {}).get("ros__parameters") if isinstance(body, dict) else None
            if not isinstance(params, dict):
                raise CellConfigError(f"parameter file {path}: section {node!r} has no 'ros__parameters:' mapping")
            sections.setdefault(name, {}).update(_flatten(params))
    return sections


def base_in_task(workspace_origin_in_base) -> list[float]:
    """[x, y, z, yaw] of the task origin in the base frame -> the base in the task frame."""
    x, y, z, yaw = (float(v) for v in workspace_origin_in_base)
    c, s = math.cos(yaw), math.sin(yaw)
    # X_task_base = inv(X_base_task): rotation -yaw, translation -R^T p
    return [-(c * x + s * y), -(-s * x + c * y), -z, -yaw]


def _pose_matrix(name: str, values) -> np.ndarray:
    values = [float(v) for v in values]
    try:
        return xyz_quat_to_matrix(values)
    except PoseError:
        raise CellConfigError(f"{name} must be [x, y, z (m), qx, qy, qz, qw] with a unit quaternion, got {values}") from None


def _xyz_quat(X) -> list:
    return [round(float(v), 6) for v in (*X[:3, 3], *Rotation.from_matrix(X[:3, :3]).as_quat(canonical=True))]


def camera_in_task(workspace_origin_in_base, camera_in_base) -> list:
    """tsdf.camera_pose (task frame) from the camera in the base frame."""
    X_base_camera = _pose_matrix("ur_arm.camera_in_base", camera_in_base)
    return _xyz_quat(np.linalg.inv(xyz_yaw_to_matrix(workspace_origin_in_base)) @ X_base_camera)


def convert_camera_pose(sections: dict) -> list:
    """ur_arm.camera_in_base from an old-form tsdf.camera_pose and the file's
    workspace_origin_in_base (right only if that origin is the one it was calibrated with)."""
    origin = list(sections.get("stack", {}).get("workspace_origin_in_base", []))
    pose = sections.get("tsdf", {}).get("camera_pose")
    if pose is None:
        raise CellConfigError("the cell file has no tsdf.camera_pose: nothing to convert")
    if len(origin) != 4 or not any(origin):
        raise CellConfigError("the cell file has no stack.workspace_origin_in_base: without it the task-frame "
                              "camera_pose cannot be put in the base frame; calibrate again (bring-up step 5)")
    return _xyz_quat(xyz_yaw_to_matrix(origin) @ _pose_matrix("tsdf.camera_pose", pose))


CONVERT_HINT = ("convert it once, while stack.workspace_origin_in_base is still the one it was calibrated with: "
                "ros2 run gravgrasp_detector calibrate_camera --ros-args -p convert:=true -p cell_file:={file} "
                "(writes ur_arm.camera_in_base, removes tsdf.camera_pose); if the origin was measured again "
                "since, calibrate again (README bring-up step 5)")


@dataclasses.dataclass
class StackPlan:
    arm_adapter: str
    overrides: list            # ['-p', 'node:name:=value', ...] appended to the ROS arguments
    notes: list                # one line each, logged at start
    warnings: list = dataclasses.field(default_factory=list)  # one line each, logged as warnings


def _fmt(value) -> str:
    if isinstance(value, list):
        return "[" + ",".join(repr(float(v)) for v in value) + "]"
    return repr(float(value))


def plan(stack: dict, sections: dict, cell_file: str = "cell.yaml") -> StackPlan:
    """Derived parameters and conflicts from the stack section's values (as declared by
    the stack node: arm_adapter, workspace_origin_in_base, object_mass_kg, score_safety_factor)
    and the file's sections; `cell_file` names the file in what to run."""
    adapter = stack["arm_adapter"]
    if adapter not in ARM_ADAPTERS:
        raise CellConfigError(f"stack.arm_adapter is {adapter!r}: use 'service' (another process serves move_to_pose, "
                              "e.g. the sim bridge) or 'ur' (the UR adapter runs in the stack)")
    overrides, notes = [], []
    origin = list(stack["workspace_origin_in_base"])
    if any(origin):
        if len(origin) != 4 or not all(math.isfinite(v) for v in origin):
            raise CellConfigError(f"stack.workspace_origin_in_base must be [x, y, z (m), yaw (rad)], got {origin}")
        for node, name in (("execute", "arm_base_xyz_yaw"), ("ur_arm", "base_xyz_yaw")):
            if name in sections.get(node, {}):
                raise CellConfigError(f"{node}.{name} and stack.workspace_origin_in_base both place the robot: "
                                      f"keep one (workspace_origin_in_base sets {node}.{name})")
        base = base_in_task(origin)
        overrides += ["-p", f"execute:arm_base_xyz_yaw:={_fmt(base)}", "-p", f"ur_arm:base_xyz_yaw:={_fmt(base)}"]
        notes.append(f"workspace origin {origin} in the base frame -> robot base {np.round(base, 4).tolist()} "
                     "(x, y, z, yaw) in the task frame for execute and ur_arm")
    warnings = _camera(origin, sections, overrides, notes, cell_file)
    mass, factor = float(stack["object_mass_kg"]), float(stack["score_safety_factor"])
    if mass > 0:
        if "min_score_n" in sections.get("detect", {}):
            raise CellConfigError("detect.min_score_n and stack.object_mass_kg both set the score threshold: keep one")
        if factor < 1.0:
            raise CellConfigError(f"stack.score_safety_factor {factor} is below 1: a grasp must hold at least the weight")
        min_score = mass * G_MPS2 * factor
        overrides += ["-p", f"detect:min_score_n:={_fmt(min_score)}"]
        notes.append(f"object mass {mass:g} kg x {G_MPS2} m/s^2 x {factor:g} -> detect.min_score_n {min_score:.2f} N")
    elif mass < 0:
        raise CellConfigError(f"stack.object_mass_kg is {mass}: give the heaviest object's mass in kg (0 = no threshold from it)")
    return StackPlan(adapter, overrides, notes, warnings)


def _camera(origin, sections, overrides, notes, cell_file) -> list:
    """tsdf.camera_pose composed from ur_arm.camera_in_base; the warnings for the old form."""
    tsdf, ur = sections.get("tsdf", {}), sections.get("ur_arm", {})
    camera = list(ur.get("camera_in_base", []))
    if not any(camera):
        if "camera_pose" in tsdf and tsdf.get("camera_pose_source") == "parameter":
            return ["tsdf.camera_pose is a fixed camera in the task frame (the old form): a re-measured "
                    "stack.workspace_origin_in_base would leave it wrong; " + CONVERT_HINT.format(file=cell_file)]
        return []
    if not any(origin):
        raise CellConfigError("ur_arm.camera_in_base (the camera in the robot base frame) needs "
                              "stack.workspace_origin_in_base to place it in the task frame: measure it (bring-up step 4)")
    if "camera_pose" in tsdf:
        raise CellConfigError("ur_arm.camera_in_base and tsdf.camera_pose both place the camera: delete "
                              "tsdf.camera_pose (the stack composes it from camera_in_base and the workspace origin)")
    if tsdf.get("camera_pose_source", "parameter") != "parameter":
        raise CellConfigError(f"ur_arm.camera_in_base is a fixed camera but tsdf.camera_pose_source is "
                              f"{tsdf['camera_pose_source']!r}: set it to 'parameter' (or delete camera_in_base "
                              "for a camera on the wrist)")
    pose = camera_in_task(origin, camera)
    overrides += ["-p", "tsdf:camera_pose_source:=parameter", "-p", f"tsdf:camera_pose:={_fmt(pose)}"]
    when = ur.get("calibration_date")
    notes.append(f"camera {[round(float(v), 4) for v in camera]} in the base frame"
                 f"{' (calibrated ' + str(when) + ')' if when else ''} -> tsdf.camera_pose "
                 f"{[round(v, 4) for v in pose]} in the task frame")
    return []


def check_consistency(execute_params: dict, ur_params: dict | None) -> None:
    """With the UR adapter in the stack: the executor's arm model must be the arm's."""
    if ur_params is None:
        return
    base_e, base_u = execute_params["arm_base_xyz_yaw"], ur_params["base_xyz_yaw"]
    if not np.allclose(base_e, base_u, atol=1e-6):
        raise CellConfigError(f"execute.arm_base_xyz_yaw {list(base_e)} and ur_arm.base_xyz_yaw {list(base_u)} differ: "
                              "they are the same robot base (set stack.workspace_origin_in_base to give it once)")
    tcp_e, tcp_u = execute_params["tcp_offset_m"], ur_params["tcp_in_flange"]
    if abs(tcp_e - tcp_u[2]) > 1e-3 or any(abs(v) > 1e-3 for v in tcp_u[:2]):
        raise CellConfigError(f"execute.tcp_offset_m {tcp_e} (the reachability model's flange -> TCP distance) and "
                              f"ur_arm.tcp_in_flange {list(tcp_u)} disagree: set both to the gripper's TCP "
                              "(2F-85: 0.1558 m along the flange z)")


def unknown_parameters(sections: dict, declared: dict) -> list[str]:
    """'node.name' for each parameter the file gives a node of this process that the node
    does not declare (a typo would otherwise be ignored silently)."""
    out = []
    for node, names in declared.items():
        for name in sections.get(node, {}):
            if name not in names and not name.startswith("qos_overrides."):
                out.append(f"{node}.{name}")
    return out
