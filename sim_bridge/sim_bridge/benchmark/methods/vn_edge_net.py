"""VN-EdgeGraspNet's network (Huang et al., "Edge Grasp Network: A Graph-Based
SE(3)-invariant Approach to Grasp Detection", ICRA 2023, the vector-neuron variant),
written from the paper and from its published checkpoints' tensor names and shapes, in
plain torch (no torch-geometric). The layer order and the feature concatenations follow
the authors' code (github.com/HaojHuang/Edge-Grasp-Network, models/vn_*.py), which was
read, not copied.

Every feature is C 3-vectors per point (vector neurons, Deng et al. 2021). A VN linear
layer mixes channels only, so rotating the input rotates the output; a VN ReLU
clips each vector's component along a learned direction; a VN max-pool keeps, per
channel, the vector with the largest component along a learned direction. All
nonlinearities here have slope 0 (the checkpoints were trained so).

The four checkpoints are four state dicts, loaded strictly (`load_vn_edge`):
- local_emd_model: a 3-layer PointNet++-style conv over each ball (the points within
  5 cm of an apex, relative to it; input channels: position and normal), each message
  (neighbour features, relative position) -> VN linear, VN ReLU, VN linear, VN max over
  the 16 nearest neighbours (self included), then a VN ReLU: 32, 64, 128 channels.
- global_emd_model: per ball, the concatenated local features (224) -> VN linear-ReLU
  twice, VN linear, max-pool over the ball, VN ReLU (128); concatenated back onto each
  point (352) -> VN linear-ReLU, VN linear, max-pool, VN ReLU: one 381-vector feature per
  ball.
- std: an edge's 512 vectors (approach, contact position, contact normal, contact's 128
  local features, its ball's 381 global ones) -> VN linear-ReLU 256, 128, linear 3: a
  per-edge frame; the 512 vectors' components in that frame are rotation invariant.
- classifier_model: those 1536 numbers -> MLP 256, 128, 64 -> one logit (success).
"""

from __future__ import annotations

import pathlib
import re

import torch
from torch import nn

from ...physics.baseline_files import SOURCES, BaselineFileMissing, baselines_dir
from .vgn import read_state_dict, state_dict_mismatches

CHECKPOINT_DIR = "vn_edge_grasp"  # in the baselines directory
EPOCH = 105  # the published checkpoints
PARTS = ("local_emd_model", "global_emd_model", "classifier_model", "std")
EPS = 1e-7  # the authors' guard in the VN ReLU's division
KNN_K = 16  # local graph: 16 nearest neighbours per ball point, itself included
LOCAL_CHANNELS = (32, 64, 128)
GLOBAL_INNER, GLOBAL_CHANNELS = 128, 381
EDGE_CHANNELS = 1 + 1 + 1 + LOCAL_CHANNELS[-1] + GLOBAL_CHANNELS  # 512


class VNEdgeModelError(ValueError):
    """Checkpoint files that are not VN-EdgeGraspNet's published model."""


# vector-neuron layers. Features are (..., 3, C): channels last, so a layer's nn.Linear
# mixes channels as it is (the authors' (N, C, 3) transposed; the same numbers)


def vn_relu(x, direction):
    """Each vector of x, less its component against `direction` where that is negative
    (slope 0): x where x.d >= 0, else x projected onto the plane orthogonal to d."""
    dot = (x * direction).sum(-2, keepdim=True)
    d_norm_sq = (direction * direction).sum(-2, keepdim=True)
    return x - dot.clamp(max=0.0) / (d_norm_sq + EPS) * direction


class VNLinear(nn.Module):
    def __init__(self, in_channels, out_channels):
        super().__init__()
        self.map_to_feat = nn.Linear(in_channels, out_channels, bias=False)

    def forward(self, x):
        return self.map_to_feat(x)


class VNReLU(nn.Module):
    """VN ReLU with a learned direction per channel (channels in = out)."""

    def __init__(self, channels):
        super().__init__()
        self.map_to_dir = nn.Linear(channels, channels, bias=False)

    def forward(self, x):
        return vn_relu(x, self.map_to_dir(x))


class VNLinearReLU(nn.Module):
    """VN linear, then a VN ReLU whose direction is learned from the layer's input."""

    def __init__(self, in_channels, out_channels):
        super().__init__()
        self.map_to_feat = nn.Linear(in_channels, out_channels, bias=False)
        self.map_to_dir = nn.Linear(in_channels, out_channels, bias=False)

    def forward(self, x):
        return vn_relu(self.map_to_feat(x), self.map_to_dir(x))


def vn_max(x, direction, dim: int):
    """Per channel, the vector of x along `dim` whose component along `direction` is
    largest (the first on a tie); x and direction (..., n, ..., 3, C), `dim` < -2."""
    best = (x * direction).sum(-2, keepdim=True).argmax(dim, keepdim=True)
    return x.gather(dim, best.expand(*best.shape[:-2], 3, best.shape[-1])).squeeze(dim)


