"""Hand-eye calibration (gravgrasp_detector.calibration.hand_eye) on ChArUco images
rendered at known poses with pixel noise (tests/support/board_views.py): the recovered camera
pose must be within 2 mm and 0.5 deg of the truth, eye-to-hand and eye-in-hand; and
one clear sentence for each bad input."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from board_views import DIST, HEIGHT, K, WIDTH, BoardRenderer, look_at, pose_difference, transform
from gravgrasp_detector.calibration.hand_eye import (CalibrationError, CharucoTarget, calibrate, detect_board,
                                                     solve_hand_eye)

TARGET = CharucoTarget(squares_x=7, squares_y=5, square_m=0.030, marker_m=0.022, dictionary="DICT_5X5_100")
TOLERANCE_MM, TOLERANCE_DEG = 2.0, 0.5


@pytest.fixture(scope="module")
def renderer():
    return BoardRenderer(TARGET)


def visible(X_camera_board, renderer, margin_px=40):
    s = renderer.target
    corners = np.array([[0, 0, 0], [s.squares_x * s.square_m, 0, 0], [0, s.squares_y * s.square_m, 0],
                        [s.squares_x * s.square_m, s.squares_y * s.square_m, 0]])
    cam = (X_camera_board[:3, :3] @ corners.T).T + X_camera_board[:3, 3]
    if (cam[:, 2] < 0.1).any():
        return False
    px = (K @ cam.T).T
    px = px[:, :2] / px[:, 2:]
    return ((px > margin_px) & (px < [WIDTH - margin_px, HEIGHT - margin_px])).all()


def eye_to_hand_views(renderer, rng, n=12, tilt_deg=25.0, only_about_z=False):
    """Camera fixed in the cell, board on the flange: (views, X_task_camera truth)."""
    X_task_camera = look_at(np.array([0.15, -0.30, 0.65]), [0.15, 0.15, 0.15])
    X_flange_board = transform((-0.105, -0.075, 0.03), (180, 0, 0)) @ transform(rotvec_deg=(0, 0, 15))
    views = []
    while len(views) < n:
        if only_about_z:  # degenerate: every board orientation differs by a turn about the view axis
            tilt = (0.0, 0.0, rng.uniform(-60, 60))
        else:
            tilt = (rng.uniform(-tilt_deg, tilt_deg), rng.uniform(-tilt_deg, tilt_deg), rng.uniform(-40, 40))
        R = X_task_camera[:3, :3] @ Rotation.from_rotvec(np.radians(tilt)).as_matrix()
        centre = np.array([0.15, 0.15, 0.20]) + rng.uniform([-0.08, -0.06, -0.06], [0.08, 0.06, 0.06])
        X_task_board = np.eye(4)
        X_task_board[:3, :3] = R
        X_task_board[:3, 3] = centre - R @ renderer.centre()
        X_camera_board = np.linalg.inv(X_task_camera) @ X_task_board
        if not visible(X_camera_board, renderer):
            continue
        X_task_flange = X_task_board @ np.linalg.inv(X_flange_board)
        views.append((f"view {len(views)}", renderer.render(X_camera_board, rng), X_task_flange))
    return views, X_task_camera


def eye_in_hand_views(renderer, rng, n=12):
    """Camera on the flange, board on the table: (views, X_flange_camera truth)."""
    X_task_board = np.eye(4)
    X_task_board[:3, :3] = Rotation.from_rotvec([np.pi, 0, 0]).as_matrix()  # board z down, away from the camera
    X_task_board[:3, 3] = np.array([0.15, 0.15, 0.05]) - X_task_board[:3, :3] @ renderer.centre()
    X_flange_camera = transform((0.065, 0.0, 0.045), (4, -3, 90))
    views = []
    while len(views) < n:
        eye = np.array([0.15, 0.15, 0.05]) + rng.uniform([-0.15, -0.15, 0.33], [0.15, 0.15, 0.50])
        X_task_camera = look_at(eye, np.array([0.15, 0.15, 0.05]) + rng.uniform(-0.03, 0.03, 3)) \
            @ transform(rotvec_deg=(0, 0, rng.uniform(-45, 45)))
        X_camera_board = np.linalg.inv(X_task_camera) @ X_task_board
        if not visible(X_camera_board, renderer):
            continue
        X_task_flange = X_task_camera @ np.linalg.inv(X_flange_camera)
        views.append((f"view {len(views)}", renderer.render(X_camera_board, rng), X_task_flange))
    return views, X_flange_camera


@pytest.mark.parametrize("mode", ["eye_to_hand", "eye_in_hand"])
def test_recovers_the_camera_pose_within_2_mm_and_half_a_degree(renderer, mode):
    rng = np.random.default_rng(7)
    make = eye_to_hand_views if mode == "eye_to_hand" else eye_in_hand_views
    views, truth = make(renderer, rng)
    result = calibrate(views, K, DIST, TARGET, mode)
    error_mm, error_deg = pose_difference(result.X, truth)
    print(f"\n{mode}: {result.views} views, 1280x720, pixel noise sigma 2 gray levels: "
          f"error {error_mm:.3f} mm / {error_deg:.4f} deg (limit {TOLERANCE_MM} mm / {TOLERANCE_DEG} deg); "
          f"residual {result.residual_mm:.3f} mm / {result.residual_deg:.4f} deg; "
          f"reprojection {result.reprojection_px:.3f} px")
    assert error_mm < TOLERANCE_MM and error_deg < TOLERANCE_DEG
    assert result.residual_mm < 2.0 and result.reprojection_px < 1.0
    assert len(result.pose_xyz_quat) == 7


def test_board_not_found(renderer):
    blank = np.full((HEIGHT, WIDTH), 120, np.uint8)
    with pytest.raises(CalibrationError, match=r"^board not found in view 3 \(0 ChArUco corners"):
        detect_board(blank, K, DIST, TARGET, "view 3")
    wrong = CharucoTarget(dictionary="DICT_4X4_50")  # the print is 5x5: nothing decodes
    rng = np.random.default_rng(1)
    views, _ = eye_to_hand_views(renderer, rng, n=1)
    with pytest.raises(CalibrationError, match="board not found .* match the print"):
        detect_board(views[0][1], K, DIST, wrong, "view 0")


def test_too_few_views(renderer):
    rng = np.random.default_rng(2)
    views, _ = eye_to_hand_views(renderer, rng, n=3)
    blank = np.full((HEIGHT, WIDTH), 120, np.uint8)
    skipped = []
    views.append(("empty view", blank, np.eye(4)))
    with pytest.raises(CalibrationError, match=r"^too few views: 3 with the board found, need at least 5") as error:
        calibrate(views, K, DIST, TARGET, "eye_to_hand", log=skipped.append)
    print(f"\n{error.value}")
    assert len(skipped) == 1 and "empty view" in skipped[0]


def test_degenerate_motions_all_about_one_axis(renderer):
    rng = np.random.default_rng(3)
    views, _ = eye_to_hand_views(renderer, rng, n=8, only_about_z=True)
    with pytest.raises(CalibrationError, match=r"^degenerate motions: every rotation between views turns about one axis") as error:
        calibrate(views, K, DIST, TARGET, "eye_to_hand")
    print(f"\n{error.value}")
    # Pure translations: no rotation at all.
    X = [transform((0.01 * i, 0.02 * (i % 3), 0.0)) for i in range(6)]
    with pytest.raises(CalibrationError, match=r"^degenerate motions: the flange turned at most 0.0 deg"):
        solve_hand_eye(X, X, "eye_to_hand")


def test_unknown_mode_is_named():
    X = [transform(rotvec_deg=(10 * i, 5 * i * i, 0)) for i in range(6)]
    with pytest.raises(CalibrationError, match="mode 'eye_on_hand'"):
        solve_hand_eye(X, X, "eye_on_hand")
