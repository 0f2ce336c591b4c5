"""`ros2 run gravgrasp_detector calibrate_camera`: where the camera is, from a ChArUco board.

    # live: jog the arm from pose to pose and let it rest ~1 s at each (views are taken by themselves)
    ros2 run gravgrasp_detector calibrate_camera --ros-args --params-file cell.yaml \\
        -p mode:=eye_to_hand -p cell_file:=cell.yaml
    # from a bag recorded while doing the same (image, camera_info, flange_pose)
    ros2 run gravgrasp_detector calibrate_camera --ros-args -p bag:=calib_bag -p cell_file:=cell.yaml
    # the board to print
    ros2 run gravgrasp_detector calibrate_camera --ros-args -p board_png:=board.png
    # a cell file of the old form (tsdf.camera_pose, task frame) -> ur_arm.camera_in_base
    ros2 run gravgrasp_detector calibrate_camera --ros-args -p convert:=true -p cell_file:=cell.yaml

Inputs: `image_topic` (sensor_msgs/Image: mono8, bgr8, rgb8, bgra8, rgba8, mono16),
`camera_info_topic` (its CameraInfo: K and plumb_bob D), `pose_topic`
(geometry_msgs/PoseStamped, the flange in the robot base frame: ur_arm's
`flange_pose_base`). Images are paired with the flange pose by header stamp, only while
the arm rests (calibration/capture.py). After `views` views (or `~/solve`,
std_srvs/Trigger, live) it solves (calibration/hand_eye.py), prints the result and
residuals, and writes into `cell_file` the result with its record (`ur_arm.calibration_date`,
`_mode`, `_views`, `_residual_mm`, `_residual_deg`, `_reprojection_px`):
eye_to_hand -> `ur_arm.camera_in_base`, the camera in the robot base frame, which the
stack turns into tsdf `camera_pose` through `stack.workspace_origin_in_base` at start-up
(so re-measuring the workspace origin keeps the calibration); eye_in_hand ->
`ur_arm.camera_in_flange` (tsdf camera_pose_source topic). Exit 0 on success; 2 with one
sentence on bad input (board not found in any view, too few views, degenerate motions,
unreadable bag).
"""
from __future__ import annotations

import datetime
import math
import pathlib
import sys
import threading

import cv2
import numpy as np
import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from rosbags.rosbag2 import Reader
from sensor_msgs.msg import CameraInfo, Image
from std_srvs.srv import Trigger

from ..calibration.capture import CaptureSettings, StillPoseCapture
from ..calibration.hand_eye import MODES, CalibrationError, CharucoTarget, HandEyeResult, detect_board, solve_hand_eye
from ..poses import PoseError
from . import cell_file
from .bag_replay import read_bag
from .cell_config import CellConfigError, convert_camera_pose, load_sections
from .interface import described, matrix_from_pose_msg, stamp_s

ENCODINGS = {"mono8": (np.uint8, 1), "8UC1": (np.uint8, 1), "bgr8": (np.uint8, 3), "rgb8": (np.uint8, 3),
             "bgra8": (np.uint8, 4), "rgba8": (np.uint8, 4), "mono16": (np.uint16, 1), "16UC1": (np.uint16, 1)}