def vn_max_pool(x, direction, group, n_groups: int):
    """vn_max over the rows of x (N, 3, C) of each group (N,) -> (n_groups, 3, C). Every
    group must have a member."""
    score = (x * direction).sum(1)  # (N, C)
    index = group[:, None].expand_as(score)
    best = torch.full((n_groups, score.shape[1]), -torch.inf, dtype=score.dtype)
    best = best.scatter_reduce(0, index, score, "amax")
    rows = torch.arange(len(x))[:, None].expand_as(score)
    first = torch.where(score == best[group], rows, len(x))
    chosen = torch.full_like(best, len(x), dtype=torch.long).scatter_reduce(0, index, first, "amin")
    return x.gather(0, chosen[:, None, :].expand(-1, 3, -1))


# the four parts (attribute names are the checkpoints')


class PointConvVN(nn.Module):
    """One local layer: messages (neighbour features, neighbour - centre) -> VN linear,
    VN ReLU, VN linear -> VN max over each point's neighbours."""

    def __init__(self, in_channels, out_channels):
        super().__init__()
        self.vn_linear_1 = VNLinear(in_channels, out_channels)
        self.relu_1 = VNReLU(out_channels)
        self.vn_linear_2 = VNLinear(out_channels, out_channels)
        self.map_to_dir = VNLinear(out_channels, out_channels)

    def forward(self, features, positions, neighbours):
        """features (N, 3, C), positions (N, 3), neighbours (N, k) -> (N, 3, C')."""
        # The first layer is linear in the message (neighbour features, relative
        # position): apply it to each point once and gather, rather than to each of the
        # N k messages. (Regrouping more of it flips near-ties of the max below more
        # often than the authors' order of operations does: vn-edge-baseline.md.)
        w = self.vn_linear_1.map_to_feat.weight  # (C', C + 1): the last column reads the position
        relative = positions[neighbours][..., None] - positions[:, None, :, None]  # (N, k, 3, 1)
        message = (features @ w[:, :-1].T)[neighbours] + relative * w[:, -1]
        message = self.vn_linear_2(self.relu_1(message))
        return vn_max(message, self.map_to_dir(message), dim=1)


class LocalEmbedding(nn.Module):
    """Ball points (relative positions and normals, each (N, 3)) and each one's k
    nearest of its ball (N, k) -> features after each of the three layers: (N, 3, 32),
    (N, 3, 64), (N, 3, 128)."""

    def __init__(self):
        super().__init__()
        c1, c2, c3 = LOCAL_CHANNELS
        self.conv1, self.relu1 = PointConvVN(2 + 1, c1), VNReLU(c1)
        self.conv2, self.relu2 = PointConvVN(c1 + 1, c2), VNReLU(c2)
        self.conv3, self.relu3 = PointConvVN(c2 + 1, c3), VNReLU(c3)

    def forward(self, positions, normals, neighbours):
        h = torch.stack((positions, normals), dim=-1)
        out = []
        for conv, relu in ((self.conv1, self.relu1), (self.conv2, self.relu2), (self.conv3, self.relu3)):
            h = relu(conv(h, positions, neighbours))
            out.append(h)
        return out


class GlobalEmbedding(nn.Module):
    """Ball points' concatenated local features (N, 3, 224) and their ball index ->
    one (3, 381) feature per ball, twice max-pooled over the ball."""

    def __init__(self):
        super().__init__()
        c_in, c = sum(LOCAL_CHANNELS), GLOBAL_INNER
        self.vn1, self.vn2, self.vn3 = VNLinearReLU(c_in, c), VNLinearReLU(c, c), VNLinear(c, c)
        self.map_to_dir_1, self.relu3 = VNLinear(c, c), VNReLU(c)
        self.vn4, self.vn5 = VNLinearReLU(c_in + c, GLOBAL_CHANNELS), VNLinear(GLOBAL_CHANNELS, GLOBAL_CHANNELS)
        self.map_to_dir_2, self.relu5 = VNLinear(GLOBAL_CHANNELS, GLOBAL_CHANNELS), VNReLU(GLOBAL_CHANNELS)

    def forward(self, features, ball, n_balls: int):
        g = self.vn3(self.vn2(self.vn1(features)))
        g = self.relu3(vn_max_pool(g, self.map_to_dir_1(g), ball, n_balls))
        g = self.vn5(self.vn4(torch.cat((features, g[ball]), dim=-1)))
        return self.relu5(vn_max_pool(g, self.map_to_dir_2(g), ball, n_balls))


