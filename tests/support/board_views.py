"""Camera images of a ChArUco board at known poses, for the calibration tests.

The board's printable image is warped into a pinhole camera by the plane homography
K [r1 r2 t] (board plane z = 0), then blurred slightly and given Gaussian pixel noise.
Which pixel of the printable image is which point of the board plane is measured on the
printable image itself (its detected ChArUco corners), so no OpenCV layout convention
is assumed here."""
from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from gravgrasp_detector.calibration.hand_eye import CharucoTarget

WIDTH, HEIGHT = 1280, 720
K = np.array([[900.0, 0.0, 640.0], [0.0, 900.0, 360.0], [0.0, 0.0, 1.0]])
DIST = np.zeros(5)


class BoardRenderer:
    def __init__(self, target: CharucoTarget, pixels_per_square: int = 120, margin_px: int = 60):
        self.target = target
        self.image = target.image(pixels_per_square, margin_px)
        board = target.board()
        corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(self.image)
        obj, img = board.matchImagePoints(corners, ids)
        # board plane (m) -> printable image pixels
        self.H_image_plane, _ = cv2.findHomography(obj.reshape(-1, 3)[:, :2], img.reshape(-1, 2))

    def render(self, X_camera_board, rng, noise_sigma=2.0, background=110) -> np.ndarray:
        R, t = X_camera_board[:3, :3], X_camera_board[:3, 3]
        H_camera_plane = K @ np.column_stack([R[:, 0], R[:, 1], t])
        H = H_camera_plane @ np.linalg.inv(self.H_image_plane)
        view = cv2.warpPerspective(self.image, H, (WIDTH, HEIGHT), flags=cv2.INTER_LINEAR,
                                   borderMode=cv2.BORDER_CONSTANT, borderValue=background)
        mask = cv2.warpPerspective(np.full_like(self.image, 255), H, (WIDTH, HEIGHT), flags=cv2.INTER_NEAREST)
        view = np.where(mask > 0, view, background).astype(np.float32)
        view = cv2.GaussianBlur(view, (3, 3), 0.7)
        view += rng.normal(0.0, noise_sigma, view.shape)
        return np.clip(view, 0, 255).astype(np.uint8)

    def centre(self) -> np.ndarray:
        """Board centre in the board frame (the corner origin + half the board)."""
        return np.array([self.target.squares_x * self.target.square_m / 2, self.target.squares_y * self.target.square_m / 2, 0.0])


def look_at(eye, target, up=(0, 0, 1)) -> np.ndarray:
    """Optical frame (z forward, x right, y down) at `eye` looking at `target`."""
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-6:
        x = np.cross(z, (0, 1, 0))
    x /= np.linalg.norm(x)
    X = np.eye(4)
    X[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    X[:3, 3] = eye
    return X


def transform(xyz=(0, 0, 0), rotvec_deg=(0, 0, 0)) -> np.ndarray:
    X = np.eye(4)
    X[:3, :3] = Rotation.from_rotvec(np.radians(rotvec_deg)).as_matrix()
    X[:3, 3] = xyz
    return X


def pose_difference(A, B) -> tuple[float, float]:
    """(mm, deg) between two 4x4 poses."""
    dp = float(np.linalg.norm(A[:3, 3] - B[:3, 3]) * 1000)
    da = float(np.degrees(Rotation.from_matrix(A[:3, :3].T @ B[:3, :3]).magnitude()))
    return dp, da
