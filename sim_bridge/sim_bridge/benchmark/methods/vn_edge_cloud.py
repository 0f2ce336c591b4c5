"""The point cloud VN-EdgeGraspNet reads, from the project's TSDF of a view, made as its
authors' clutter test (test_clutter_grasp.py of github.com/HaojHuang/Edge-Grasp-Network)
makes it: a 180^3 TSDF of the 0.30 m cube (1.67 mm voxels, truncation 4 voxels, Open3D
UniformTSDFVolume), its surface points (Open3D's `extract_point_cloud`: one point per
sign change of the TSDF between two neighbouring observed voxels, interpolated along
their edge), cropped to the grasp workspace, outliers removed, normals estimated and
oriented, and down-sampled on a 4.5 mm voxel grid. Every Open3D step is called with the
authors' parameters; `surface_points` restates extract_point_cloud on the project's grid
(the grid holds (d + 1) / 2 on exactly the voxels extract_point_cloud reads), so the
benchmark's (grid, voxel size, origin) is all it needs."""

from __future__ import annotations

import dataclasses

import numpy as np

from gravgrasp_detector.perception.tsdf import TSDFVolume

from ...physics.scenes import TABLE_HEIGHT_M

SIZE_M, RESOLUTION, TRUNCATION_VOXELS = 0.30, 180, 4


def edge_volume() -> TSDFVolume:
    """The project's TSDF volume of the size and resolution VN-EdgeGraspNet's test uses."""
    return TSDFVolume(size_m=SIZE_M, resolution=RESOLUTION, truncation_voxels=TRUNCATION_VOXELS)


@dataclasses.dataclass(frozen=True)
class CloudOptions:
    """The authors' clutter-test constants (lengths in metres, task frame)."""

    border_m: float = 0.02  # the crop leaves this much of the cube's sides out
    above_table_m: float = 0.005  # and the points below the table top + this
    point_noise_m: float = 0.0008  # Gaussian, per coordinate: the test's --add_noise (on by default)
    min_points: int = 100  # fewer points: no detection
    outlier_neighbours: int = 30  # remove_statistical_outlier(nb_neighbors, std_ratio)
    outlier_std_ratio: float = 1.0
    radius_outlier_points: int = 30  # remove_radius_outlier(nb_points, radius)
    radius_outlier_m: float = 0.03
    normal_radius_m: float = 0.04  # estimate_normals(KDTreeSearchParamHybrid(radius, max_nn))
    normal_max_nn: int = 30
    orient_k: int = 30  # orient_normals_consistent_tangent_plane(k)
    voxel_down_m: float = 0.0045


def surface_points(grid, voxel_size_m: float, origin=np.zeros(3)) -> np.ndarray:
    """(N, 3) task-frame points where the TSDF changes sign between two neighbouring
    voxels, both observed within the band (grid != 0) and inside the volume's one-voxel
    border, at the linear zero crossing between their centres: Open3D's
    UniformTSDFVolume.extract_point_cloud, in its order (voxel by voxel, then x, y, z)."""
    grid = np.asarray(grid, dtype=np.float32)
    res = grid.shape[0]
    f = 2.0 * grid - 1.0  # back to d / truncation
    observed = grid != 0.0
    keys, points = [], []
    for axis in range(3):
        # voxels 1 .. res - 2 on every axis, and their +axis neighbour too
        lo, hi = [slice(1, res - 1)] * 3, [slice(1, res - 1)] * 3
        lo[axis], hi[axis] = slice(1, res - 2), slice(2, res - 1)
        lo, hi = tuple(lo), tuple(hi)
        f0, f1 = f[lo], f[hi]
        crossing = observed[lo] & observed[hi] & (f0 * f1 < 0)
        ijk = np.argwhere(crossing) + 1
        r0, r1 = np.abs(f0[crossing]).astype(np.float64), np.abs(f1[crossing]).astype(np.float64)
        p = (ijk + 0.5) * voxel_size_m
        p[:, axis] += voxel_size_m * r0 / (r0 + r1)
        points.append(p + np.asarray(origin, dtype=np.float64))
        keys.append(np.ravel_multi_index(ijk.T, grid.shape) * 3 + axis)
    order = np.argsort(np.concatenate(keys), kind="stable")
    return np.concatenate(points)[order]


def workspace_bounds(size_m=SIZE_M, table_z_m=TABLE_HEIGHT_M, options=CloudOptions()) -> tuple:
    """(lower, upper) of the crop, the authors' `sim.lower`, `sim.upper`."""
    b = options.border_m
    return np.array([b, b, table_z_m + options.above_table_m]), np.array([size_m - b, size_m - b, size_m])


def edge_point_cloud(points, rng: np.random.Generator, bounds=None, options=CloudOptions()):
    """Surface points (N, 3) -> (points (M, 3), normals (M, 3)) as float32, or None when
    too few are left (the authors' test then skips the view)."""
    import open3d as o3d  # lazy: ~2 s to import

    lower, upper = workspace_bounds(options=options) if bounds is None else bounds
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))
    cloud = cloud.crop(o3d.geometry.AxisAlignedBoundingBox(lower, upper))
    if options.point_noise_m > 0 and len(cloud.points):
        noisy = np.asarray(cloud.points) + rng.normal(0.0, options.point_noise_m, (len(cloud.points), 3))
        cloud.points = o3d.utility.Vector3dVector(noisy)
    if len(cloud.points) < options.min_points:
        return None
    cloud, _ = cloud.remove_statistical_outlier(nb_neighbors=options.outlier_neighbours,
                                                std_ratio=options.outlier_std_ratio)
    cloud, _ = cloud.remove_radius_outlier(nb_points=options.radius_outlier_points, radius=options.radius_outlier_m)
    if len(cloud.points) < options.min_points:
        return None
    cloud.estimate_normals(search_param=o3d.geometry.KDTreeSearchParamHybrid(radius=options.normal_radius_m,
                                                                             max_nn=options.normal_max_nn))
    cloud.orient_normals_consistent_tangent_plane(options.orient_k)
    cloud = cloud.voxel_down_sample(voxel_size=options.voxel_down_m)
    return np.asarray(cloud.points, dtype=np.float32), np.asarray(cloud.normals, dtype=np.float32)
