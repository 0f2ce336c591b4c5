"""Small training scenes from a real TSDF fusion (tsdf.TSDFVolume) of an analytic box
ray-cast with numpy, labelled with top-down grasps over the box (the best-held, at the
centre, as power grasps) and explicit negatives on the table beside it: small enough
that a few epochs take seconds, structured enough that learning is measurable. Used by the training and score-calibration tests."""
import numpy as np

from gravgrasp_detector.perception import tsdf


def _box_depth(intr, T_task_camera, box_min, box_max, table_z=0.05):
    """Ray-cast depth [m] of an axis-aligned box on a table plane (numpy)."""
    u, v = np.meshgrid(np.arange(intr.width), np.arange(intr.height))
    rays_c = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u, float)], -1)
    R, t = T_task_camera[:3, :3], T_task_camera[:3, 3]
    d = rays_c @ R.T
    depth_along = np.full(u.shape, np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        s_table = (table_z - t[2]) / d[..., 2]
        depth_along = np.where(s_table > 0, s_table, np.inf)
        t0 = (box_min - t) / d
        t1 = (box_max - t) / d
        near = np.nanmax(np.minimum(t0, t1), -1)
        far = np.nanmin(np.maximum(t0, t1), -1)
        hit = (near <= far) & (near > 0)
        depth_along = np.where(hit & (near < depth_along), near, depth_along)
    depth_along[~np.isfinite(depth_along)] = 0.0
    return depth_along.astype(np.float32)  # rays_c has unit z: parameter == depth


def _look_at(eye, target):
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(z, [0, 0, 1.0]); x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4); T[:3, :3] = np.stack([x, y, z], 1); T[:3, 3] = eye
    return T


def make_scene(path, rng):
    size = rng.uniform(0.04, 0.07, size=2)
    height = rng.uniform(0.05, 0.12)
    centre = rng.uniform(0.11, 0.19, size=2)
    box_min = np.array([*(centre - size / 2), 0.05]); box_max = np.array([*(centre + size / 2), 0.05 + height])
    volume = tsdf.TSDFVolume()
    intr = tsdf.CameraIntrinsics(160, 120, 140.0, 140.0, 80.0, 60.0)
    for yaw in rng.uniform(0, 2 * np.pi, size=2):
        eye = np.array([0.15 + 0.5 * np.cos(yaw), 0.15 + 0.5 * np.sin(yaw), 0.55])
        T = _look_at(eye, np.array([0.15, 0.15, 0.05]))
        volume.integrate(_box_depth(intr, T, box_min, box_max), intr, T)
    # Top-down grasps across the box's narrow side: TCP 2 cm below the top face.
    vs = volume.voxel_size_m
    xs = np.arange(box_min[0] + 0.01, box_max[0] - 0.01, vs)
    ys = np.arange(box_min[1] + 0.01, box_max[1] - 0.01, vs)
    p = np.array([(x, y, box_max[2] - 0.02) for x in xs for y in ys])
    index = np.floor(p / vs).astype(np.int64)
    e_z = np.tile([0, 0, -1.0], (len(p), 1))
    e_x = np.tile([1.0, 0, 0] if size[1] < size[0] else [0, 1.0, 0], (len(p), 1))
    score = 40.0 - 200.0 * np.linalg.norm(p[:, :2] - centre, axis=1)  # best at the centre
    # Explicit negatives: top-down poses on the table 2 cm beside the box (the open
    # fingers would hit the table), as the scene stage lists colliding poses.
    beside = np.array([(box_max[0] + 0.02, y, 0.06) for y in ys] + [(box_min[0] - 0.02, y, 0.06) for y in ys])
    negative_index = np.unique(np.floor(beside / vs).astype(np.int64), axis=0)
    np.savez_compressed(path, tsdf=volume.grid(), label_index=index, label_score=score.astype(np.float32),
                        label_e_x=e_x.astype(np.float32), label_e_z=e_z.astype(np.float32),
                        # the best-held grasps (centre) as power, the rest precision
                        label_mode=np.where(score > 35, 0, 1).astype(np.uint8),
                        negative_index=negative_index.astype(np.uint8),
                        mode_names=np.asarray(("power", "precision", "none")))


def write_scenes(root, count, seed):
    """`count` scene files scene_000.npz ... in `root` (a folder that exists); -> root."""
    rng = np.random.default_rng(seed)
    for n in range(count):
        make_scene(root / f"scene_{n:03d}.npz", rng)
    return root
