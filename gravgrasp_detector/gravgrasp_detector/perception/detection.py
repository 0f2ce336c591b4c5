"""From a TSDF grid to ranked grasps: network, masks, non-maximum suppression, poses.

Selection of a voxel as a grasp (all in torch on the output tensors, no copies to
numpy until the final few grasps):
1. near-surface mask: within `surface_distance_voxels` (cube neighbourhood) of an
   observed voxel on or behind a surface (0 < grid <= 0.5). The network is out of
   its training domain far from anything it saw. Voxels inside objects and in
   occluded space are kept: a power grasp's TCP can lie inside the object, and the
   learned validness head (paper Sec. V) is what rejects bad ones.
2. validness = sigmoid(logit) >= validness_threshold and score_n >= min_score_n (and
   > 0 when ranked by the score, rank_by "score": the paper's rule). A binary model
   (rank_by "validness") has no score: its validness is its success probability.
   min_score_n = a known payload's mass x g x a safety factor (`payload_min_score_n`).
3. non-maximum suppression: keep a voxel only if its ranking key (the score, or validness
   for a binary model) is the maximum of the surviving keys in its
   (2 * nms_radius_voxels + 1)^3 neighbourhood.
4. rank by that key (highest first), evaluate the rotation head only at the first few
   voxels and rebuild R (rotation.py).
5. something to hold: keep a grasp only if at least `min_surface_voxels` observed
   on-or-behind-surface voxels (0 < grid <= 0.5) lie in the closing region of the open
   hand at its pose (between the pads, palm face to finger tips); then keep
   `max_grasps`.  Validness is over-confident next to objects and in unobserved space
   (a real D435 frame gave grasps 6 cm from any observed surface); this is the cheap
   geometric veto the paper's learned validness should make unnecessary.
Other selections (the benchmark's and the studies': another ranking, a mask on the
candidates, a rerun of steps 3-5) are built from the same steps: `network_outputs`, then
`select_grasps` with a `rank_key` and a `from_candidates` of their own.
With precision bf16 only the backbone runs in bf16 (autocast); the score/validness
head runs in float32 on its output, so bf16 rounding of the outputs (8 mantissa
bits: 0.125 N at 30 N) does not decide near-ties.
The TCP position is the voxel centre: origin + (index + 0.5) * voxel_size_m.
"""

import math
from dataclasses import dataclass

import numpy as np
import torch

from robotiq_driver.hand_geometry import FINGER_TIP_Z_M, MAX_STROKE_M, PAD_WIDTH_M, PALM_FACE_Z_M

from . import rotation
from .tsdf import InputError

# Where an object must be for the closing fingers to meet it (TCP frame, metres).
CLOSING_REGION_TCP = np.array([[-PAD_WIDTH_M / 2, -MAX_STROKE_M / 2, PALM_FACE_Z_M],
                               [PAD_WIDTH_M / 2, MAX_STROKE_M / 2, FINGER_TIP_Z_M]])

PRECISIONS = ("auto", "bf16", "fp32")
RANKINGS = ("score", "validness")
G_MPS2 = 9.81
# A known payload asks for grasps predicted to hold this many times its weight: the
# score's error is ~13 N (doc/score-calibration.md) and executed grasps hold less than
# their labels; the stack's `score_safety_factor` default.
PAYLOAD_SAFETY_FACTOR = 1.5


def payload_min_score_n(mass_kg, safety_factor=PAYLOAD_SAFETY_FACTOR):
    """The least gravity-rejection score [N] of a grasp trusted with `mass_kg`."""
    if not (math.isfinite(mass_kg) and mass_kg >= 0 and math.isfinite(safety_factor) and safety_factor >= 1):
        raise ValueError(f"payload {mass_kg} kg, safety factor {safety_factor}: give a mass >= 0 kg and a "
                         "factor >= 1 (a grasp must hold at least the weight)")
    return mass_kg * G_MPS2 * safety_factor


@dataclass(frozen=True)
class DetectionOptions:
    """How grasps are selected from the network's outputs (steps 1-5 of the module doc)
    and how the network runs. The detect node's parameters of the same names."""

    validness_threshold: float = 0.5
    min_score_n: float = 0.0  # [N]; not applied for a model without a score (has_score False)
    max_grasps: int = 20
    surface_distance_voxels: int = 6
    nms_radius_voxels: int = 2  # 0: no non-maximum suppression
    min_surface_voxels: int = 1  # 0: no step 5
    # "bf16" (autocast + channels_last_3d), "fp32", or "auto" (bf16 where the CPU has
    # AMX, see bf16_faster)
    precision: str = "fp32"
    # "score" (the gravity-rejection score [N]: the paper's rule) or "validness" (a model
    # trained with --target binary: its validness is its success probability);
    # `model_file.ranking(metadata)` says which a model needs
    rank_by: str = "score"
    # False for a model without a gravity-rejection score (trained with --target binary:
    # its score head is untrained): its grasps carry score_n NaN, and only rank_by
    # "validness" applies. `model_file.has_score(metadata)` says which.
    has_score: bool = True

    def __post_init__(self):
        if self.precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {PRECISIONS}, got {self.precision!r}")
        if self.rank_by not in RANKINGS:
            raise ValueError(f"rank_by {self.rank_by!r}: use one of {RANKINGS}")
        if not self.has_score and self.rank_by != "validness":
            raise ValueError(f"rank_by {self.rank_by!r} needs a gravity-rejection score, and has_score is False "
                             "(a model trained with --target binary): rank by 'validness'")


