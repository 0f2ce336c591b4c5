"""One parameter file per cell: the two samples (gravgrasp_detector/cells/) start the
stack; the simulated one picks an object end to end, the UR5e one runs until it needs
the robot and says so. Plus what `stack` derives from and checks in a cell file."""
import math
import pathlib
import re

import numpy as np
import pytest
from gravgrasp_msgs.msg import GraspArray, ObjectStates
from gravgrasp_msgs.srv import ExecuteGrasp, MoveToPose
from std_srvs.srv import SetBool

from scipy.spatial.transform import Rotation

from gravgrasp_detector.calibration.hand_eye import solve_hand_eye
from gravgrasp_detector.execution.ur_arm_settings import xyz_yaw_to_matrix
from gravgrasp_detector.poses import matrix_to_xyz_quat, xyz_quat_to_matrix
from gravgrasp_detector.ros.cell_config import (CellConfigError, base_in_task, camera_in_task, check_consistency,
                                                convert_camera_pose, load_sections, params_files, plan,
                                                unknown_parameters)
from ros_testing import BackgroundSpin, wait_until

pytestmark = pytest.mark.drake

CELLS = pathlib.Path(__file__).resolve().parents[2] / "gravgrasp_detector" / "cells"
SIM, UR = CELLS / "sim.yaml", CELLS / "ur5e_2f85_realsense.yaml"
STACK = dict(arm_adapter="service", workspace_origin_in_base=[0.0] * 4, object_mass_kg=0.0, score_safety_factor=1.5)


def test_workspace_origin_becomes_the_base_pose():
    origin = [0.30, -0.15, 0.02, math.pi / 2]
    base = base_in_task(origin)
    X_base_task = xyz_yaw_to_matrix(origin)
    np.testing.assert_allclose(xyz_yaw_to_matrix(base) @ X_base_task, np.eye(4), atol=1e-12)
    p = plan({**STACK, "workspace_origin_in_base": origin, "object_mass_kg": 0.5}, {})
    assert "execute:arm_base_xyz_yaw:=" in " ".join(p.overrides) and "ur_arm:base_xyz_yaw:=" in " ".join(p.overrides)
    assert "-p detect:min_score_n:=7.3575" in " ".join(p.overrides)
    print(p.notes)


def test_plan_refuses_conflicts_and_bad_values():
    with pytest.raises(CellConfigError, match="both place the robot"):
        plan({**STACK, "workspace_origin_in_base": [0.3, 0.0, 0.0, 0.0]}, {"execute": {"arm_base_xyz_yaw": [0.0] * 4}})
    with pytest.raises(CellConfigError, match="both set the score threshold"):
        plan({**STACK, "object_mass_kg": 1.0}, {"detect": {"min_score_n": 5.0}})
    with pytest.raises(CellConfigError, match="arm_adapter is 'moveit'"):
        plan({**STACK, "arm_adapter": "moveit"}, {})
    with pytest.raises(CellConfigError, match="tcp_offset_m 0.174 .* disagree"):
        check_consistency({"arm_base_xyz_yaw": [0.0] * 4, "tcp_offset_m": 0.174},
                          {"base_xyz_yaw": [0.0] * 4, "tcp_in_flange": [0.0, 0.0, 0.1558, 0.0, 0.0, 0.0]})


def test_samples_parse_and_name_only_real_parameters():
    assert params_files(["stack", "--ros-args", "--params-file", str(UR), "-p", "a:=1"]) == [UR]
    for path in (SIM, UR):
        sections = load_sections([path])
        assert {"stack", "tsdf", "detect", "execute"} <= set(sections)
    assert unknown_parameters({"execute": {"gripper_prot": "x", "qos_overrides./a.subscription.depth": 1}},
                              {"execute": {"gripper_port"}}) == ["execute.gripper_prot"]


def _pose_apart(a, b):
    A, B = xyz_quat_to_matrix(a), xyz_quat_to_matrix(b)
    return (float(np.linalg.norm(A[:3, 3] - B[:3, 3])),
            float(np.degrees(Rotation.from_matrix(A[:3, :3].T @ B[:3, :3]).magnitude())))


