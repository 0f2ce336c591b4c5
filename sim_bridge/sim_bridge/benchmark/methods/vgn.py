"""VGN (Breyer et al., CoRL 2020) with its published weights as a detector: a view's TSDF
-> ranked grasps for the Panda hand. Written from VGN's corl2020 source (networks.py,
detection.py, perception.py, simulation.py of github.com/ethz-asl/vgn).

Input. VGN reads a 40^3 TSDF of a 0.30 m cube with its corner at the origin and the table
top at z = 0.05 m (Open3D UniformTSDFVolume, truncation 4 voxels), holding (d / trunc + 1)
/ 2 on observed voxels inside the truncation band (0.5 on the surface) and 0 elsewhere
(`get_grid`). The project's volume (`gravgrasp_detector.perception.tsdf`, `vgn_volume()` here) is
that volume: the same Open3D integration, cube, resolution, truncation and values, and the
benchmark's table top is at 0.05 m too. So the grid passes as it is, with no resampling;
tests/sim_bridge/test_vgn_method.py checks it voxel for voxel against get_grid's way.

Output -> grasps (VGN's detection.py): quality smoothed by a Gaussian (sigma 1 voxel);
quality zeroed except within 2 dilations (6-connected) of observed free space (grid > 0.5)
that do not enter observed inside (1e-3 < grid < 0.5); widths outside [1.33, 9.33] voxels
rejected; quality below 0.90 dropped; non-maximum suppression by a 4-voxel maximum filter.
Each surviving voxel is a grasp: orientation from the unit quaternion (x, y, z, w),
position voxel index x voxel size (VGN's training labels round position / voxel size, so
the index, not the voxel centre index + 0.5 the project's own detection uses; 3.75 mm per
axis apart), width in voxels x voxel size. VGN's clutter-removal run executes a random
one of them; these are ranked by quality, best first, as GIGA's `--best` evaluation (the
numbers the benchmark compares against) does.

Grasp frame. VGN's grasp pose is the Panda hand's TCP as VGN's simulation places it:
z = approach (hand towards the object), y = the axis the fingers close along, x = y x z;
origin on the hand's axis 0.062 m from the URDF `panda_hand` link frame (PyBullet's body
frame is the link's centre of mass, 0.04 m up z, and VGN's T_body_tcp adds 0.022), about
at the fingers' base: the finger tips are 0.05 m (VGN's finger_depth) further along z.
That is physics.panda_hand's TCP frame (HAND_TO_TCP_M, FINGER_DEPTH_M), which the Panda
executor moves; the project's TCP frame for the 2F-85 (robotiq_driver.hand_geometry,
grasp_execution) has the same axes. So the pose passes unchanged: a VGN grasp is
T_task_tcp for the Panda hand.
"""

from __future__ import annotations

import collections.abc
import dataclasses
import pathlib

import numpy as np
import torch
import torch.nn.functional as F
from scipy import ndimage
from scipy.spatial.transform import Rotation
from torch import nn

from gravgrasp_detector.perception import hand_clearance
from gravgrasp_detector.execution.executor import ExecutionLimits
from gravgrasp_detector.perception.detection import Grasp
from gravgrasp_detector.perception.tsdf import TSDFVolume
from robotiq_driver.hand_geometry import FINGER_TIP_Z_M

from ...physics.baseline_files import SOURCES, BaselineFileMissing, baseline_file
from ..sim_cell import HAND_GEOMETRY
from .method import Detector

MODEL_FILE = "vgn/vgn_conv.pth"  # in the baselines directory
SIZE_M, RESOLUTION, TRUNCATION_VOXELS = 0.30, 40, 4
VOXEL_SIZE_M = SIZE_M / RESOLUTION


class VGNModelError(ValueError):
    """A model file that is not VGN's published ConvNet."""


@dataclasses.dataclass(frozen=True)
class VGNOptions:
    """VGN's post-processing constants (detection.py's defaults); voxels of VOXEL_SIZE_M."""

    gaussian_sigma_voxels: float = 1.0
    min_width_voxels: float = 1.33
    max_width_voxels: float = 9.33
    quality_threshold: float = 0.90
    nms_size_voxels: int = 4
    max_grasps: int | None = None  # None: all that survive