@dataclass
class Grasp:
    pose: np.ndarray  # 4x4 T_task_tcp (float64)
    # gravity-rejection score [N], always newtons; NaN for a model that has none (trained
    # with --target binary, VGN): its validness is what it knows
    score_n: float
    validness: float  # [0, 1]
    voxel_index: tuple  # (i, j, k)
    # what the grasps were ranked by, higher first (score_n or validness, or a caller's
    # rank_key); None (a grasp made by hand): score_n
    rank_key: float | None = None

    def __post_init__(self):
        if self.rank_key is None:
            self.rank_key = self.score_n


def bf16_available():
    """True if this CPU runs bf16 convolutions natively (AVX-512 BF16 / AMX)."""
    return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())


def bf16_faster():
    """True if bf16 is worth it here: native bf16 *with AMX tiles*. With AVX-512 BF16
    alone detection was slower in bf16 than in fp32 (a 2-core Xeon, shipped v3 model:
    10.4 vs 8.1 ms); with AMX it was 2x faster (5.7 vs 11.3 ms)."""
    amx = getattr(torch.cpu, "_is_amx_tile_supported", None)  # private; absent in old torch
    return bf16_available() and bool(amx is not None and amx())


def resolve_precision(precision):
    """'auto' -> 'bf16' where bf16_faster(), else 'fp32'; the others as they are."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}")
    if precision == "auto":
        return "bf16" if bf16_faster() else "fp32"
    return precision


def _prepare(model, precision):
    # bf16 (autocast): channels_last_3d routes every conv to oneDNN and avoids layout
    # reorders. fp32 convs go to oneDNN in either layout (networks._conv3d), and the
    # contiguous one was ~8 % faster on an AVX2 EPYC (19.8-21.1 vs 22.1-23.6 ms CPU).
    layout = torch.channels_last_3d if precision == "bf16" else torch.contiguous_format
    if getattr(model, "_gravgrasp_layout", None) != layout:
        model.to(memory_format=layout)
        model._gravgrasp_layout = layout
    return layout


def _to_transform(origin):
    origin = np.asarray(origin, dtype=np.float64)
    if origin.shape == (4, 4):
        return origin
    if origin.shape == (3,):
        T = np.eye(4)
        T[:3, 3] = origin
        return T
    raise ValueError(f"origin must be a 3-vector or a 4x4 transform, got shape {origin.shape}")


def check_grid(tsdf_grid, resolution):
    """Raise InputError unless `tsdf_grid` is a finite (R, R, R) grid with something observed."""
    shape = tuple(tsdf_grid.shape)
    if shape != (resolution,) * 3:
        raise InputError(
            "grid_shape",
            f"TSDF grid has shape {shape}, the model expects {(resolution,) * 3}: set the "
            "tsdf node's resolution to the model's",
        )
    if not bool(torch.isfinite(tsdf_grid).all()):
        raise InputError("grid_values", "TSDF grid contains NaN or inf: the volume is corrupt")
    if not bool((tsdf_grid != 0).any()):
        raise InputError(
            "empty_tsdf",
            "TSDF volume has no observed surface (all voxels 0): integrate depth frames "
            "that see the workspace (is the tsdf node getting depth and a camera pose?)",
        )


@torch.inference_mode()
def detect_grasps(model, tsdf_grid, voxel_size_m, origin=(0.0, 0.0, 0.0), options=DetectionOptions()):
    """Ranked grasps (list of Grasp, best first) in the TSDF's frame.

    With options.rank_by "score" they are ranked by the gravity-rejection score [N], at
    least options.min_score_n; with "validness" (a binary model) by validness. Each
    Grasp's score_n is the score in N (NaN when options.has_score is False: a binary
    model's score head is untrained) and its rank_key what it was ranked by.

    model: networks.GraspNet (eval mode). tsdf_grid: (R, R, R) float32 in tsdf.py's
    value convention. origin: the grid corner in the task frame (3-vector or 4x4).
    Raises InputError for an unusable grid.
    """
    grid = torch.as_tensor(np.asarray(tsdf_grid, dtype=np.float32))
    half, score_n, validness = network_outputs(model, grid, options.precision)
    return select_grasps(grid, score_n if options.has_score else None, validness,
                         rotations_at(model, half), model.rotation_representation, voxel_size_m, origin, options)


def rotations_at(model, half):
    """(N, 3) voxel indices -> (N, C) rotation channels of `model` (select_grasps'
    rotation_channels_at), from network_outputs' `half`."""
    return lambda index: model.rotation_at(half, index, half=True)