def _eye_to_hand_poses(X_base_camera, n=8, seed=5):
    """Flange poses in the base frame and the board poses the camera sees (board on the flange)."""
    rng = np.random.default_rng(seed)
    X_flange_board = xyz_quat_to_matrix([0.0, 0.0, 0.05, 0.0, 0.0, 0.0, 1.0])
    flanges, boards = [], []
    for _ in range(n):
        F = np.eye(4)
        F[:3, :3] = Rotation.from_rotvec(rng.uniform(-0.4, 0.4, 3)).as_matrix() @ np.diag([1.0, -1.0, -1.0])
        F[:3, 3] = [0.0, 0.6, 0.3] + rng.uniform(-0.1, 0.1, 3)
        flanges.append(F)
        boards.append(np.linalg.inv(X_base_camera) @ F @ X_flange_board)
    return flanges, boards


def test_camera_in_base_gives_the_old_task_pose_and_survives_a_remeasured_origin():
    X_base_camera = xyz_quat_to_matrix([0.0, 0.15, 0.65] + list(Rotation.from_euler("x", -135, degrees=True).as_quat()))
    flanges, boards = _eye_to_hand_poses(X_base_camera)
    origin = [-0.15, 0.45, 0.0, 0.1]
    X_base_task = xyz_yaw_to_matrix(origin)
    # The old way: flange poses in the task frame, the result stored as tsdf.camera_pose.
    old = matrix_to_xyz_quat(solve_hand_eye([np.linalg.inv(X_base_task) @ F for F in flanges], boards).X)
    # Now: flange poses in the base frame, the result stored as ur_arm.camera_in_base.
    camera_in_base = matrix_to_xyz_quat(solve_hand_eye(flanges, boards).X)
    sections = {"ur_arm": {"camera_in_base": camera_in_base}}
    cell = plan({**STACK, "workspace_origin_in_base": origin}, sections)
    composed = [float(v) for v in re.search(r"tsdf:camera_pose:=\[(.*?)\]", " ".join(cell.overrides)).group(1).split(",")]
    assert "-p tsdf:camera_pose_source:=parameter" in " ".join(cell.overrides)
    assert any("tsdf.camera_pose" in n for n in cell.notes) and cell.warnings == []
    mm, deg = _pose_apart(composed, old)
    assert mm < 1e-5 and deg < 1e-3, "the same origin: the same camera pose as before"
    # The workspace origin measured again (2 cm and 3 deg off): the composed pose follows it.
    remeasured = [-0.13, 0.44, 0.0, 0.1 + math.radians(3)]
    truth = matrix_to_xyz_quat(np.linalg.inv(xyz_yaw_to_matrix(remeasured)) @ X_base_camera)
    mm, deg = _pose_apart(camera_in_task(remeasured, camera_in_base), truth)
    assert mm < 1e-5 and deg < 1e-3
    stale_m, stale_deg = _pose_apart(old, truth)
    print(f"\nthe old task-frame pose after re-measuring: {stale_m * 1000:.0f} mm / {stale_deg:.1f} deg off")
    assert stale_m > 0.02, "what the old form left wrong"


def test_eye_to_hand_does_not_depend_on_the_controllers_tcp():
    """Flange poses from the controller's TCP pose and a tcp_in_flange that is off by E are
    the true ones times E, a constant in the flange frame: the solve puts it into the board's
    pose on the flange, and the camera pose does not change (doc/arm-adapter.md)."""
    X_base_camera = xyz_quat_to_matrix([0.0, 0.15, 0.65] + list(Rotation.from_euler("x", -135, degrees=True).as_quat()))
    flanges, boards = _eye_to_hand_poses(X_base_camera)
    E = xyz_quat_to_matrix([0.003, -0.002, 0.004] + list(Rotation.from_euler("z", 0.8, degrees=True).as_quat()))
    mm, deg = _pose_apart(matrix_to_xyz_quat(solve_hand_eye([F @ E for F in flanges], boards).X),
                          matrix_to_xyz_quat(X_base_camera))
    assert mm < 1e-5 and deg < 1e-3


