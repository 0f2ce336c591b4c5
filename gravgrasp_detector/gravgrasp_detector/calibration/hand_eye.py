"""Where is the camera? Hand-eye calibration with a ChArUco board (OpenCV), no rclpy.

Two set-ups, both solved with `cv2.calibrateHandEye` (Park's method by default):

    eye_to_hand  the camera is fixed in the cell, the board is fixed to the flange.
                 Unknown: X_base_camera (ur_arm's `camera_in_base`; the stack
                 composes the tsdf node's `camera_pose` from it and the workspace origin).
    eye_in_hand  the camera is on the wrist, the board lies fixed in the cell.
                 Unknown: X_flange_camera (ur_arm's `camera_in_flange`, which then
                 publishes `camera_pose` as the arm moves).

Input: views = pairs (image, X_base_flange), the flange pose in the robot base frame at the
moment of the image (ur_arm publishes it on `flange_pose_base`), plus the camera's
intrinsics and distortion (its CameraInfo). Each image gives X_camera_board by ChArUco
corner detection + solvePnP.

The eye-to-hand case is the eye-in-hand one with the robot poses inverted: calibrateHandEye
solves A_i X = X B_i for the camera in the "gripper" frame; handing it
X_flange_base (instead of X_base_flange) makes its "gripper" the robot base and its
"base" the flange, so the answer is X_base_camera. (Any fixed frame of the robot poses
works; the eye-to-hand answer is in that frame. The robot's base is the one that no
re-measuring of the workspace moves.)

calibrateHandEye's answer is then refined, together with the other fixed transform
(eye-to-hand: the board in the flange; eye-in-hand: the board in the robot base frame), on the
reprojection error of every detected board corner (scipy least_squares, Huber loss).

Residuals: the RMS reprojection error of all corners through that one model (px), and,
per view, how far its own board pose predicts the other fixed transform from the solved
one (RMS over views, mm and deg): a view far off the others is a bad view (motion blur,
a robot pose taken while moving).

Bad input raises CalibrationError with one sentence saying what to do: the board is not
in an image, too few views, or motions all turning about one axis (no unique answer).
"""
from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from ..poses import matrix_to_xyz_quat

MODES = ("eye_to_hand", "eye_in_hand")
MIN_VIEWS = 5            # calibrateHandEye needs 3; 5 makes one bad view visible in the residuals
MIN_BOARD_CORNERS = 6    # fewer ChArUco corners make solvePnP unreliable
MIN_ROTATION_DEG = 5.0   # a pair of views rotated less says nothing about the rotation axis


class CalibrationError(ValueError):
    """Bad calibration input; the message says what to do."""


@dataclasses.dataclass(frozen=True)
class CharucoTarget:
    """A ChArUco board as printed: squares along x and y, square and marker edge in
    metres (measure the print!), and the ArUco dictionary."""
    squares_x: int = 7
    squares_y: int = 5
    square_m: float = 0.030
    marker_m: float = 0.022
    dictionary: str = "DICT_5X5_100"

    def board(self):
        if not hasattr(cv2.aruco, self.dictionary):
            raise CalibrationError(f"unknown ArUco dictionary {self.dictionary!r}: use a cv2.aruco name such as DICT_5X5_100")
        if not 0 < self.marker_m < self.square_m:
            raise CalibrationError(f"marker_m {self.marker_m} must be smaller than square_m {self.square_m}")
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_m, self.marker_m, dictionary)

    def image(self, pixels_per_square: int = 100, margin_px: int = 0) -> np.ndarray:
        """The board as an 8-bit image, for printing (and for tests)."""
        size = (self.squares_x * pixels_per_square + 2 * margin_px, self.squares_y * pixels_per_square + 2 * margin_px)
        return self.board().generateImage(size, marginSize=margin_px, borderBits=1)


@dataclasses.dataclass
class BoardView:
    X_camera_board: np.ndarray
    corners: int
    reprojection_px: float
    object_points: np.ndarray = None   # Nx3 board corners (m), board frame
    image_points: np.ndarray = None    # Nx2 where they were detected (px)


@dataclasses.dataclass
class HandEyeResult:
    mode: str
    X: np.ndarray                  # eye_to_hand: X_base_camera; eye_in_hand: X_flange_camera
    views: int
    residual_mm: float             # RMS spread of the per-view predictions of the other fixed transform
    residual_deg: float
    reprojection_px: float         # RMS of every board corner through the refined model
    per_view: list                 # (position mm, rotation deg, reprojection px) of each view

    @property
    def pose_xyz_quat(self) -> list:
        """[x, y, z, qx, qy, qz, qw]: ur_arm's camera_in_base (eye_to_hand) or camera_in_flange."""
        return matrix_to_xyz_quat(self.X)

    def summary(self) -> str:
        what = "camera in the robot base frame" if self.mode == "eye_to_hand" else "camera in the flange frame"
        return (f"{self.mode}: {what} {np.round(self.pose_xyz_quat, 5).tolist()} from {self.views} views; "
                f"residual {self.residual_mm:.2f} mm / {self.residual_deg:.3f} deg RMS, "
                f"board reprojection {self.reprojection_px:.2f} px")