@torch.inference_mode()
def network_outputs(model, grid, precision):
    """(half-resolution features, score_n [N], validness in [0, 1]), (R, R, R) each but the
    features, of `model` on the (R, R, R) grid (a tensor); InputError for an unusable grid."""
    precision = resolve_precision(precision)
    check_grid(grid, model.resolution)
    layout = _prepare(model, precision)
    x = grid[None, None].contiguous(memory_format=layout)
    with torch.autocast("cpu", dtype=torch.bfloat16, enabled=precision == "bf16"):
        # Heads from the half-resolution decoder output (exactly equal, see networks.py).
        half = model.half_features(x)
    # The head in float32 (oneDNN, ~0.7 ms): bf16 outputs would round scores to 8
    # mantissa bits (0.125 N at 30 N) and let rounding decide near-ties.
    half = half.float()
    score_n, validness_logit = model.score_and_validness_from_half(half)
    return half, score_n[0], torch.sigmoid(validness_logit[0])


def surface_voxel_centres(grid, voxel_size_m, origin=(0.0, 0.0, 0.0)):
    """(M, 3) float64: centres of the observed on-or-behind-surface voxels (0 < v <= 0.5),
    what step 5 counts in the closing region."""
    g = np.asarray(grid)
    return np.asarray(origin, float) + (np.argwhere((g > 0) & (g <= 0.5)) + 0.5) * voxel_size_m


def surface_voxels_in_closing_region(grid, poses_grid, voxel_size_m):
    """(N,) int: observed on-or-behind-surface voxels (0 < v <= 0.5) whose centres lie
    in the closing region of the open hand at each pose (4x4, grid frame)."""
    poses = np.asarray(poses_grid, dtype=np.float32).reshape(-1, 4, 4)
    centres = surface_voxel_centres(grid, voxel_size_m).astype(np.float32)
    if not len(centres) or not len(poses):
        return np.zeros(len(poses), int)
    lo, hi = CLOSING_REGION_TCP.astype(np.float32)
    # all poses at once, in the TCP frames: q[j, n, m] = (R_n^T (c_m - t_n))_j, as one
    # (3N, 3) x (3, M) product, then the box test axis by axis on contiguous rows (a
    # stacked matmul of 3x3s and an .all() over the short last axis took ~10x longer)
    R = poses[:, :3, :3]
    n = len(poses)
    q = (R.transpose(2, 0, 1).reshape(3 * n, 3) @ centres.T).reshape(3, n, -1)
    q -= np.einsum("ni,nij->jn", poses[:, :3, 3], R)[:, :, None]
    inside = (q[0] >= lo[0]) & (q[0] <= hi[0])
    for j in (1, 2):
        inside &= (q[j] >= lo[j]) & (q[j] <= hi[j])
    return inside.sum(axis=1)


def cube_max(volume, radius):
    """Max over the (2 radius + 1)^3 cube around each voxel of an (R, R, R) tensor
    (bool: any), ignoring voxels outside the volume.

    Separable, by shifted element-wise maxima along each axis with doubling reach
    (1, 2, 4 ...): about 3 log2(r) passes; ~30x faster than max_pool3d here.
    """
    r = int(radius)
    x = volume
    for dim in range(3):
        n, reach = x.shape[dim], 0
        while reach < min(r, n - 1):
            shift = min(reach + 1, r - reach, n - 1)
            out = x.clone()
            head, tail = out.narrow(dim, 0, n - shift), out.narrow(dim, shift, n - shift)
            torch.maximum(head, x.narrow(dim, shift, n - shift), out=head)
            torch.maximum(tail, x.narrow(dim, 0, n - shift), out=tail)
            x, reach = out, reach + shift
    return x


def near_surface_mask(grid, surface_distance_voxels):
    """(R, R, R) bool: within the cube neighbourhood of an observed on/behind-surface voxel."""
    return cube_max((grid > 0) & (grid <= 0.5), surface_distance_voxels)