def test_old_form_camera_pose_is_read_with_one_warning():
    old = {"tsdf": {"camera_pose_source": "parameter", "camera_pose": [0.15, -0.30, 0.65, -0.9239, 0.0, 0.0, 0.3827]},
           "stack": {"workspace_origin_in_base": [-0.15, 0.45, 0.0, 0.0]}}
    cell = plan({**STACK, "workspace_origin_in_base": [-0.15, 0.45, 0.0, 0.0]}, old, "/home/lab/cell.yaml")
    assert len(cell.warnings) == 1, cell.warnings
    print(f"\n{cell.warnings[0]}")
    assert "tsdf.camera_pose is a fixed camera in the task frame (the old form)" in cell.warnings[0]
    assert ("ros2 run gravgrasp_detector calibrate_camera --ros-args -p convert:=true "
            "-p cell_file:=/home/lab/cell.yaml") in cell.warnings[0]
    assert "tsdf:camera_pose" not in " ".join(cell.overrides), "the old pose is used as it is"
    # Converted, the file composes the same pose again.
    converted = convert_camera_pose(old)
    mm, deg = _pose_apart(camera_in_task([-0.15, 0.45, 0.0, 0.0], converted), old["tsdf"]["camera_pose"])
    assert mm < 1e-6 and deg < 1e-3
    # The sample cell file is in the new form, and composes the pose it had in the old one.
    sample = load_sections([UR])
    cell = plan({**STACK, "workspace_origin_in_base": sample["stack"]["workspace_origin_in_base"]}, sample)
    composed = [float(v) for v in re.search(r"tsdf:camera_pose:=\[(.*?)\]", " ".join(cell.overrides)).group(1).split(",")]
    mm, deg = _pose_apart(composed, old["tsdf"]["camera_pose"])
    assert cell.warnings == [] and mm < 1e-6 and deg < 1e-3


def test_camera_in_base_conflicts_are_refused():
    camera = {"camera_in_base": [0.0, 0.15, 0.65, 0.0, 0.0, 0.0, 1.0]}
    origin = {**STACK, "workspace_origin_in_base": [0.1, 0.2, 0.0, 0.0]}
    with pytest.raises(CellConfigError, match="needs stack.workspace_origin_in_base"):
        plan(STACK, {"ur_arm": camera})
    with pytest.raises(CellConfigError, match="both place the camera: delete tsdf.camera_pose"):
        plan(origin, {"ur_arm": camera, "tsdf": {"camera_pose": [0.0] * 6 + [1.0]}})
    with pytest.raises(CellConfigError, match="camera_pose_source is 'topic'"):
        plan(origin, {"ur_arm": camera, "tsdf": {"camera_pose_source": "topic"}})
    with pytest.raises(CellConfigError, match="unit quaternion"):
        plan(origin, {"ur_arm": {"camera_in_base": [0.0, 0.15, 0.65, 0.0, 0.0, 0.0, 2.0]}})
    with pytest.raises(CellConfigError, match="no stack.workspace_origin_in_base"):
        convert_camera_pose({"tsdf": {"camera_pose": [0.0] * 6 + [1.0]}})


@pytest.fixture
def spin(ros_node):
    spinner = BackgroundSpin(ros_node)
    yield spinner
    spinner.shutdown()


def test_ur_sample_starts_until_it_needs_the_robot(ros_process, ros_node, spin):
    """The real ur_rtde tries 192.168.1.102 (no robot here): every node starts, says what
    is missing, and keeps serving; nothing moves while the executor is disarmed."""
    stack = ros_process("gravgrasp_detector", "stack", cmd=[
        str(pathlib.Path(__file__).resolve().parents[2] / "ros_ws/install/gravgrasp_detector/lib/gravgrasp_detector/stack"),
        "--ros-args", "--params-file", str(UR)])
    stack.wait_for_output("execute ready", timeout_s=120)
    stack.wait_for_output("ur_arm ready", timeout_s=30)
    unreachable = stack.wait_for_output(r"cannot reach the UR controller at 192\.168\.1\.102: [^\n]*", 60).group(0)
    port = stack.wait_for_output(r"gripper_port /dev/serial/by-id/\S+ does not exist[^\n]*", 10).group(0)
    notes = re.findall(r"cell: [^\n]*", stack.output())
    print("\n" + "\n".join([unreachable, port] + notes))
    assert any("detect.min_score_n 7.36 N" in n for n in notes) and any("robot base" in n for n in notes)
    assert "camera pose from parameter" in stack.output()
    assert any("in the base frame -> tsdf.camera_pose" in n for n in notes) and "old form" not in stack.output()
    move = MoveToPose.Request(speed_mps=0.05)
    move.target.header.frame_id = "task"
    move.target.pose.position.x, move.target.pose.position.y, move.target.pose.position.z = 0.15, 0.15, 0.2
    move.target.pose.orientation.x, move.target.pose.orientation.w = 1.0, 0.0
    answer = spin.call(ros_node.create_client(MoveToPose, "move_to_pose"), move, 30, resend_s=5.0)  # refused: safe to resend
    assert not answer.success and answer.message.startswith("arm connection lost"), answer.message
    request = ExecuteGrasp.Request()
    request.header.frame_id = "task"
    request.grasp.pose.position.x, request.grasp.pose.position.y, request.grasp.pose.position.z = 0.15, 0.15, 0.08
    request.grasp.pose.orientation.x, request.grasp.pose.orientation.w = 1.0, 0.0
    result = spin.call(ros_node.create_client(ExecuteGrasp, "execute_grasp"), request, 30, resend_s=5.0)
    # No camera here: refused for the missing view (before it would refuse as disarmed).
    assert result.result_code == ExecuteGrasp.Response.STALE_SCENE and "no TSDF" in result.message, result.message
    assert stack.alive()


