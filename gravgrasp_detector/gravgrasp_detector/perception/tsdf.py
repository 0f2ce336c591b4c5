"""Truncated signed distance volume of the workspace (Open3D), as the network sees it.

Frames and layout (DESIGN.md, gravgrasp_msgs/msg/TSDFVolume.msg):
- The volume is a cube of `size_m` in the gravity-aligned `task` frame (z up) whose
  corner sits at the task origin; voxel (i, j, k) centre =
  (i + 0.5, j + 0.5, k + 0.5) * voxel_size_m, i along task x, k along task z.
- Arrays are C order (i, j, k), i.e. flat index = (i * res + j) * res + k.

Value convention of `grid()` (the network input), identical to VGN's grid:
- v = (d / truncation + 1) / 2 for voxels observed at least once whose truncated
  signed distance d lies strictly inside the band (|d| < 0.98 * truncation);
  0.5 on the surface, > 0.5 in front of it (free space towards the camera),
  < 0.5 behind it (inside the object). d is Open3D's: the depth difference along the
  camera ray (times the ray length per unit depth), averaged over frames.
- v = 0 for voxels never observed AND for observed voxels at or beyond the
  truncation band (far free space, deep behind a surface). `weights()` tells the
  two apart (0 = never observed).

Depth images follow REP-118: float32 metres, or uint16 millimetres via
`depth_from_millimetres`; 0, NaN and +/-inf are "no return".
"""

from dataclasses import dataclass

import numpy as np

# Name of the value convention above; stored in model files and checked on load.
TSDF_CONVENTION = "vgn-0.5-surface-band-only-unobserved-0"

# Voxels whose normalised |d| reaches this are dropped from the grid (VGN/Open3D).
_BAND_LIMIT = 0.98


class InputError(ValueError):
    """Bad sensor input. `cause` is a short stable key (one report per cause)."""

    def __init__(self, cause, message):
        super().__init__(message)
        self.cause = cause


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics in pixels of the depth image (sensor_msgs/CameraInfo K)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def from_k(cls, k, width, height):
        """From a row-major 3x3 K (CameraInfo.k, 9 values) and the image size."""
        k = np.asarray(k, dtype=np.float64).reshape(-1)
        if k.size != 9:
            raise InputError("camera_info_k", f"K must have 9 values, got {k.size}")
        return cls(int(width), int(height), float(k[0]), float(k[4]), float(k[2]), float(k[5]))

    def check(self):
        """Raise InputError unless these intrinsics describe a calibrated camera."""
        if self.width <= 0 or self.height <= 0:
            raise InputError(
                "camera_info_size",
                f"CameraInfo size is {self.width}x{self.height}: the camera driver "
                "must publish the image width and height",
            )
        if not (self.fx > 0 and self.fy > 0 and np.isfinite([self.cx, self.cy]).all()):
            raise InputError(
                "camera_info_k",
                f"CameraInfo K has fx={self.fx}, fy={self.fy}, cx={self.cx}, cy={self.cy}: "
                "the camera is not calibrated; publish its calibration (K with fx, fy > 0)",
            )

    @property
    def matrix(self):
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


DEPTH_ENCODINGS = {"16UC1": np.uint16, "32FC1": np.float32}


def depth_from_millimetres(depth_mm):
    """uint16 depth in millimetres (REP-118 16UC1) -> float32 metres, 0 stays 0."""
    depth_mm = np.asarray(depth_mm)
    if depth_mm.dtype != np.uint16:
        raise InputError(
            "encoding", f"millimetre depth must be uint16, got {depth_mm.dtype}"
        )
    return depth_mm.astype(np.float32) * np.float32(0.001)


