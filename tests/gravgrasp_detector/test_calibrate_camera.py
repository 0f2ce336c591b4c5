"""calibrate_camera end to end on a rosbag2 file (rendered board images at known poses,
the flange poses as ur_arm publishes them in the robot base frame, the arm resting at each
view and moving in between): the installed executable writes the camera pose in the base
frame, and the calibration's record, into a cell parameter file. Plus the pieces: view
capture while the arm rests, the text edits of the file, and converting the old form."""
import re
import subprocess

import numpy as np
from geometry_msgs.msg import PoseStamped
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import CameraInfo, Image

from board_views import HEIGHT, K, WIDTH, BoardRenderer, pose_difference, transform
from gravgrasp_detector.calibration.capture import StillPoseCapture
from gravgrasp_detector.ros.bag_replay import write_bag
from gravgrasp_detector.ros.cell_config import camera_in_task, load_sections, plan
from gravgrasp_detector.ros.cell_file import remove_parameters, set_parameters
from ros_testing import executable
from test_camera_calibration import TARGET, eye_to_hand_views

CELL = """# A cell. Comments stay.
tsdf:
  ros__parameters:
    camera_pose_source: topic   # sim camera
    frame_id: task
    camera_pose:
      - 0.0
      - 0.0

execute:
  ros__parameters:
    gripper_port: /dev/ttyUSB0
"""


def test_cell_file_edit_keeps_the_rest():
    text = set_parameters(CELL, "tsdf", {"camera_pose_source": "parameter", "camera_pose": [0.1, 0, 0.5, 0, 0, 0, 1]},
                          comment="calibrate_camera 2026: eye_to_hand")
    assert "# A cell. Comments stay." in text and "gripper_port: /dev/ttyUSB0" in text and "frame_id: task" in text
    assert "    camera_pose: [0.1, 0.0, 0.5, 0.0, 0.0, 0.0, 1.0]\n" in text
    assert "      - 0.0" not in text, "the old block list is gone"
    assert "    camera_pose_source: \"parameter\"\n" in text
    assert text.count("# calibrate_camera 2026: eye_to_hand") == 2
    again = set_parameters(text, "tsdf", {"camera_pose": [0.2] * 7}, comment="calibrate_camera 2027: eye_to_hand")
    assert again.count("# calibrate_camera") == 2 and "2026" in again and again.count("2027") == 1  # replaced, not stacked
    added = set_parameters(CELL, "ur_arm", {"camera_in_flange": [0.0, 0.0, 0.1, 0.0, 0.0, 0.0, 1.0]})
    assert added.endswith("ur_arm:\n  ros__parameters:\n    camera_in_flange: [0.0, 0.0, 0.1, 0.0, 0.0, 0.0, 1.0]\n")


def test_cell_file_remove_takes_the_block_and_the_tools_comment():
    text = set_parameters(CELL, "tsdf", {"camera_pose": [0.1] * 7}, comment="calibrate_camera 2026: eye_to_hand")
    text = set_parameters(text, "tsdf", {"max_depth_m": 1.5})
    gone = remove_parameters(text, "tsdf", ["camera_pose", "not_there"])
    assert "camera_pose:" not in gone and "calibrate_camera 2026" not in gone
    assert "camera_pose_source: topic   # sim camera" in gone and "max_depth_m: 1.5" in gone
    assert remove_parameters(CELL, "tsdf", ["camera_pose"]) == CELL.replace("    camera_pose:\n      - 0.0\n      - 0.0\n", "")
    assert remove_parameters(CELL, "ur_arm", ["camera_in_base"]) == CELL


def test_capture_takes_one_view_per_rest():
    capture = StillPoseCapture()
    X = transform((0.1, 0.1, 0.3))
    for i in range(20):  # moving: 1 cm per 33 ms
        capture.add_pose(i / 30, transform((0.1 + 0.01 * i, 0.1, 0.3)))
    assert capture.offer_image(19 / 30, None) == "the arm is moving"
    for i in range(20, 50):
        capture.add_pose(i / 30, X)
    assert capture.offer_image(49 / 30, "img") is None
    assert capture.offer_image(49 / 30 + 0.01, "img") == "already have a view at this pose: move the arm on"
    assert "older than the image" in capture.offer_image(3.0, "img")
    capture.reject_last()
    assert capture.views == [] and capture.offer_image(49 / 30, "img").startswith("already have")


