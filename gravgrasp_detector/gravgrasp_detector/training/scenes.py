"""Training data: scene files written by sim_bridge's data generation, each holding the
fused TSDF grid and sparse voxel labels (see `load_scene`); the --data-subset and
--target label selection; the train/validation split, by scene, that depends only on
the file names and the seed (adding scenes does not reshuffle the validation set); and
the augmentation (quarter turns about gravity, +-2-voxel shifts, labels moved with the
volume) that builds a training example."""
from __future__ import annotations

import hashlib
import pathlib

import numpy as np
import torch

from .config import TrainConfig

G_MPS2 = 9.81
# Mode names as sim_bridge.datagen.object_grasps writes them; scene files carry their own
# `mode_names`, which win.
DEFAULT_MODE_NAMES = ("power", "precision", "none")


class DataError(RuntimeError):
    """Training data that cannot be used; the message says why and what to do."""


def load_scene(path):
    """A scene file -> dict(tsdf (R,R,R) float32, index (K,3) int64, score (K,),
    e_x (K,3), e_z (K,3), mode (K,) or None, negative_index (M,3) int64,
    negative_reason (M,) int64)."""
    try:
        with np.load(path) as z:
            scene = {
                "tsdf": z["tsdf"].astype(np.float32),
                "index": z["label_index"].astype(np.int64).reshape(-1, 3),
                "score": z["label_score"].astype(np.float32).reshape(-1),
                "e_x": z["label_e_x"].astype(np.float32).reshape(-1, 3),
                "e_z": z["label_e_z"].astype(np.float32).reshape(-1, 3),
                "mode": z["label_mode"].astype(np.int64).reshape(-1) if "label_mode" in z else None,
                "mode_names": [str(n) for n in z["mode_names"]] if "mode_names" in z else DEFAULT_MODE_NAMES,
                # explicit validness negatives (scenes from before them have none)
                "negative_index": (z["negative_index"].astype(np.int64).reshape(-1, 3) if "negative_index" in z
                                   else np.zeros((0, 3), np.int64)),
            }
            # why each is one (scene_dataset's codes; 0 where a file does not say)
            scene["negative_reason"] = (z["negative_reason"].astype(np.int64).reshape(-1) if "negative_reason" in z
                                        else np.zeros(len(scene["negative_index"]), np.int64))
    except (OSError, KeyError, ValueError) as err:
        raise DataError(f"scene file {path} is unreadable or lacks tsdf/label_* arrays ({err}); "
                        "regenerate it with 'ros2 run sim_bridge datagen scenes'") from None
    return scene


def select_labels(scene, config: TrainConfig):
    """Apply the --data subset and --target to a scene's labels -> (index, score,
    valid_target, e_x, e_z)."""
    keep = np.ones(len(scene["score"]), bool)
    if config.subset == "precision-only":
        if scene["mode"] is None:
            raise DataError("--data precision-only needs label_mode in the scene files; "
                            "regenerate scenes with a datagen that records grasp modes")
        keep &= scene["mode"] == list(scene["mode_names"]).index("precision")
    index, score = scene["index"][keep], scene["score"][keep]
    valid = np.ones(len(score), np.float32)
    if config.target == "binary":
        valid = (score >= config.nominal_mass_kg * G_MPS2).astype(np.float32)
    return index, score, valid, scene["e_x"][keep], scene["e_z"][keep]


def split_scenes(files, validation_fraction, seed):
    """Deterministic split by scene: a file is in validation iff a hash of its name
    and the seed falls below the fraction."""
    train, val = [], []
    for f in files:
        h = int(hashlib.sha256(f"{seed}:{pathlib.Path(f).name}".encode()).hexdigest()[:8], 16)
        (val if h / 2**32 < validation_fraction else train).append(f)
    if not val and len(train) > 1:
        val.append(train.pop())
    return train, val


def rotate_about_gravity(grid, index, e_x, e_z, quarter_turns):
    """Rotate the volume and its labels by quarter_turns x 90 deg about the task z axis
    through the volume centre (exact on the voxel grid)."""
    k = quarter_turns % 4
    if k == 0:
        return grid, index, e_x, e_z
    r = grid.shape[0]
    grid = np.rot90(grid, k, axes=(0, 1)).copy()
    c, s = [1, 0, -1, 0][k], [0, 1, 0, -1][k]
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], np.float32)
    i, j = index[:, 0], index[:, 1]
    for _ in range(k):  # one 90 deg turn: (i, j) -> (r-1-j, i), matching np.rot90
        i, j = r - 1 - j, i
    index = np.stack([i, j, index[:, 2]], 1)
    return grid, index, e_x @ Rz.T, e_z @ Rz.T


def shift(grid, index, offset):
    """Translate volume and labels by an integer voxel offset (x, y only: the table
    stays at its height); voxels shifted in are unobserved (0), labels leaving drop."""
    r = grid.shape[0]
    out = np.zeros_like(grid)
    dx, dy = offset
    src = (slice(max(0, -dx), r - max(0, dx)), slice(max(0, -dy), r - max(0, dy)))
    dst = (slice(max(0, dx), r - max(0, -dx)), slice(max(0, dy), r - max(0, -dy)))
    out[dst] = grid[src]
    moved = index + np.array([dx, dy, 0])
    inside = ((moved >= 0) & (moved < r)).all(1)
    return out, moved, inside


def make_example(scene, config, rng=None):
    """One training example as dense tensors; augmented when rng is given. The explicit
    negatives ride along as extra rows with valid 0 (and no score or rotation), so the
    augmentation moves them with the labels (the scene stage keeps them off labelled
    voxels)."""
    index, score, valid, e_x, e_z = select_labels(scene, config)
    negatives = scene.get("negative_index", np.zeros((0, 3), np.int64))
    if len(negatives):
        zeros = np.zeros((len(negatives), 3), np.float32)
        index = np.concatenate([index, negatives])
        score = np.concatenate([score, np.zeros(len(negatives), np.float32)])
        valid = np.concatenate([valid, np.zeros(len(negatives), np.float32)])
        e_x, e_z = np.concatenate([e_x, zeros]), np.concatenate([e_z, zeros])
    grid = scene["tsdf"]
    keep = np.ones(len(score), bool)
    if rng is not None:
        grid, index, e_x, e_z = rotate_about_gravity(grid, index, e_x, e_z, int(rng.integers(4)))
        grid, index, keep = shift(grid, index, rng.integers(-2, 3, size=2))
    index, score, valid, e_x, e_z = index[keep], score[keep], valid[keep], e_x[keep], e_z[keep]
    return {
        "tsdf": torch.from_numpy(np.ascontiguousarray(grid))[None],
        "index": torch.from_numpy(index),
        "score": torch.from_numpy(score),
        "valid": torch.from_numpy(valid),
        "R": torch.from_numpy(np.stack([e_x, np.cross(e_z, e_x), e_z], -1).astype(np.float32)),
    }