def test_a_typo_in_the_cell_file_stops_the_start(ros_process, tmp_path):
    bad = tmp_path / "cell.yaml"
    bad.write_text(SIM.read_text().replace("gripper_port:", "gripper_prot:"))
    stack = ros_process("gravgrasp_detector", "stack", cmd=[
        str(pathlib.Path(__file__).resolve().parents[2] / "ros_ws/install/gravgrasp_detector/lib/gravgrasp_detector/stack"),
        "--ros-args", "--params-file", str(bad)])
    assert stack.wait_exit(120) == 2
    assert "cannot start: the parameter file gives execute.gripper_prot, which no node of the stack declares" in stack.output()


def test_sim_sample_end_to_end(ros_process, ros_node, spin, tmp_path):
    """sim bridge + stack from the one file: depth -> tsdf -> detect -> /grasps -> execute
    over DDS and Modbus RTU -> the box is lifted. The scene (seed 2: one 44x55x103 mm box)
    and the pty path are the test's; the rest is the sample."""
    link = str(tmp_path / "ttyCellGripper")
    installed = pathlib.Path(__file__).resolve().parents[2] / "ros_ws/install"
    sim = ros_process("sim_bridge", "sim", cmd=[
        str(installed / "sim_bridge/lib/sim_bridge/sim"), "--ros-args", "--params-file", str(SIM),
        "-p", "sim:seed:=2", "-p", "sim:n_objects:=1", "-p", f"sim:gripper_link:={link}"])
    sim.wait_for_output("sim ready", timeout_s=180)
    stack = ros_process("gravgrasp_detector", "stack", cmd=[
        str(installed / "gravgrasp_detector/lib/gravgrasp_detector/stack"), "--ros-args", "--params-file", str(SIM),
        "-p", f"execute:gripper_port:={link}"])
    stack.wait_for_output("execute ready", timeout_s=120)
    # The stack logs its cell notes just after the nodes' "ready" lines.
    stack.wait_for_output(r"detect\.min_score_n 1\.47 N", timeout_s=30)
    seen = {}
    ros_node.create_subscription(GraspArray, "grasps", lambda m: seen.__setitem__("grasps", m), 10)
    ros_node.create_subscription(ObjectStates, "object_states", lambda m: seen.__setitem__("states", m), 10)
    assert wait_until(lambda: "states" in seen and seen.get("grasps") is not None and len(seen["grasps"].grasps) > 0, 120), \
        "no grasps from the stack"
    grasps = seen["grasps"].grasps
    assert min(g.gravity_rejection_score for g in grasps) >= 1.47
    assert all(a.gravity_rejection_score >= b.gravity_rejection_score for a, b in zip(grasps, grasps[1:])), \
        "not ranked by score"
    assert spin.call(ros_node.create_client(SetBool, "execute/arm"), SetBool.Request(data=True), resend_s=5.0).success
    result = spin.call(ros_node.create_client(ExecuteGrasp, "execute_grasp"),
                       ExecuteGrasp.Request(use_index=True, grasp_index=0), 300)
    print(f"\nsim cell: top grasp {grasps[0].gravity_rejection_score:.1f} N -> {result.message}")
    assert result.result_code == ExecuteGrasp.Response.SUCCESS, result.message
    assert wait_until(lambda: seen["states"].lifted[0], 15), "not lifted in the ground truth"