def image_msg(gray, stamp_ns):
    msg = Image(height=gray.shape[0], width=gray.shape[1], encoding="mono8", step=gray.shape[1])
    msg.data = gray.tobytes()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10**9)
    msg.header.frame_id = "camera_color_optical_frame"
    return msg


def pose_msg(X, stamp_ns):
    msg = PoseStamped()
    msg.header.frame_id = "base"  # ur_arm's flange_pose_base
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10**9)
    p, q = msg.pose.position, msg.pose.orientation
    p.x, p.y, p.z = (float(v) for v in X[:3, 3])
    q.x, q.y, q.z, q.w = (float(v) for v in Rotation.from_matrix(X[:3, :3]).as_quat())
    return msg


def calibration_bag(path, views):
    """30 Hz flange poses: 0.5 s moving towards each view's pose, 0.8 s resting there;
    two images per rest (one during the motion, which must not count)."""
    info = CameraInfo(width=WIDTH, height=HEIGHT, distortion_model="plumb_bob")
    info.k = K.ravel().tolist()
    info.d = [0.0] * 5
    messages, t = [], 10**9
    previous = views[0][2]
    for _, image, X in views:
        for i in range(15):  # moving
            f = (i + 1) / 15
            M = previous.copy()
            M[:3, 3] = (1 - f) * previous[:3, 3] + f * X[:3, 3] + [0, 0, 0.02 * np.sin(np.pi * f)]
            messages.append(("/ur_arm/flange_pose_base", pose_msg(M, t), t))
            if i == 10:
                messages.append(("/camera/color/image_raw", image_msg(image, t), t))
            t += 33_333_333
        for i in range(24):  # resting
            messages.append(("/ur_arm/flange_pose_base", pose_msg(X, t), t))
            t += 33_333_333
        messages.append(("/camera/color/camera_info", info, t - 16_666_666))
        messages.append(("/camera/color/image_raw", image_msg(image, t - 16_666_666), t - 16_666_666))
        previous = X
    return write_bag(path, messages)


def run_calibrate(params, timeout_s=120):
    cmd = [str(executable("gravgrasp_detector", "calibrate_camera")), "--ros-args"]
    for name, value in params.items():
        cmd += ["-p", f"{name}:={value}"]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)


def test_calibrate_camera_from_a_bag_writes_the_cell_file(tmp_path):
    rng = np.random.default_rng(11)
    views, truth = eye_to_hand_views(BoardRenderer(TARGET), rng, n=10)
    bag = calibration_bag(tmp_path / "calib_bag", views)
    cell = tmp_path / "cell.yaml"
    cell.write_text(CELL)
    run = run_calibrate({"bag": str(bag), "cell_file": str(cell), "views": 10, "mode": "eye_to_hand",
                         "image_topic": "/camera/color/image_raw", "camera_info_topic": "/camera/color/camera_info",
                         "pose_topic": "/ur_arm/flange_pose_base"})
    out = run.stdout + run.stderr
    assert run.returncode == 0, out
    assert "view 10/10" in out and "view 11/" not in out, "one view per rest, none while moving"
    text = cell.read_text()
    pose = re.search(r"^    camera_in_base: \[(.*)\]$", text, re.M).group(1)
    X = np.eye(4)
    values = [float(v) for v in pose.split(",")]
    X[:3, :3] = Rotation.from_quat(values[3:]).as_matrix()
    X[:3, 3] = values[:3]
    error_mm, error_deg = pose_difference(X, truth)
    note = re.search(r"# calibrate_camera .*", text).group(0)
    print(f"\nfrom the bag: error {error_mm:.3f} mm / {error_deg:.4f} deg; {note}")
    assert error_mm < 2.0 and error_deg < 0.5
    assert 'camera_pose_source: "parameter"' in text and "gripper_port: /dev/ttyUSB0" in text
    # The record, as values a program reads (not only the comment); the old task-frame pose is gone.
    record = load_sections([cell])["ur_arm"]
    print({k: v for k, v in record.items() if k.startswith("calibration_")})
    assert record["calibration_views"] == 10 and record["calibration_mode"] == "eye_to_hand"
    assert re.fullmatch(r"20\d\d-\d\d-\d\dT\d\d:\d\dZ", record["calibration_date"])
    assert 0 < record["calibration_residual_mm"] < 2.0 and 0 < record["calibration_residual_deg"] < 0.5
    assert 0 < record["calibration_reprojection_px"] < 1.0
    assert "camera_pose" not in load_sections([cell])["tsdf"]
    assert text.count("# calibrate_camera") == 1 and "eye_to_hand, the camera in the robot base frame" in note


