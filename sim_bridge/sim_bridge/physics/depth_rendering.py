"""Depth images of posed triangle meshes by ray casting (Open3D RaycastingScene).

Headless and CPU-only; used to render training scenes and test data, so they reach
the TSDF exactly as a camera's depth would. No rclpy.

Conventions: T_task_camera is the pose of the camera *optical* frame (z forward,
x right, y down) in the task frame; pixel (u, v) has its centre at integer
coordinates (OpenCV/ROS CameraInfo); depth is the optical-axis z of the hit in
metres, float32, 0 where a ray hits nothing (REP-118 "no return").
"""

import numpy as np
import open3d as o3d


class DepthRenderer:
    """A fixed set of meshes; render() it from any number of views."""

    def __init__(self, meshes):
        """meshes: trimesh.Trimesh already in the task frame, or (mesh, T_task_mesh) pairs."""
        self._scene = o3d.t.geometry.RaycastingScene()
        for item in meshes:
            mesh, T = item if isinstance(item, tuple) else (item, np.eye(4))
            vertices = np.asarray(mesh.vertices, np.float64) @ np.asarray(T)[:3, :3].T + np.asarray(T)[:3, 3]
            self._scene.add_triangles(
                o3d.core.Tensor(vertices.astype(np.float32)),
                o3d.core.Tensor(np.asarray(mesh.faces, np.uint32)),
            )
        self._ray_cache = (None, None)

    def render(self, intrinsics, T_task_camera, max_depth_m=np.inf):
        """float32 (height, width) depth in metres; 0 = no hit (or beyond max_depth_m)."""
        T = np.asarray(T_task_camera, np.float64)
        d_cam = self._camera_rays(intrinsics)  # (H, W, 3), z = 1: t_hit is then depth
        d_task = d_cam @ T[:3, :3].T
        origins = np.broadcast_to(T[:3, 3], d_task.shape)
        rays = np.concatenate((origins, d_task), axis=-1).astype(np.float32)
        t_hit = self._scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        hit = np.isfinite(t_hit) & (t_hit <= max_depth_m)
        return np.where(hit, t_hit, 0.0).astype(np.float32)

    def _camera_rays(self, k):
        key = (k.width, k.height, k.fx, k.fy, k.cx, k.cy)
        if self._ray_cache[0] != key:
            u, v = np.meshgrid(np.arange(k.width, dtype=np.float64), np.arange(k.height, dtype=np.float64))
            rays = np.stack(((u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u)), axis=-1)
            self._ray_cache = (key, rays)
        return self._ray_cache[1]


def render_depth(meshes, intrinsics, T_task_camera, max_depth_m=np.inf):
    """One-shot DepthRenderer(meshes).render(...)."""
    return DepthRenderer(meshes).render(intrinsics, T_task_camera, max_depth_m)


def look_at(eye, target, up=(0.0, 0.0, 1.0)):
    """T_task_camera (optical frame) of a camera at `eye` looking at `target`.

    Image "up" (-y) points as close to `up` as possible; when looking along `up`,
    task +y is used instead so the result is always defined.
    """
    eye, target, up = (np.asarray(a, np.float64) for a in (eye, target, up))
    z = target - eye
    norm = np.linalg.norm(z)
    if norm < 1e-9:
        raise ValueError("look_at: eye and target coincide")
    z /= norm
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-6:
        x = np.cross(z, (0.0, 1.0, 0.0))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack((x, y, z), axis=1)
    T[:3, 3] = eye
    return T


def random_view_on_hemisphere(rng, target, radius_m=(0.45, 0.65), elevation_deg=(30.0, 80.0), azimuth_deg=(0.0, 360.0)):
    """T_task_camera looking at `target` from a random point of the upper hemisphere.

    rng: numpy Generator. Elevation is measured from the horizontal plane (90 = above).
    """
    r = rng.uniform(*radius_m)
    elevation = np.radians(rng.uniform(*elevation_deg))
    azimuth = np.radians(rng.uniform(*azimuth_deg))
    offset = r * np.array([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
    return look_at(np.asarray(target, np.float64) + offset, target)