@dataclasses.dataclass
class VGNGrasp(Grasp):
    """A project Grasp (pose T_task_tcp, VGN's TCP; validness and rank_key VGN's quality,
    a success probability, and score_n NaN: VGN has no score in N, as the project's binary
    models have none) with VGN's predicted opening. VGN's simulation opens the fingers
    fully whatever the width."""

    width_m: float = dataclasses.field(kw_only=True)  # after Grasp's defaulted fields (rank_key)


# the network (networks.py's ConvNet; attribute names are the state dict's)


def _conv(in_channels, out_channels, kernel, stride=1):
    return nn.Conv3d(in_channels, out_channels, kernel, stride=stride, padding=kernel // 2)


class _Encoder(nn.Module):
    """40^3 -> 5^3: three stride-2 convolutions, each followed by a ReLU."""

    def __init__(self):
        super().__init__()
        self.conv1, self.conv2, self.conv3 = _conv(1, 16, 5, 2), _conv(16, 32, 3, 2), _conv(32, 64, 3, 2)

    def forward(self, x):
        for conv in (self.conv1, self.conv2, self.conv3):
            x = F.relu(conv(x))
        return x


class _Decoder(nn.Module):
    """5^3 -> 40^3: convolution, ReLU, nearest-neighbour upsampling to 10, 20 and 40."""

    def __init__(self):
        super().__init__()
        self.conv1, self.conv2, self.conv3 = _conv(64, 64, 3), _conv(64, 32, 3), _conv(32, 16, 5)

    def forward(self, x):
        for conv, size in ((self.conv1, 10), (self.conv2, 20), (self.conv3, 40)):
            x = F.interpolate(F.relu(conv(x)), size)
        return x


class VGNNet(nn.Module):
    """(B, 1, 40, 40, 40) grid -> quality (sigmoid), unit quaternion (x, y, z, w), width
    [voxels], each per voxel at 40^3."""

    def __init__(self):
        super().__init__()
        self.encoder, self.decoder = _Encoder(), _Decoder()
        self.conv_qual, self.conv_rot, self.conv_width = _conv(16, 1, 5), _conv(16, 4, 5), _conv(16, 1, 5)

    def forward(self, x):
        x = self.decoder(self.encoder(x))
        return torch.sigmoid(self.conv_qual(x)), F.normalize(self.conv_rot(x), dim=1), self.conv_width(x)


def read_state_dict(path, error, where: str):
    """The tensors of the file at `path`; `error` (an exception class) with one sentence
    ending in `where` (where the right file is) if it is not a state dict."""
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # zip, pickle or unsafe-type errors all mean "not a state dict"
        raise error(f"{path} is not a PyTorch state dict (torch.load, tensors only, raised "
                    f"{type(e).__name__}); {where}") from e
    if not isinstance(state, collections.abc.Mapping):
        raise error(f"{path} holds a {type(state).__name__}, not a state dict; {where}")
    return state


def state_dict_mismatches(state, expected, whose: str = "VGN's") -> list:
    """Every way `state` differs from `expected` (name -> tensor): missing, unexpected and
    mis-shaped tensors, one entry each (`whose`: the model the expected shapes are)."""
    problems = [f"missing {name} {tuple(t.shape)}" for name, t in expected.items() if name not in state]
    problems += [f"unexpected {name}" for name in state if name not in expected]
    problems += [f"{name} is {tuple(state[name].shape)}, {whose} is {tuple(t.shape)}"
                 for name, t in expected.items()
                 if name in state and tuple(getattr(state[name], "shape", ())) != tuple(t.shape)]
    return problems


def load_vgn(path=None, baselines_dir=None) -> VGNNet:
    """VGN's ConvNet with the weights of `path` (default: MODEL_FILE in the baselines
    directory), in eval mode. Strict: a file that is not exactly VGN's 18 tensors raises one
    VGNModelError naming every missing, unexpected or mis-shaped one; a missing file
    raises BaselineFileMissing saying where to get it."""
    if path is None:
        path = baseline_file(MODEL_FILE, baselines_dir)
    path = pathlib.Path(path)
    if not path.is_file():
        raise BaselineFileMissing(f"VGN model file {path} not found: get it from {SOURCES['vgn']}, or leave the "
                                  f"path out to read {MODEL_FILE} from the baselines directory (--baselines DIR)")
    state = read_state_dict(path, VGNModelError, f"VGN's model is {SOURCES['vgn']}")
    net = VGNNet()
    problems = state_dict_mismatches(state, net.state_dict())
    if problems:
        raise VGNModelError(f"{path} is not VGN's ConvNet ({len(problems)} problems): " + "; ".join(problems))
    net.load_state_dict(state, strict=True)
    return net.eval()


# the input


def vgn_volume() -> TSDFVolume:
    """The project's TSDF volume VGN reads (see the module doc)."""
    return TSDFVolume(size_m=SIZE_M, resolution=RESOLUTION, truncation_voxels=TRUNCATION_VOXELS)


def vgn_input(tsdf) -> tuple:
    """The benchmark's (grid, voxel_size_m, origin) -> (grid float32 (40, 40, 40),
    T_task_grid 4x4). Raises ValueError for a volume VGN was not trained on."""
    grid, voxel_size_m, origin = tsdf
    grid = np.asarray(grid, dtype=np.float32)
    if grid.shape != (RESOLUTION,) * 3 or not np.isclose(voxel_size_m, VOXEL_SIZE_M):
        raise ValueError(f"VGN reads a {RESOLUTION}^3 TSDF of {VOXEL_SIZE_M * 1e3:.1f} mm voxels, got "
                         f"{grid.shape} of {voxel_size_m * 1e3:.2f} mm: make the volume with vgn_volume()")
    origin = np.asarray(origin, dtype=np.float64)
    if origin.shape == (3,):
        T_task_grid = np.eye(4)
        T_task_grid[:3, 3] = origin
    elif origin.shape == (4, 4):
        T_task_grid = origin
    else:
        raise ValueError(f"origin must be a 3-vector or a 4x4 transform, got shape {origin.shape}")
    return grid, T_task_grid


# the output (detection.py's predict, process, select)


@torch.inference_mode()
def predict(net: VGNNet, grid) -> tuple:
    """(quality (40,)*3, quaternions (4, 40, 40, 40) x y z w, width (40,)*3 [voxels])."""
    x = torch.as_tensor(np.asarray(grid, dtype=np.float32))[None, None]
    quality, quaternions, width = net(x)
    return quality[0, 0].numpy(), quaternions[0].numpy(), width[0, 0].numpy()


FREE_SPACE_DILATIONS = 2  # VGN's detection.py
# Where VGN's TCP (the Panda's finger base, VGN's finger depth of 5 cm behind the finger
# tips) would sit on a 2F-85 grasp: along its approach, in the 2F-85's TCP frame
FINGER_BASE_Z_M = FINGER_TIP_Z_M - 0.05


def free_space_band(grid):
    """(R, R, R) bool tensor: VGN's mask (its detection.py's `process`) on a grid in tsdf.py's
    convention, numpy or torch: observed free space (grid > 0.5), grown by FREE_SPACE_DILATIONS
    six-connected steps that never enter observed inside (1e-3 < grid < 0.5). scipy's
    binary_dilation(grid > 0.5, iterations=2, mask=~inside), as VGN calls it."""
    grid = torch.as_tensor(grid)
    may_grow = ~((grid > 1e-3) & (grid < 0.5))
    kept = grid > 0.5
    for _ in range(FREE_SPACE_DILATIONS):
        grown = kept.clone()
        for dim in range(3):
            n = kept.shape[dim]
            ahead, behind = grown.narrow(dim, 1, n - 1), grown.narrow(dim, 0, n - 1)
            ahead |= kept.narrow(dim, 0, n - 1)
            behind |= kept.narrow(dim, 1, n - 1)
        kept = kept | (grown & may_grow)
    return kept


def mask_quality(grid, quality, width_voxels, options: VGNOptions = VGNOptions()):
    """Smoothed quality, 0 away from observed free space, inside objects and at widths
    out of range (detection.py's `process`)."""
    quality = ndimage.gaussian_filter(quality, sigma=options.gaussian_sigma_voxels, mode="nearest")
    quality[~free_space_band(grid).numpy()] = 0.0
    quality[(width_voxels < options.min_width_voxels) | (width_voxels > options.max_width_voxels)] = 0.0
    return quality


def select_grasps(quality, quaternions, width_voxels, voxel_size_m=VOXEL_SIZE_M, T_task_grid=np.eye(4),
                  options: VGNOptions = VGNOptions()) -> list:
    """Masked quality -> VGNGrasps ranked by quality, best first (detection.py's `select`,
    then the order of GIGA's --best)."""
    quality = np.where(quality < options.quality_threshold, 0.0, quality)
    peaks = (quality > 0) & (quality == ndimage.maximum_filter(quality, size=options.nms_size_voxels))
    index = np.argwhere(peaks)
    order = np.argsort(-quality[peaks], kind="stable")[:options.max_grasps]
    grasps = []
    for i, j, k in index[order]:
        pose = np.eye(4)
        pose[:3, :3] = Rotation.from_quat(quaternions[:, i, j, k]).as_matrix()
        pose[:3, 3] = np.array([i, j, k], dtype=np.float64) * voxel_size_m
        q = float(quality[i, j, k])
        grasps.append(VGNGrasp(pose=T_task_grid @ pose, score_n=float("nan"), validness=q, rank_key=q,
                               voxel_index=(int(i), int(j), int(k)),
                               width_m=float(width_voxels[i, j, k]) * voxel_size_m))
    return grasps


def make_vgn_detector(net: VGNNet, options: VGNOptions = VGNOptions()):
    """The benchmark's detect callable: (grid, voxel_size_m, origin) -> ranked VGNGrasps."""

    def detect(tsdf):
        grid, T_task_grid = vgn_input(tsdf)
        if not grid.any():
            return []
        quality, quaternions, width_voxels = predict(net, grid)
        quality = mask_quality(grid, quality, width_voxels, options)
        return select_grasps(quality, quaternions, width_voxels, VOXEL_SIZE_M, T_task_grid, options)
    return detect


# the benchmark's methods (methods.METHODS["vgn"]; "vgn_2f85" through vgn_2f85.py)


def make_detector(path, protocol, hand: str = "panda", to_hand=None) -> Detector:
    """VGN with the weights at `path` as the benchmark's Detector, under the protocol's
    max_grasps and, when on, its clear_hand (the open hand swept from the pre-grasp, as
    hand_clearing.py does for the 2F-85). The protocol's validness_threshold and
    min_score_n are the project's detection's: VGN keeps its own 0.90 quality threshold.
    Its quality is a success probability: target "binary". Another hand executing VGN's
    grasps (vgn_2f85): `hand` names it and `to_hand` moves each VGNGrasp into its TCP
    frame, before the clearance check with that hand's geometry."""
    net = load_vgn(path)
    vgn_grasps = make_vgn_detector(net, VGNOptions(max_grasps=None if protocol.clear_hand else protocol.max_grasps))

    def detect_all(tsdf):
        grasps = vgn_grasps(tsdf)
        return [to_hand(g) for g in grasps] if to_hand else grasps
    if not protocol.clear_hand:
        return Detector(detect_all, vgn_volume(), "binary")
    geometry = HAND_GEOMETRY[hand]

    def detect(tsdf):
        grasps = detect_all(tsdf)
        if not grasps:
            return grasps
        grid, voxel_size_m, origin = tsdf
        points = hand_clearance.occupied_points(np.asarray(grid), voxel_size_m, vgn_input(tsdf)[1][:3, 3])
        hit = hand_clearance.hands_collide(np.array([g.pose for g in grasps]), points, voxel_size_m,
                                           ExecutionLimits.pregrasp_distance_m, geometry)
        return [g for g, h in zip(grasps, hit) if not h][:protocol.max_grasps]
    return Detector(detect, vgn_volume(), "binary")