def depth_from_image_msg(msg):
    """sensor_msgs/Image (or any message with its fields: rosbags reads them too) -> HxW uint16 (mm)
    or float32 (m) array. Raises InputError. No ROS import: the node and the benchmark share it."""
    dtype = DEPTH_ENCODINGS.get(msg.encoding)
    if dtype is None:
        raise InputError(
            "encoding",
            f"depth image encoding is {msg.encoding!r}: publish 16UC1 (millimetres) or "
            "32FC1 (metres) per REP-118, e.g. remap depth/image to the camera's depth "
            "(not colour or disparity) topic",
        )
    itemsize = np.dtype(dtype).itemsize
    if msg.step < msg.width * itemsize or len(msg.data) < msg.step * msg.height or msg.width * msg.height == 0:
        raise InputError(
            "malformed_image",
            f"depth image {msg.width}x{msg.height} {msg.encoding} with step {msg.step} carries "
            f"{len(msg.data)} bytes (need step >= {msg.width * itemsize} and step x height "
            "bytes): the publisher fills the message wrongly",
        )
    rows = np.frombuffer(bytes(msg.data), np.uint8, msg.step * msg.height).reshape(msg.height, msg.step)
    depth = rows[:, : msg.width * itemsize].copy().view(np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<"))
    return depth.astype(dtype, copy=False)


def check_camera_pose(T_task_camera, size_m, max_distance_m=3.0):
    """Raise InputError unless T_task_camera is a rigid transform that can see the cube.

    The camera is in the optical convention (z forward, x right, y down).
    """
    T = np.asarray(T_task_camera, dtype=np.float64)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise InputError(
            "camera_pose_matrix",
            "camera pose must be a finite 4x4 transform T_task_camera",
        )
    R = T[:3, :3]
    if (
        not np.allclose(R.T @ R, np.eye(3), atol=1e-3)
        or np.linalg.det(R) < 0
        or not np.allclose(T[3], [0, 0, 0, 1])
    ):
        raise InputError(
            "camera_pose_rotation",
            "camera pose rotation is not a proper rotation (check the quaternion is "
            "normalised and the matrix is T_task_camera, not its inverse)",
        )
    centre = np.full(3, size_m / 2)
    distance = np.linalg.norm(T[:3, 3] - centre)
    if distance > max_distance_m:
        raise InputError(
            "camera_pose_far",
            f"camera is {distance:.2f} m from the workspace centre (max {max_distance_m} m): "
            "give the pose of the camera optical frame in the task frame, in metres",
        )
    centre_in_camera = R.T @ (centre - T[:3, 3])
    if centre_in_camera[2] <= 0:
        raise InputError(
            "camera_pose_behind",
            "the workspace is behind the camera (its centre has z <= 0 in the camera "
            "frame): the pose must be of the optical frame (z forward, x right, y down)",
        )


# The volume the scenes are fused into (and so the models' input).
SIZE_M, RESOLUTION, TRUNCATION_VOXELS = 0.30, 40, 4


def volume_metadata(size_m=SIZE_M, resolution=RESOLUTION, truncation_voxels=TRUNCATION_VOXELS):
    """What a model file records of the volume it was trained on (TSDFVolume's defaults
    are the scenes'); needs no Open3D, so a training machine without it can write models."""
    voxel_size_m = float(size_m) / int(resolution)
    return {"size_m": float(size_m), "resolution": int(resolution), "voxel_size_m": voxel_size_m,
            "truncation_m": truncation_voxels * voxel_size_m, "convention": TSDF_CONVENTION}


class TSDFVolume:
    """Fuses depth images into a `resolution`^3 TSDF of a `size_m` cube (task frame)."""

    def __init__(self, size_m=SIZE_M, resolution=RESOLUTION, truncation_voxels=TRUNCATION_VOXELS, max_depth_m=3.0):
        self.size_m = float(size_m)
        self.resolution = int(resolution)
        self.voxel_size_m = self.size_m / self.resolution
        self.truncation_voxels = truncation_voxels
        self.truncation_m = truncation_voxels * self.voxel_size_m
        self.max_depth_m = float(max_depth_m)  # farther returns are ignored
        self.origin = np.zeros(3)  # grid corner in the task frame
        self._intrinsics_cache = (None, None)
        self._dummy_color = None
        # lazy: open3d costs ~2 s of CPU to import, and the nodes that only read volumes
        # (detect, execute) import this module but never integrate.
        import open3d

        self._o3d = open3d
        self.reset()

    def reset(self):
        """Forget every integrated frame."""
        # A new volume: UniformTSDFVolume.reset() in Open3D 0.20 keeps the voxel values.
        self._volume = self._o3d.pipelines.integration.UniformTSDFVolume(
            length=self.size_m,
            resolution=self.resolution,
            sdf_trunc=self.truncation_m,
            color_type=self._o3d.pipelines.integration.TSDFVolumeColorType.NoColor,
            origin=self.origin.reshape(3, 1),
        )
        self.frames_integrated = 0

    def integrate(self, depth, intrinsics, T_task_camera):
        """Fuse one depth image.

        depth: HxW float32 metres (0/NaN/inf = no return) or uint16 millimetres.
        intrinsics: CameraIntrinsics of that image. T_task_camera: 4x4 pose of the
        camera optical frame in the task frame. Raises InputError on bad input.
        """
        depth = np.asarray(depth)
        if depth.dtype == np.uint16:
            depth = depth_from_millimetres(depth)
        elif depth.dtype != np.float32:
            raise InputError(
                "encoding",
                f"depth must be float32 metres or uint16 millimetres, got {depth.dtype}",
            )
        intrinsics.check()
        if depth.shape != (intrinsics.height, intrinsics.width):
            raise InputError(
                "size_mismatch",
                f"depth image is {depth.shape[1]}x{depth.shape[0]} but CameraInfo says "
                f"{intrinsics.width}x{intrinsics.height}: use the CameraInfo published "
                "with this depth stream (same camera namespace)",
            )
        check_camera_pose(T_task_camera, self.size_m)
        valid = np.isfinite(depth) & (depth > 0) & (depth <= self.max_depth_m)
        if not valid.any():
            raise InputError(
                "all_invalid_depth",
                "depth image has no valid pixel (all 0/NaN/inf or beyond "
                f"{self.max_depth_m} m): check the camera sees the workspace within its "
                "range and is not covered",
            )
        # Open3D treats NaN as no return but +inf as a hit at infinity: zero them all.
        depth = np.where(valid, depth, np.float32(0.0)).astype(np.float32, copy=False)

        rgbd = self._o3d.geometry.RGBDImage()
        rgbd.depth = self._o3d.geometry.Image(depth)
        rgbd.color = self._color_placeholder(depth.shape)
        self._volume.integrate(
            rgbd, self._o3d_intrinsics(intrinsics), np.linalg.inv(T_task_camera)
        )
        self.frames_integrated += 1

    def tsdf_and_weights(self):
        """(d / truncation in [-1, 1], integration weight), each float32 (res, res, res)."""
        values = np.asarray(self._volume.extract_volume_tsdf(), dtype=np.float32)
        shape = (self.resolution,) * 3
        return values[:, 0].reshape(shape), values[:, 1].reshape(shape)

    def grid(self):
        """The network input: float32 (res, res, res) in the convention of the module doc."""
        tsdf, weights = self.tsdf_and_weights()
        return to_network_grid(tsdf, weights)

    def weights(self):
        return self.tsdf_and_weights()[1]

    def _o3d_intrinsics(self, intrinsics):
        key, cached = self._intrinsics_cache
        if key != intrinsics:
            cached = self._o3d.camera.PinholeCameraIntrinsic(
                intrinsics.width, intrinsics.height,
                intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy,
            )
            self._intrinsics_cache = (intrinsics, cached)
        return cached

    def _color_placeholder(self, shape):
        # Open3D wants a colour image even for NoColor volumes; it is never read.
        if self._dummy_color is None or self._dummy_color_shape != shape:
            self._dummy_color = self._o3d.geometry.Image(np.zeros(shape, np.uint8))
            self._dummy_color_shape = shape
        return self._dummy_color


def to_network_grid(tsdf, weights):
    """Normalised TSDF in [-1, 1] + weights -> network value convention (module doc)."""
    keep = (weights > 0) & (np.abs(tsdf) < _BAND_LIMIT)
    return np.where(keep, (tsdf + 1.0) * 0.5, 0.0).astype(np.float32)