def select_grasps(
    grid,
    score_n,
    validness,
    rotation_channels_at,
    rotation_representation,
    voxel_size_m,
    origin=(0.0, 0.0, 0.0),
    options=DetectionOptions(),
    rank_key=None,
    from_candidates=None,
):
    """Steps 1-5 of the module doc on network outputs, ranked (and suppressed) by
    ``score_n``, or validness with options.rank_by "validness" (options' precision is the
    caller's: it chose the outputs).

    grid, score_n, validness: (R, R, R) tensors; score_n None for a model without a score
    (its grasps carry score_n NaN; rank_by must be "validness"): a NaN score is refused
    rather than let it drop (or keep) every voxel. rotation_channels_at: callable (N, 3)
    long voxel indices -> (N, C) rotation channels.
    A caller's own selection (the benchmark's and the studies', not the node's):
    rank_key, an (R, R, R) tensor ranking the candidates instead; from_candidates(grid,
    candidate, ranked, poses_at) -> (index (N, 3), poses (N, 4, 4)), the grasps from the
    candidate mask of steps 1-2, by default ``ranked(candidate)`` (steps 3-5), with
    poses_at: (N, 3) voxel indices -> (N, 4, 4) poses, both in the grid's frame.
    """
    grid = torch.as_tensor(grid)
    validness = torch.as_tensor(validness).float()
    by_score = options.rank_by == "score"
    if score_n is not None:
        score_n = torch.as_tensor(score_n).float()
        if bool(torch.isnan(score_n).any()):
            raise ValueError("score_n has NaN: pass score_n=None for a model without a gravity-rejection score")
    elif by_score:
        raise ValueError(f"rank_by {options.rank_by!r} needs a gravity-rejection score, and score_n is None: "
                         "rank by 'validness'")
    candidate = near_surface_mask(grid, options.surface_distance_voxels) & (validness >= options.validness_threshold)
    if by_score:
        candidate &= (score_n >= options.min_score_n) & (score_n > 0)  # a grasp holding 0 N is none
        key = score_n
    else:  # validness ranks; a score, if any, only selects
        candidate &= validness > 0
        if score_n is not None and options.min_score_n > 0:
            candidate &= score_n >= options.min_score_n
        key = validness
    if rank_key is not None:
        key = torch.as_tensor(rank_key).float()
        if bool(torch.isnan(key).any()):
            raise ValueError("rank_key has NaN: NaN keys would drop out of NMS and ranking unnoticed")

    def poses_at(index):  # (N, 3) voxel indices -> (N, 4, 4) grasps in the grid's frame
        poses = np.zeros((len(index), 4, 4))
        R = rotation.reconstruct(rotation_representation, rotation_channels_at(index).float())
        poses[:, :3, :3] = R.double().numpy()
        poses[:, :3, 3] = (index.double().numpy() + 0.5) * voxel_size_m
        poses[:, 3, 3] = 1.0
        return poses

    def ranked(candidate):  # steps 3-5
        return _ranked_poses(grid, candidate, key, poses_at, voxel_size_m, options)
    if from_candidates is None:
        index, poses = ranked(candidate)
    else:
        index, poses = from_candidates(grid, candidate, ranked, poses_at)
    if len(index) == 0:
        return []
    at = tuple(index.T)
    scores = score_n[at].tolist() if score_n is not None else [float("nan")] * len(index)
    poses = _to_transform(origin) @ poses
    return [
        Grasp(pose=pose, score_n=score, validness=v, voxel_index=tuple(ijk), rank_key=k)
        for pose, score, v, ijk, k in zip(poses, scores, validness[at].tolist(), index.tolist(), key[at].tolist())
    ]


def _ranked_poses(grid, candidate, key, poses_at, voxel_size_m, options):
    """Steps 3-5 on the candidate voxels: (index (N, 3), poses (N, 4, 4) in the grid's
    frame), best first by `key`, N <= max_grasps. `poses_at`: (N, 3) voxel indices ->
    (N, 4, 4) grasp poses."""
    max_grasps = int(options.max_grasps)
    masked = torch.where(candidate, key, torch.full_like(key, -1.0))
    r = int(options.nms_radius_voxels)
    if r > 0:
        candidate = candidate & (masked == cube_max(masked, r))
    index = candidate.nonzero()
    # rotations for a few more than max_grasps: step 5 may veto some
    ranked = 4 * max_grasps if options.min_surface_voxels > 0 else max_grasps
    order = torch.sort(key[candidate], descending=True, stable=True).indices[:ranked]
    index = index[order]
    if len(index) == 0:
        return index, np.zeros((0, 4, 4))
    poses = poses_at(index)
    keep = np.arange(len(index))
    if options.min_surface_voxels > 0:
        # best first, a chunk at a time: usually the first chunk fills max_grasps
        kept, n = [], max_grasps
        for start in range(0, len(index), n):
            counts = surface_voxels_in_closing_region(grid, poses[start:start + n], voxel_size_m)
            kept.extend(start + np.flatnonzero(counts >= options.min_surface_voxels))
            if len(kept) >= n:
                break
        keep = np.asarray(kept, int)
    keep = torch.as_tensor(keep[:max_grasps], dtype=torch.long)
    return index[keep], poses[keep.numpy()]