def test_convert_an_old_cell_file(tmp_path):
    cell = tmp_path / "cell.yaml"
    old = [0.15, -0.30, 0.65, -0.9239, 0.0, 0.0, 0.3827]
    cell.write_text(f"stack:\n  ros__parameters:\n    workspace_origin_in_base: [-0.15, 0.45, 0.0, 0.2]\n\n{CELL}"
                    .replace("camera_pose_source: topic", "camera_pose_source: parameter")
                    .replace("    camera_pose:\n      - 0.0\n      - 0.0\n", f"    camera_pose: {old}\n"))
    sections = load_sections([cell])
    assert len(plan({"arm_adapter": "ur", "workspace_origin_in_base": [-0.15, 0.45, 0.0, 0.2], "object_mass_kg": 0.0,
                     "score_safety_factor": 1.5}, sections).warnings) == 1
    run = run_calibrate({"convert": "true", "cell_file": str(cell)})
    assert run.returncode == 0, run.stdout + run.stderr
    print(f"\n{run.stdout.strip()}")
    assert "tsdf.camera_pose -> ur_arm.camera_in_base" in run.stdout
    sections = load_sections([cell])
    assert "camera_pose" not in sections["tsdf"] and sections["tsdf"]["camera_pose_source"] == "parameter"
    composed = camera_in_task([-0.15, 0.45, 0.0, 0.2], sections["ur_arm"]["camera_in_base"])
    np.testing.assert_allclose(composed[:3], old[:3], atol=1e-5)
    assert abs(abs(np.dot(composed[3:], old[3:])) - 1) < 1e-4
    assert plan({"arm_adapter": "ur", "workspace_origin_in_base": [-0.15, 0.45, 0.0, 0.2], "object_mass_kg": 0.0,
                 "score_safety_factor": 1.5}, sections).warnings == []
    run = run_calibrate({"convert": "true", "cell_file": str(cell)})  # nothing left to convert
    assert run.returncode == 2 and "has no tsdf.camera_pose: nothing to convert" in run.stderr, run.stderr


def test_bad_inputs_one_sentence_each(tmp_path):
    rng = np.random.default_rng(12)
    views, _ = eye_to_hand_views(BoardRenderer(TARGET), rng, n=3)
    bag = calibration_bag(tmp_path / "few", views)
    run = run_calibrate({"bag": str(bag), "image_topic": "/camera/color/image_raw",
                         "camera_info_topic": "/camera/color/camera_info", "pose_topic": "/ur_arm/flange_pose_base"})
    assert run.returncode == 2 and "too few views: 3 with the board found" in run.stdout + run.stderr
    run = run_calibrate({"bag": str(bag)})  # default topic names are not in this bag
    assert run.returncode == 2
    assert "has no messages on /image, /camera_info, /flange_pose_base" in run.stderr, run.stderr
    run = run_calibrate({"mode": "eye_on_hand"})
    assert run.returncode == 2 and "mode 'eye_on_hand'" in run.stderr
    png = tmp_path / "board.png"
    run = run_calibrate({"board_png": str(png)})
    assert run.returncode == 0 and png.exists() and "print it so a square is 30 mm" in run.stdout