def to_gray(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if image.dtype != np.uint8:  # e.g. 16-bit infrared: stretch to 8 bits
        image = cv2.normalize(image, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    return image


def detect_board(image, K, dist, target: CharucoTarget, name: str = "the image") -> BoardView:
    """X_camera_board from one image; CalibrationError if the board is not found."""
    board = target.board()
    detector = cv2.aruco.CharucoDetector(board)
    corners, ids, _, marker_ids = detector.detectBoard(to_gray(image))
    found = 0 if ids is None else len(ids)
    if found < MIN_BOARD_CORNERS:
        markers = 0 if marker_ids is None else len(marker_ids)
        raise CalibrationError(
            f"board not found in {name} ({found} ChArUco corners, {markers} markers; need {MIN_BOARD_CORNERS} corners): "
            f"check that the whole {target.squares_x}x{target.squares_y} {target.dictionary} board is in view, in focus "
            "and evenly lit, and that squares_x/squares_y/dictionary match the print")
    object_points, image_points = board.matchImagePoints(corners, ids)
    K, dist = np.asarray(K, float).reshape(3, 3), np.asarray(dist, float).ravel()
    ok, rvec, tvec = cv2.solvePnP(object_points, image_points, K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        raise CalibrationError(f"board not found in {name}: its corners gave no pose (solvePnP failed); take the view again")
    projected, _ = cv2.projectPoints(object_points, rvec, tvec, K, dist)
    error = float(np.sqrt(np.mean(np.sum((projected.reshape(-1, 2) - image_points.reshape(-1, 2)) ** 2, axis=1))))
    X = np.eye(4)
    X[:3, :3] = cv2.Rodrigues(rvec)[0]
    X[:3, 3] = tvec.ravel()
    return BoardView(X, found, error, object_points.reshape(-1, 3), image_points.reshape(-1, 2))


def check_motions(X_base_flange: list) -> None:
    """CalibrationError if the flange rotations cannot determine a hand-eye transform:
    too few views, hardly any rotation, or every rotation about (nearly) one axis."""
    n = len(X_base_flange)
    if n < MIN_VIEWS:
        raise CalibrationError(
            f"too few views: {n} with the board found, need at least {MIN_VIEWS} (10-15 recommended); "
            "capture more arm poses with the board in view")
    axes, largest = [], 0.0
    for i in range(n):
        for j in range(i + 1, n):
            rotvec = Rotation.from_matrix(X_base_flange[i][:3, :3].T @ X_base_flange[j][:3, :3]).as_rotvec()
            angle = float(np.degrees(np.linalg.norm(rotvec)))
            largest = max(largest, angle)
            if angle >= MIN_ROTATION_DEG:
                axes.append(rotvec / np.linalg.norm(rotvec))
    if not axes:
        raise CalibrationError(
            f"degenerate motions: the flange turned at most {largest:.1f} deg between views; tilt it by "
            "15-30 deg about different axes between views (translations alone cannot fix the rotation)")
    singular = np.linalg.svd(np.asarray(axes), compute_uv=False)
    if len(singular) < 2 or singular[1] < 0.1 * singular[0]:
        main = np.linalg.svd(np.asarray(axes))[2][0]
        raise CalibrationError(
            "degenerate motions: every rotation between views turns about one axis "
            f"(~{np.round(main, 2).tolist()} in the flange frame), which leaves the transform along it "
            "undetermined; add views tilted about at least one other axis")


def solve_hand_eye(X_base_flange: list, X_camera_board: list, mode: str = "eye_to_hand",
                   method: int = cv2.CALIB_HAND_EYE_PARK, observations=None, K=None, dist=None) -> HandEyeResult:
    """The camera pose from matched robot and board poses (see the module doc).

    With `observations` (per view: board corners Nx3, their detections Nx2) and the
    intrinsics, calibrateHandEye's answer is refined on the corners' reprojection."""
    if mode not in MODES:
        raise CalibrationError(f"mode {mode!r}: use 'eye_to_hand' (camera fixed, board on the flange) or "
                               "'eye_in_hand' (camera on the flange, board fixed)")
    if len(X_base_flange) != len(X_camera_board):
        raise ValueError("one flange pose per board pose")
    robot = [np.asarray(X, float) for X in X_base_flange]
    check_motions(robot)
    if mode == "eye_to_hand":
        robot_in = [np.linalg.inv(X) for X in robot]  # X_flange_base: the "gripper" becomes the robot base frame
    else:
        robot_in = robot
    R, t = cv2.calibrateHandEye([X[:3, :3] for X in robot_in], [X[:3, 3] for X in robot_in],
                                [X[:3, :3] for X in X_camera_board], [X[:3, 3] for X in X_camera_board],
                                method=method)
    X = np.eye(4)
    X[:3, :3], X[:3, 3] = R, np.asarray(t).ravel()
    Y = _mean_pose(_other_transform(mode, X, robot, X_camera_board))
    per_view_px = [float("nan")] * len(robot)
    if observations is not None:
        # calibrateHandEye works on the per-view board poses, where one grazing view's depth
        # error weighs as much as any; refine X and the other fixed transform together on
        # every detected corner (reprojection error, robust loss) instead.
        X, Y, per_view_px = _refine(mode, X, Y, robot, observations, K, dist)
    predictions = _other_transform(mode, X, robot, X_camera_board)
    per_view = [(*_difference(P, Y), px) for P, px in zip(predictions, per_view_px)]
    rms = lambda values: float(math.sqrt(np.mean(np.square(values))))  # noqa: E731
    reprojection = rms(per_view_px) if observations is not None else float("nan")
    return HandEyeResult(mode, X, len(robot), rms([v[0] for v in per_view]), rms([v[1] for v in per_view]),
                         reprojection, per_view)


def _other_transform(mode, X, robot, X_camera_board) -> list:
    """Each view's prediction of the fixed transform that is not asked for."""
    if mode == "eye_to_hand":   # X_flange_board = inv(X_base_flange) X_base_camera X_camera_board
        return [np.linalg.inv(F) @ X @ B for F, B in zip(robot, X_camera_board)]
    return [F @ X @ B for F, B in zip(robot, X_camera_board)]  # X_base_board


def _camera_board(mode, X, Y, F) -> np.ndarray:
    if mode == "eye_to_hand":   # X = X_base_camera, Y = X_flange_board
        return np.linalg.inv(X) @ F @ Y
    return np.linalg.inv(F @ X) @ Y  # X = X_flange_camera, Y = X_base_board


def _mean_pose(poses) -> np.ndarray:
    M = np.eye(4)
    M[:3, :3] = Rotation.from_matrix([P[:3, :3] for P in poses]).mean().as_matrix()
    M[:3, 3] = np.mean([P[:3, 3] for P in poses], axis=0)
    return M


def _difference(A, B) -> tuple[float, float]:
    return (float(np.linalg.norm(A[:3, 3] - B[:3, 3]) * 1000),
            float(np.degrees(Rotation.from_matrix(A[:3, :3].T @ B[:3, :3]).magnitude())))


def _to_params(X):
    return np.concatenate([Rotation.from_matrix(X[:3, :3]).as_rotvec(), X[:3, 3]])


def _from_params(v):
    X = np.eye(4)
    X[:3, :3] = Rotation.from_rotvec(v[:3]).as_matrix()
    X[:3, 3] = v[3:6]
    return X


def _refine(mode, X, Y, robot, observations, K, dist):
    K, dist = np.asarray(K, float).reshape(3, 3), np.asarray(dist, float).ravel()

    def residuals(v, per_view=False):
        Xv, Yv = _from_params(v[:6]), _from_params(v[6:])
        out = []
        for F, (obj, img) in zip(robot, observations):
            C = _camera_board(mode, Xv, Yv, F)
            projected, _ = cv2.projectPoints(obj, cv2.Rodrigues(C[:3, :3])[0], C[:3, 3], K, dist)
            out.append((projected.reshape(-1, 2) - img).ravel())
        return out if per_view else np.concatenate(out)

    fit = least_squares(residuals, np.concatenate([_to_params(X), _to_params(Y)]), loss="huber", f_scale=1.0,
                        x_scale="jac")
    per_view_px = [float(np.sqrt(np.mean(np.sum(r.reshape(-1, 2) ** 2, axis=1)))) for r in residuals(fit.x, True)]
    return _from_params(fit.x[:6]), _from_params(fit.x[6:]), per_view_px


def calibrate(views, K, dist, target: CharucoTarget, mode: str = "eye_to_hand", skip_unseen: bool = True,
              log=None) -> HandEyeResult:
    """views: iterable of (name, image, X_base_flange). Images without the board are
    skipped (and logged) when skip_unseen, else raise."""
    flanges, boards, observations = [], [], []
    for name, image, X_base_flange in views:
        try:
            view = detect_board(image, K, dist, target, name)
        except CalibrationError as e:
            if not skip_unseen:
                raise
            if log:
                log(f"skipped: {e}")
            continue
        flanges.append(np.asarray(X_base_flange, float))
        boards.append(view.X_camera_board)
        observations.append((view.object_points, view.image_points))
    return solve_hand_eye(flanges, boards, mode, observations=observations, K=K, dist=dist)