class EdgeFrame(nn.Module):
    """(E, 3, 512) edge features -> their components in a learned per-edge frame,
    (E, 512 * 3) channel by channel, invariant to rotations of the input (the
    checkpoints' `std`)."""

    def __init__(self):
        super().__init__()
        self.vn1 = VNLinearReLU(EDGE_CHANNELS, EDGE_CHANNELS // 2)
        self.vn2 = VNLinearReLU(EDGE_CHANNELS // 2, EDGE_CHANNELS // 4)
        self.vn_lin = nn.Linear(EDGE_CHANNELS // 4, 3, bias=False)

    def forward(self, x):
        frame = self.vn_lin(self.vn2(self.vn1(x)))  # (E, 3, 3): three vectors
        return torch.einsum("eic,eif->ecf", x, frame).flatten(1)


class Classifier(nn.Module):
    def __init__(self):
        super().__init__()
        c = EDGE_CHANNELS * 3
        self.head = nn.Sequential(nn.Linear(c, 256), nn.ReLU(), nn.Linear(256, 128), nn.ReLU(),
                                  nn.Linear(128, 64), nn.ReLU(), nn.Linear(64, 1))

    def forward(self, x):
        return self.head(x)[:, 0]


class VNEdgeNet(nn.Module):
    """The four parts under the checkpoints' names; `forward` scores edges."""

    def __init__(self):
        super().__init__()
        self.local_emd_model, self.global_emd_model = LocalEmbedding(), GlobalEmbedding()
        self.std, self.classifier_model = EdgeFrame(), Classifier()

    def forward(self, ball_positions, ball_normals, ball, n_balls, neighbours, edge_point, approaches):
        """Ball points (position relative to their apex (N, 3), normal (N, 3), ball index
        (N,), sorted), each one's k nearest points of its ball (N, k), the edges to
        score (ball-point rows (E,)) and their approach vectors, pointing away from the
        object (E, 3) -> logits (E,)."""
        h1, h2, h3 = self.local_emd_model(ball_positions, ball_normals, neighbours)
        global_features = self.global_emd_model(torch.cat((h1, h2, h3), dim=-1), ball, n_balls)
        edge = torch.cat((approaches[..., None], ball_positions[edge_point, :, None],
                          ball_normals[edge_point, :, None], h3[edge_point], global_features[ball[edge_point]]), dim=-1)
        return self.classifier_model(self.std(edge))


# strict loading


def checkpoint_paths(path=None, baselines=None) -> dict:
    """{part: path} of the four checkpoints. `path`: a directory holding
    <part>-ckpt-105.pt, or any one of the four files (the others next to it, same epoch);
    None: CHECKPOINT_DIR in the baselines directory."""
    path = pathlib.Path(path) if path is not None else baselines_dir(baselines) / CHECKPOINT_DIR
    epoch = EPOCH
    if path.suffix == ".pt":
        match = re.fullmatch(rf"({'|'.join(PARTS)})-ckpt-(\d+)\.pt", path.name)
        if not match:
            raise VNEdgeModelError(f"{path} is not named <part>-ckpt-<epoch>.pt with part one of {', '.join(PARTS)}: "
                                   f"give VN-EdgeGraspNet's checkpoint directory or one of its four files")
        path, epoch = path.parent, int(match.group(2))
    return {part: path / f"{part}-ckpt-{epoch}.pt" for part in PARTS}


def checkpoint_mismatches(state, expected) -> list:
    """Every way `state` differs from `expected` (name -> tensor), one entry each."""
    return state_dict_mismatches(state, expected, "VN-EdgeGraspNet's")


def _read_state(path: pathlib.Path):
    return read_state_dict(path, VNEdgeModelError, f"VN-EdgeGraspNet's are in {SOURCES['vn_edge_grasp']}")


def load_vn_edge(path=None, baselines=None) -> VNEdgeNet:
    """VN-EdgeGraspNet with the published weights (see checkpoint_paths for `path`), in
    eval mode. Strict: one BaselineFileMissing naming every missing file and where to get
    them; one VNEdgeModelError naming every missing, unexpected or mis-shaped tensor of
    every file."""
    paths = checkpoint_paths(path, baselines)
    missing = [str(p) for p in paths.values() if not p.is_file()]
    if missing:
        raise BaselineFileMissing(f"VN-EdgeGraspNet checkpoint{'s' if len(missing) > 1 else ''} {', '.join(missing)} "
                                  f"not found: get them from {SOURCES['vn_edge_grasp']}, or leave the path out to "
                                  f"read {CHECKPOINT_DIR}/ from the baselines directory (--baselines DIR)")
    net = VNEdgeNet()
    states, problems = {}, []
    for part, p in paths.items():
        states[part] = _read_state(p)
        problems += [f"{p.name}: {m}" for m in checkpoint_mismatches(states[part], getattr(net, part).state_dict())]
    if problems:
        raise VNEdgeModelError(f"not VN-EdgeGraspNet's checkpoints ({len(problems)} problems): " + "; ".join(problems))
    for part, state in states.items():
        getattr(net, part).load_state_dict(state, strict=True)
    return net.eval()
