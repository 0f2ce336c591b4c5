"""TSDF integration on analytic scenes: values, zero crossings, axis order, bad input."""
import numpy as np
import pytest

from gravgrasp_detector.perception.tsdf import (
    CameraIntrinsics,
    InputError,
    TSDFVolume,
    depth_from_millimetres,
    to_network_grid,
)

W, H = 640, 480
K = CameraIntrinsics(W, H, fx=540.0, fy=540.0, cx=319.5, cy=239.5)
CAM_Z = 0.70
TABLE_Z = 0.05
BOX = dict(x=(0.17, 0.26), y=(0.08, 0.20), top=0.125)  # offset in +x only


def top_down_pose(x=0.15, y=0.15, z=CAM_Z):
    """Optical frame looking straight down: x_cam = x_task, y_cam = -y_task, z_cam = -z_task."""
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = (x, y, z)
    return T


def pixel_rays(T):
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    d_cam = np.stack(((u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones_like(u, float)), -1)
    return d_cam @ T[:3, :3].T  # ray direction per unit optical depth, task frame


def analytic_depth(T):
    """Depth (m, float32) of table + box seen from a top-down camera inside the box's prism
    (no side wall is visible, so each ray hits the box top or the table)."""
    d = pixel_rays(T)
    cam = T[:3, 3]
    depth_top = (cam[2] - BOX["top"]) / -d[..., 2]
    p = cam + depth_top[..., None] * d
    on_box = (BOX["x"][0] <= p[..., 0]) & (p[..., 0] <= BOX["x"][1]) & (BOX["y"][0] <= p[..., 1]) & (p[..., 1] <= BOX["y"][1])
    depth_table = (cam[2] - TABLE_Z) / -d[..., 2]
    return np.where(on_box, depth_top, depth_table).astype(np.float32)


def expected_value(z_surface, vol, i, j, T):
    """Network value of every k along column (i, j) above a horizontal surface seen
    top-down. Open3D measures the SDF along the camera ray: the depth difference
    (voxel centre z - z_surface) times the ray's length per unit depth at the pixel
    the voxel centre projects to."""
    z = (np.arange(vol.resolution) + 0.5) * vol.voxel_size_m
    centres = np.stack(np.broadcast_arrays(*column_centres(vol, i, j), z), -1)
    p_cam = (centres - T[:3, 3]) @ T[:3, :3]
    u = np.floor(p_cam[:, 0] / p_cam[:, 2] * K.fx + K.cx + 0.5)
    v = np.floor(p_cam[:, 1] / p_cam[:, 2] * K.fy + K.cy + 0.5)
    ray_length = np.sqrt(1 + ((u - K.cx) / K.fx) ** 2 + ((v - K.cy) / K.fy) ** 2)
    d = np.clip((z - z_surface) * ray_length / vol.truncation_m, -1.0, 1.0)
    return np.where(np.abs(d) < 0.98, (d + 1) / 2, 0.0), z - z_surface


def column_centres(vol, i, j):
    return (np.array([i, j]) + 0.5) * vol.voxel_size_m


def test_plane_and_box_values_and_zero_crossing():
    vol = TSDFVolume(size_m=0.30, resolution=40, truncation_voxels=4)
    T = top_down_pose(x=0.215, y=0.14)  # above the box: its walls stay hidden
    vol.integrate(analytic_depth(T), K, T)
    grid, weights = vol.grid(), vol.weights()
    assert grid.shape == (40, 40, 40) and grid.dtype == np.float32

    checked = {"box": 0, "table": 0}
    for i in range(40):
        for j in range(40):
            x, y = column_centres(vol, i, j)
            margin = vol.voxel_size_m  # columns whose footprint is clearly on/off the box
            inside = BOX["x"][0] + margin < x < BOX["x"][1] - margin and BOX["y"][0] + margin < y < BOX["y"][1] - margin
            outside = not (BOX["x"][0] - 4 * margin < x < BOX["x"][1] + 4 * margin and BOX["y"][0] - 4 * margin < y < BOX["y"][1] + 4 * margin)
            if not (inside or outside):
                continue
            z_surface = BOX["top"] if inside else TABLE_Z
            want, sdf = expected_value(z_surface, vol, i, j, T)
            seen = weights[i, j] > 0
            if not seen[sdf > 0].all():
                continue  # column partly outside the camera's view
            np.testing.assert_allclose(grid[i, j][seen], want[seen], atol=1e-4)
            # Zero crossing: last voxel below the surface / first above, in the right voxels.
            k_surface = int(np.floor(z_surface / vol.voxel_size_m - 0.5))
            assert grid[i, j, k_surface] < 0.5 <= grid[i, j, k_surface + 1]
            # Deeper than the truncation behind the surface is never updated.
            assert (weights[i, j][sdf < -vol.truncation_m] == 0).all()
            checked["box" if inside else "table"] += 1
    assert checked["box"] > 50 and checked["table"] > 300, checked


def test_axis_order_is_x_y_z():
    vol = TSDFVolume()
    T = top_down_pose(x=0.215, y=0.14)
    vol.integrate(analytic_depth(T), K, T)
    grid = vol.grid()
    k_top = int(np.floor(BOX["top"] / vol.voxel_size_m - 0.5))
    # Just above the box top the grid reads "surface band" over the box footprint only:
    # box is x in [0.17, 0.26] -> i in [23, 34], y in [0.08, 0.20] -> j in [11, 26].
    band = (grid[:, :, k_top + 1] > 0) & (grid[:, :, k_top + 1] < 0.7)
    i_idx, j_idx = np.nonzero(band)
    assert 22 <= i_idx.min() and i_idx.max() <= 35
    assert 10 <= j_idx.min() and j_idx.max() <= 27


def test_oblique_view_zero_crossing_on_plane():
    vol = TSDFVolume()
    # Camera 0.5 m away looking down at 45 deg towards the cube centre along +y.
    eye = np.array([0.15, -0.2, 0.45])
    target = np.array([0.15, 0.15, TABLE_Z])
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.array([1.0, 0.0, 0.0])
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack((x, y, z), 1)
    T[:3, 3] = eye
    d = pixel_rays(T)
    depth = ((TABLE_Z - eye[2]) / d[..., 2]).astype(np.float32)
    depth[d[..., 2] >= 0] = 0.0  # rays that never reach the table
    vol.integrate(depth, K, T)
    grid, weights = vol.grid(), vol.weights()
    k = int(np.floor(TABLE_Z / vol.voxel_size_m - 0.5))
    seen = (weights[:, :, k] > 0) & (weights[:, :, k + 1] > 0)
    assert seen.sum() > 800
    assert (grid[:, :, k][seen] < 0.5).all() and (grid[:, :, k + 1][seen] >= 0.5).all()


def test_millimetre_depth_and_invalid_pixels_match_metres():
    T = top_down_pose()
    depth_m = analytic_depth(T)
    depth_mm = np.round(depth_m * 1000).astype(np.uint16)
    a, b = TSDFVolume(), TSDFVolume()
    a.integrate(depth_mm, K, T)
    b.integrate(depth_from_millimetres(depth_mm), K, T)
    np.testing.assert_array_equal(a.grid(), b.grid())

    # NaN, +inf and 0 are all "no return": same volume as leaving those pixels out.
    holes = depth_m.copy()
    holes[:100] = np.nan
    holes[100:200] = np.inf
    holes[200:240] = 0.0
    zeroed = depth_m.copy()
    zeroed[:240] = 0.0
    c, d = TSDFVolume(), TSDFVolume()
    c.integrate(holes, K, T)
    d.integrate(zeroed, K, T)
    np.testing.assert_array_equal(c.grid(), d.grid())


def test_reset_forgets_everything():
    vol = TSDFVolume()
    T = top_down_pose()
    vol.integrate(analytic_depth(T), K, T)
    assert vol.weights().any() and vol.frames_integrated == 1
    vol.reset()
    assert not vol.weights().any() and not vol.grid().any() and vol.frames_integrated == 0


def test_network_grid_convention():
    tsdf = np.array([0.0, 0.5, -0.5, 1.0, -1.0, 0.3], np.float32)
    weights = np.array([1, 1, 1, 1, 1, 0], np.float32)
    np.testing.assert_allclose(to_network_grid(tsdf, weights), [0.5, 0.75, 0.25, 0.0, 0.0, 0.0])


def test_intrinsics_from_camera_info_k():
    k = [540.0, 0, 319.5, 0, 541.0, 239.5, 0, 0, 1]
    assert CameraIntrinsics.from_k(k, 640, 480) == CameraIntrinsics(640, 480, 540.0, 541.0, 319.5, 239.5)


@pytest.mark.parametrize(
    "change, cause, words",
    [
        (dict(depth=np.zeros((240, 320), np.float32)), "size_mismatch", "320x240 but CameraInfo says 640x480"),
        (dict(depth=np.full((H, W), np.nan, np.float32)), "all_invalid_depth", "no valid pixel"),
        (dict(depth=np.ones((H, W), np.float64)), "encoding", "float32 metres or uint16 millimetres"),
        (dict(intrinsics=CameraIntrinsics(W, H, 0.0, 0.0, 0.0, 0.0)), "camera_info_k", "not calibrated"),
        (dict(pose=top_down_pose(z=9.0)), "camera_pose_far", "from the workspace centre"),
        (dict(pose=top_down_pose(z=-0.3)), "camera_pose_behind", "behind the camera"),
        (dict(pose=np.diag([2.0, 1.0, 1.0, 1.0])), "camera_pose_rotation", "not a proper rotation"),
    ],
)
def test_bad_input_raises_one_clear_error(change, cause, words):
    vol = TSDFVolume()
    T = top_down_pose()
    args = dict(depth=analytic_depth(T), intrinsics=K, pose=T)
    args.update(change)
    with pytest.raises(InputError) as e:
        vol.integrate(args["depth"], args["intrinsics"], args["pose"])
    assert e.value.cause == cause
    assert words in str(e.value)
    assert vol.frames_integrated == 0 and not vol.weights().any()


def test_grid_equals_vgn_voxel_grid_extraction():
    """VGN reads its network input voxel by voxel from Open3D's extract_voxel_grid();
    grid() must give exactly those numbers (and 0 where VGN leaves voxels out)."""
    vol = TSDFVolume()
    T = top_down_pose(x=0.215, y=0.14)
    vol.integrate(analytic_depth(T), K, T)
    vgn = np.zeros((40, 40, 40), np.float32)
    for voxel in vol._volume.extract_voxel_grid().get_voxels():
        i, j, k = voxel.grid_index
        vgn[i, j, k] = voxel.color[0]
    assert (vgn > 0).sum() > 1000
    np.testing.assert_allclose(vol.grid(), vgn, atol=1e-6)
