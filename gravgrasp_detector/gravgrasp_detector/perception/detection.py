"""From a TSDF grid to ranked grasps: network, masks, non-maximum suppression, poses.

Selection of a voxel as a grasp (all in torch on the output tensors, no copies to
numpy until the final few grasps):
1. near-surface mask: within `surface_distance_voxels` (cube neighbourhood) of an
   observed voxel on or behind a surface (0 < grid <= 0.5). The network is out of
   its training domain far from anything it saw. Voxels inside objects and in
   occluded space are kept: a power grasp's TCP can lie inside the object, and the
   learned validness head (paper Sec. V) is what rejects bad ones.
   (`free_space_mask`, "off" by default: the paper has no such step) VGN's mask keeps
   only voxels within 2 six-connected dilations of observed free space (grid > 0.5:
   the band in front of a surface) that do not enter observed inside (1e-3 < grid <
   0.5): `free_space_band`, the rule benchmark.methods.vgn applies to VGN's grid,
   whose convention this grid shares (tsdf.py). "tcp" tests it at the candidate voxel.
   But VGN's TCP is the Panda's finger base and this one the pinch point between the
   pads, inside what a grasp holds, so there it keeps only grasps that pinch in front
   of a surface; "finger_base" tests it where VGN's TCP would sit on the candidate's
   approach, FINGER_BASE_Z_M (5 cm, VGN's finger depth, behind the finger tips),
   from every candidate's rotation (VGN masks before its non-maximum suppression).
2. validness = sigmoid(logit) >= validness_threshold and score_n >= min_score_n (and
   > 0 when ranked by a score, rank_by "score" or "expected_score"). Ranked by
   validness, a model with a score still applies min_score_n: the surest grasps among
   those predicted to hold a known payload (min_score_n = mass x g x a safety factor,
   `payload_min_score_n`); a binary model has no score to apply it to. With
   `prefer_score_n` the grasps scored at least that come first instead, the others after
   them (`held_payload_score_n`: what executed grasps needed to hold a payload).
3. non-maximum suppression: keep a voxel only if its ranking key (rank_by: the score,
   validness or validness x score) is the maximum of the surviving keys in its
   (2 * nms_radius_voxels + 1)^3 neighbourhood.
4. rank by that key (highest first), evaluate the rotation head only at the first few
   voxels and rebuild R (rotation.py).
5. something to hold: keep a grasp only if at least `min_surface_voxels` observed
   on-or-behind-surface voxels (0 < grid <= 0.5) lie in the closing region of the open
   hand at its pose (between the pads, palm face to finger tips); then keep
   `max_grasps`.  Validness is over-confident next to objects and in unobserved space
   (a real D435 frame gave grasps 6 cm from any observed surface); this is the cheap
   geometric veto the paper's learned validness should make unnecessary.
6. (`clear_hand`, off by default: the paper has no such step) the open hand, swept
   from the pre-grasp along the approach, clears the observed scene: the executor's own
   check (hand_clearance). A grasp that fails it is taken out of the candidates and
   steps 3-5 run again, so that NMS no longer lets it hide the neighbours the hand can
   reach (a grasp one voxel too deep in a glass suppressed 173 clear ones around it, and
   the executor refused the only grasp published).
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

from . import hand_clearance, rotation
from .tsdf import InputError

# Where an object must be for the closing fingers to meet it (TCP frame, metres).
CLOSING_REGION_TCP = np.array([[-PAD_WIDTH_M / 2, -MAX_STROKE_M / 2, PALM_FACE_Z_M],
                               [PAD_WIDTH_M / 2, MAX_STROKE_M / 2, FINGER_TIP_Z_M]])

PRECISIONS = ("auto", "bf16", "fp32")
RANKINGS = ("score", "validness", "expected_score")
FREE_SPACE_MASKS = ("off", "tcp", "finger_base")
# VGN's finger depth (its TCP -> the finger tips): its TCP is the Panda's finger base
VGN_FINGER_DEPTH_M = 0.05
FINGER_BASE_Z_M = FINGER_TIP_Z_M - VGN_FINGER_DEPTH_M  # where VGN's TCP would sit, in this TCP frame
FREE_SPACE_DILATIONS = 2  # VGN's detection.py
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


# The predicted score [N] at which the benchmark's executed grasps of Ours v4 held a payload
# 4 times in 5 once in the closed hand: an offset plus newtons of score per newton of weight
# (studies/executed_score_calibration.py on the v4 tuning rounds:
# sim_bridge/results/executed_score_calibration.json, 989 placed attempts; 59.6 N at 1.5 kg,
# 95 % interval 54.7-64.2 N, where 1.5 x m g is 22 N).
EXECUTED_HOLD_OFFSET_N = 35.5
EXECUTED_HOLD_N_PER_WEIGHT_N = 1.64


def held_payload_score_n(mass_kg):
    """The predicted score [N] that executed grasps needed to hold `mass_kg` 4 times in 5."""
    if not (math.isfinite(mass_kg) and mass_kg >= 0):
        raise ValueError(f"payload {mass_kg} kg: give a mass >= 0 kg")
    return EXECUTED_HOLD_OFFSET_N + EXECUTED_HOLD_N_PER_WEIGHT_N * mass_kg * G_MPS2


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
    # "score" (the gravity-rejection score [N]: the paper's rule), "validness" (a model
    # trained with --target binary: its validness is its success probability), or
    # "expected_score" (validness x score: a voxel that barely passes the threshold with a
    # high score, which the score head was never trained at, no longer outranks a sure
    # one); `model_file.ranking(metadata)` says which a model needs
    rank_by: str = "score"
    # False for a model without a gravity-rejection score (trained with --target binary:
    # its score head is untrained): its grasps carry score_n NaN, and only rank_by
    # "validness" applies. `model_file.has_score(metadata)` says which.
    has_score: bool = True
    clear_hand: bool = False  # step 6
    # VGN's mask (step 1): "off" (the paper's selection), "tcp" (at the candidate voxel)
    # or "finger_base" (where VGN's TCP would sit on the candidate's approach)
    free_space_mask: str = "off"
    pregrasp_distance_m: float = 0.05  # where step 6's approach starts (the executor's)
    # [N]; ranked by validness, the grasps scored at least this come first and the rest
    # after them, also by validness (a known payload's need, `held_payload_score_n`: unlike
    # min_score_n it never leaves a view without a grasp); 0: no preference
    prefer_score_n: float = 0.0

    def __post_init__(self):
        if self.precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {PRECISIONS}, got {self.precision!r}")
        if self.rank_by not in RANKINGS:
            raise ValueError(f"rank_by {self.rank_by!r}: use one of {RANKINGS}")
        if self.free_space_mask not in FREE_SPACE_MASKS:
            raise ValueError(f"free_space_mask {self.free_space_mask!r}: use one of {FREE_SPACE_MASKS}")
        if not (math.isfinite(self.prefer_score_n) and self.prefer_score_n >= 0):
            raise ValueError(f"prefer_score_n {self.prefer_score_n}: give a score >= 0 N (0: no preference)")
        if self.prefer_score_n > 0 and not (self.has_score and self.rank_by == "validness"):
            raise ValueError("prefer_score_n orders a score model's grasps ranked by validness: use rank_by "
                             "'validness' with a model that has a gravity-rejection score")
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
    # what the grasps were ranked by, higher first (rank_by: score_n, validness or
    # validness x score_n; 1 + validness for a grasp prefer_score_n prefers); None (a
    # grasp made by hand): score_n
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
def detect_grasps(model, tsdf_grid, voxel_size_m, origin=(0.0, 0.0, 0.0), options=DetectionOptions(),
                  score_model=None):
    """Ranked grasps (list of Grasp, best first) in the TSDF's frame.

    With options.rank_by "score" they are ranked by the gravity-rejection score [N], at
    least options.min_score_n; with "validness" by validness (among grasps of at least
    min_score_n when the model has a score); with "expected_score" by validness x score. Each Grasp's score_n is the
    score in N (NaN when options.has_score is False: a binary model's score head is
    untrained) and its rank_key what it was ranked by.

    model: networks.GraspNet (eval mode). tsdf_grid: (R, R, R) float32 in tsdf.py's
    value convention. origin: the grid corner in the task frame (3-vector or 4x4).
    score_model: another GraspNet whose score [N] stands for `model`'s (its validness and
    rotations still place the grasps): a binary model places, a score model ranks among
    the grasps it is sure of (options.has_score then says whether score_model has one).
    Raises InputError for an unusable grid.
    """
    grid = torch.as_tensor(np.asarray(tsdf_grid, dtype=np.float32))
    half, score_n, validness_logit = _network_outputs(model, grid, options.precision)
    if score_model is not None:
        _, score_n, _ = _network_outputs(score_model, grid, options.precision)
    validness = torch.sigmoid(validness_logit[0])
    score_n = score_n[0] if options.has_score else None
    rank_key = score_n * validness if options.rank_by == "expected_score" else None
    if options.prefer_score_n > 0:  # validness in [0, 1]: the preferred ones first
        rank_key = validness + (score_n >= options.prefer_score_n).float()
    return select_grasps(
        grid,
        score_n,
        validness,
        lambda index: model.rotation_at(half, index, half=True),
        model.rotation_representation,
        voxel_size_m,
        origin,
        options,
        rank_key,
    )


def _network_outputs(model, grid, precision):
    """(half-resolution features, score_n, validness logit) of `model` on the (R, R, R) grid."""
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
    return half, score_n, validness_logit


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


def band_keeps(band, points_grid, voxel_size_m):
    """(N,) bool: whether the voxels holding points (N, 3) of the grid's frame are in
    `band` (free_space_band); a point outside the volume is not."""
    ijk = np.floor(np.asarray(points_grid, float).reshape(-1, 3) / voxel_size_m).astype(int)
    inside = np.all((ijk >= 0) & (ijk < np.array(band.shape)), axis=1)
    keeps = np.zeros(len(ijk), bool)
    keeps[inside] = band.numpy()[tuple(ijk[inside].T)]
    return keeps


def free_space_mask(grid, candidate, poses_at, voxel_size_m, where):
    """(R, R, R) bool: the candidate voxels VGN's mask (free_space_band) keeps, tested at
    the voxel (where "tcp") or at the point FINGER_BASE_Z_M along each candidate's
    approach ("finger_base": every candidate's rotation, as VGN masks before its
    non-maximum suppression; about 10x the detection's time without a mask,
    `bench_detect --free-space-mask finger_base`).
    poses_at: (N, 3) voxel indices -> (N, 4, 4) poses in the grid's frame."""
    band = free_space_band(grid)
    if where == "tcp":
        return band
    index = candidate.nonzero()
    keeps = torch.zeros_like(candidate)
    if len(index):
        poses = poses_at(index)
        at_base = band_keeps(band, poses[:, :3, 3] + FINGER_BASE_Z_M * poses[:, :3, 2], voxel_size_m)
        keeps[tuple(index[torch.as_tensor(at_base)].T)] = True
    return keeps


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
):
    """Steps 1-5 of the module doc on network outputs, ranked (and suppressed) by
    ``rank_key``, by default ``score_n``, or validness with options.rank_by "validness"
    (options' precision is the caller's: it chose the outputs).

    grid, score_n, validness, rank_key: (R, R, R) tensors; score_n None for a model
    without a score (its grasps carry score_n NaN; rank_by must be "validness"): a NaN
    score is refused rather than let it drop (or keep) every voxel. rotation_channels_at:
    callable (N, 3) long voxel indices -> (N, C) rotation channels.
    """
    grid = torch.as_tensor(grid)
    validness = torch.as_tensor(validness).float()
    by_score = options.rank_by != "validness"
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

    if options.free_space_mask != "off":
        candidate &= free_space_mask(grid, candidate, poses_at, voxel_size_m, options.free_space_mask)

    def ranked(candidate):  # steps 3-5
        return _ranked_poses(grid, candidate, key, poses_at, voxel_size_m, options)
    grasps = ranked(candidate)
    if options.clear_hand:
        grasps = _clear_hand(grid, candidate, grasps, ranked, poses_at, voxel_size_m, options)
    index, poses = grasps
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