def image_from_msg(msg: Image) -> np.ndarray:
    if msg.encoding not in ENCODINGS:
        raise CalibrationError(f"image encoding {msg.encoding!r} is not supported: use the camera's colour, "
                               f"infrared or mono stream ({', '.join(ENCODINGS)})")
    dtype, channels = ENCODINGS[msg.encoding]
    rows = np.frombuffer(bytes(msg.data), np.uint8, msg.step * msg.height).reshape(msg.height, msg.step)
    image = rows[:, :msg.width * channels * np.dtype(dtype).itemsize].copy().view(
        np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")).reshape(msg.height, msg.width, channels)
    if msg.encoding.startswith("rgb"):
        image = image[..., [2, 1, 0] + ([3] if channels == 4 else [])]
    return image[..., 0] if channels == 1 else image


class CalibrateNode(Node):
    def __init__(self):
        super().__init__("calibrate_camera")
        p = lambda name, default, text: self.declare_parameter(  # noqa: E731
            name, default, described(text, read_only=True)).value
        self.mode = p("mode", "eye_to_hand", "'eye_to_hand' (camera fixed, board on the flange) or "
                                             "'eye_in_hand' (camera on the flange, board fixed)")
        self.target = CharucoTarget(
            squares_x=p("squares_x", 7, "board squares along x"), squares_y=p("squares_y", 5, "board squares along y"),
            square_m=p("square_m", 0.030, "square edge as printed, m (measure it)"),
            marker_m=p("marker_m", 0.022, "ArUco marker edge as printed, m"),
            dictionary=p("dictionary", "DICT_5X5_100", "ArUco dictionary of the board"))
        self.wanted = p("views", 12, "views to collect before solving (5 at least; 10-15 recommended)")
        self.cell_file = p("cell_file", "", "parameter file to write the result into ('' = print only)")
        self.bag = p("bag", "", "rosbag2 directory to read instead of live topics ('' = live)")
        self.board_png = p("board_png", "", "write the board as a PNG to print, then exit")
        self.convert = p("convert", False, "convert cell_file's old tsdf.camera_pose (task frame) to "
                                           "ur_arm.camera_in_base, then exit")
        self.topics = {
            "image": p("image_topic", "image", "camera image (the stream whose CameraInfo is given)"),
            "info": p("camera_info_topic", "camera_info", "that image's CameraInfo"),
            "pose": p("pose_topic", "flange_pose_base", "flange pose in the robot base frame (ur_arm's flange_pose_base)")}
        self.frame_id = p("frame_id", "base", "the robot base frame, which the flange poses (and an eye-to-hand "
                                              "result) are in")
        self.capture = StillPoseCapture(CaptureSettings(
            still_s=p("still_s", 0.5, "the arm must rest this long before an image counts, s"),
            min_move_mm=p("min_move_mm", 20.0, "views must be this far apart, mm (or min_turn_deg)"),
            min_turn_deg=p("min_turn_deg", 5.0, "views must be turned this much apart, deg (or min_move_mm)")))
        if self.mode not in MODES:
            raise CalibrationError(f"mode {self.mode!r}: use 'eye_to_hand' or 'eye_in_hand'")
        self.target.board()  # bad board parameters fail here, with their sentence
        self.K = self.dist = None
        self.boards = []   # BoardView per accepted view
        self.done = threading.Event()
        self.exit_code = 0
        self._last_why = None

    # -- inputs ---------------------------------------------------------------------

    def on_info(self, msg: CameraInfo):
        self.K = np.asarray(msg.k, float).reshape(3, 3)
        self.dist = np.asarray(msg.d, float) if len(msg.d) else np.zeros(5)

    def on_pose(self, msg: PoseStamped):
        if msg.header.frame_id not in ("", self.frame_id):
            self._say(f"flange pose is in frame {msg.header.frame_id!r}, expected {self.frame_id!r}: "
                      "give the flange in the robot base frame (ur_arm's flange_pose_base)")
            return
        try:
            X_task_flange = matrix_from_pose_msg(msg.pose)
        except PoseError as e:
            self._say(f"flange pose ignored: {e}")
            return
        self.capture.add_pose(stamp_s(msg.header.stamp), X_task_flange)

    def on_image(self, msg: Image):
        if self.done.is_set():
            return
        if self.K is None:
            self._say(f"waiting for CameraInfo on {self.topics['info']}")
            return
        t = stamp_s(msg.header.stamp)
        why = self.capture.offer_image(t, None)
        if why is not None:
            self._say(why, info=True)
            return
        n = len(self.capture.views)
        try:
            view = detect_board(image_from_msg(msg), self.K, self.dist, self.target, f"view {n}")
        except CalibrationError as e:
            self.capture.reject_last()
            self.get_logger().warn(f"{e}; move the arm on")
            return
        self.boards.append(view)
        self.get_logger().info(f"view {n}/{self.wanted}: {view.corners} corners, "
                               f"{view.reprojection_px:.2f} px; move the arm to the next pose")
        if n >= self.wanted:
            self.solve()

    def _say(self, text, info=False):
        if text != self._last_why:
            (self.get_logger().info if info else self.get_logger().warn)(text)
            self._last_why = text

    # -- result -----------------------------------------------------------------------

    def solve(self) -> HandEyeResult | None:
        flanges = [X for _, _, X in self.capture.views]
        try:
            result = solve_hand_eye(flanges, [b.X_camera_board for b in self.boards], self.mode,
                                    observations=[(b.object_points, b.image_points) for b in self.boards],
                                    K=self.K, dist=self.dist)
        except CalibrationError as e:
            self.get_logger().error(str(e))
            self.exit_code = 2
            self.done.set()
            return None
        self.get_logger().info(result.summary())
        for i, (mm, deg, px) in enumerate(result.per_view):
            self.get_logger().info(f"  view {i + 1}: {mm:.2f} mm / {deg:.3f} deg from the consensus, {px:.2f} px")
        if self.cell_file:
            self.write(result)
        self.done.set()
        return result

    def write(self, result: HandEyeResult):
        stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%MZ")
        pose = [round(v, 6) for v in result.pose_xyz_quat]
        fixed = result.mode == "eye_to_hand"
        name, other = ("camera_in_base", "camera_in_flange") if fixed else ("camera_in_flange", "camera_in_base")
        record = {"calibration_date": stamp, "calibration_mode": result.mode, "calibration_views": result.views,
                  "calibration_residual_mm": round(result.residual_mm, 3),
                  "calibration_residual_deg": round(result.residual_deg, 4),
                  "calibration_reprojection_px": round(result.reprojection_px, 3)}
        record = {k: v for k, v in record.items() if not isinstance(v, float) or math.isfinite(v)}  # NaN: not measured
        path = pathlib.Path(self.cell_file)
        text = path.read_text() if path.exists() else ""
        # One camera, one calibration: the other form and the old task-frame pose go.
        text = cell_file.remove_parameters(text, "ur_arm", [other])
        # (camera_pose_source too, with the comment an older calibrate_camera wrote above it)
        text = cell_file.remove_parameters(text, "tsdf", ["camera_pose", "camera_pose_source"])
        text = cell_file.set_parameters(text, "tsdf", {"camera_pose_source": "parameter" if fixed else "topic"})
        for key in reversed(record):  # missing ones are added at the top: reversed keeps their order
            text = cell_file.set_parameters(text, "ur_arm", {key: record[key]})
        where = "robot base frame" if fixed else "flange frame"
        text = cell_file.set_parameters(text, "ur_arm", {name: pose},
                                        f"calibrate_camera {stamp}: {result.mode}, the camera in the {where}")
        cell_file.replace_file(path, text)
        self.get_logger().info(f"written to {self.cell_file}: ur_arm.{name}, ur_arm.calibration_*, "
                               f"tsdf.camera_pose_source" + ("; the stack composes tsdf.camera_pose from it and "
                                                              "stack.workspace_origin_in_base" if fixed else ""))


def convert_cell_file(path: str) -> str:
    """The old tsdf.camera_pose (task frame) -> ur_arm.camera_in_base; the line to print.
    Raises CellConfigError."""
    if not path:
        raise CellConfigError("convert:=true needs cell_file:=<the cell file to convert>")
    camera = convert_camera_pose(load_sections([path]))
    text = cell_file.remove_parameters(pathlib.Path(path).read_text(), "tsdf", ["camera_pose"])
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%MZ")
    text = cell_file.set_parameters(text, "ur_arm", {"camera_in_base": camera},
                                    f"calibrate_camera {stamp}: converted from tsdf.camera_pose (task frame) "
                                    "with this file's workspace_origin_in_base")
    cell_file.replace_file(path, text)
    return (f"calibrate_camera: {path}: tsdf.camera_pose -> ur_arm.camera_in_base {camera} (robot base frame); "
            "the stack now composes tsdf.camera_pose from it and stack.workspace_origin_in_base")


def run_bag(node: CalibrateNode) -> int:
    topics = {name: "/" + topic.lstrip("/") for name, topic in node.topics.items()}
    path = pathlib.Path(node.bag)
    if not path.exists():
        raise CalibrationError(f"bag {path} does not exist: give the rosbag2 directory")
    try:
        with Reader(path) as reader:
            found = {c.topic for c in reader.connections if c.msgcount > 0}
        missing = [t for t in topics.values() if t not in found]
        if missing:
            raise CalibrationError(
                f"the bag {path} has no messages on {', '.join(missing)} (it has {', '.join(sorted(found)) or 'none'}): "
                "record the image, its camera_info and ur_arm's flange_pose, or set image_topic, camera_info_topic, pose_topic")
        messages = [(topic, msg) for topic, msg, _ in read_bag(path, topics.values())]
    except CalibrationError:
        raise
    except Exception as e:
        raise CalibrationError(f"cannot read the bag {path} ({type(e).__name__}: {e}): give a rosbag2 directory") from None
    # Poses first (an image needs the poses of the rest before it), then images in stamp order.
    for topic, msg in messages:
        if topic == topics["pose"]:
            node.on_pose(msg)
        elif topic == topics["info"] and node.K is None:
            node.on_info(msg)
    for topic, msg in sorted(((t, m) for t, m in messages if t == topics["image"]), key=lambda tm: stamp_s(tm[1].header.stamp)):
        if node.done.is_set():
            break
        node.on_image(msg)
    if not node.done.is_set():
        if len(node.boards) < node.wanted:
            node.get_logger().info(f"the bag gave {len(node.boards)} views (views:={node.wanted} wanted): solving with them")
        node.solve()
    return node.exit_code


def main(args=None):
    rclpy.init(args=args)
    node = None
    try:
        node = CalibrateNode()
        if node.convert:
            print(convert_cell_file(node.cell_file), flush=True)
            return 0
        if node.board_png:
            cv2.imwrite(node.board_png, node.target.image(pixels_per_square=300, margin_px=150))
            print(f"calibrate_camera: board written to {node.board_png}: {node.target.squares_x}x{node.target.squares_y} "
                  f"{node.target.dictionary}, 300 px per square; print it so a square is {node.target.square_m * 1000:g} mm, "
                  "glue it flat and rigid, and measure a square (square_m) and a marker (marker_m)")
            return 0
        if node.bag:
            return run_bag(node)
        node.create_subscription(CameraInfo, node.topics["info"], node.on_info, qos_profile_sensor_data)
        node.create_subscription(PoseStamped, node.topics["pose"], node.on_pose, 50)
        node.create_subscription(Image, node.topics["image"], node.on_image, qos_profile_sensor_data)
        node.create_service(Trigger, "~/solve", lambda req, res: _solve_now(node, res))
        node.get_logger().info(
            f"calibrate_camera ({node.mode}): waiting for {node.wanted} views on {node.resolve_topic_name(node.topics['image'])} "
            f"with flange poses on {node.resolve_topic_name(node.topics['pose'])}; jog the arm to a pose with the board "
            "in view, let it rest ~1 s, repeat (tilt about different axes)")
        while rclpy.ok() and not node.done.is_set():
            rclpy.spin_once(node, timeout_sec=0.1)
        return node.exit_code
    except (CalibrationError, CellConfigError) as e:
        print(f"calibrate_camera: {e}", file=sys.stderr, flush=True)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        return 130
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


def _solve_now(node, response):
    result = node.solve()
    response.success = result is not None
    response.message = result.summary() if result else "calibration failed: see the log"
    return response


if __name__ == "__main__":
    sys.exit(main())