CLEAR_HAND_ROUNDS = 8  # step 6's reruns of steps 3-5; what still collides after them is dropped


def _clear_hand(grid, candidate, grasps, ranked, poses_at, voxel_size_m, options):
    """Step 6: take grasps whose open hand meets the observed scene out of `candidate` and
    rank again (`ranked`: candidate mask -> steps 3-5), until the grasps kept clear it.
    A grasp that collides is checked with the candidates of its NMS neighbourhood (those it
    suppressed) at once: its neighbours one voxel deeper mostly collide too."""
    points = hand_clearance.occupied_points(np.asarray(grid), voxel_size_m)  # the grid's frame, as the poses
    candidate = candidate.clone()
    clear = torch.zeros_like(candidate)
    checked = torch.zeros_like(candidate)

    def check(index, poses):
        hit = hand_clearance.hands_collide(poses, points, voxel_size_m, options.pregrasp_distance_m)
        clear[tuple(index.T)] = torch.as_tensor(~hit)
        checked[tuple(index.T)] = True

    r = max(int(options.nms_radius_voxels), 0)
    for _ in range(CLEAR_HAND_ROUNDS):
        index, poses = grasps
        new = ~checked[tuple(index.T)]
        check(index[new], poses[new.numpy()])
        blocked = index[~clear[tuple(index.T)]]
        if len(blocked) == 0:
            return grasps
        near = torch.zeros_like(candidate)
        for i, j, k in blocked.tolist():
            near[max(i - r, 0):i + r + 1, max(j - r, 0):j + r + 1, max(k - r, 0):k + r + 1] = True
        near_index = (near & candidate & ~checked).nonzero()
        if len(near_index):
            check(near_index, poses_at(near_index))
        candidate &= ~checked | clear
        grasps = ranked(candidate)
    index, poses = grasps
    keep = (checked & clear)[tuple(index.T)]
    return index[keep], poses[keep.numpy()]
