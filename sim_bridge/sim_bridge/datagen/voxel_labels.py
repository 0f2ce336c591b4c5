"""Sparse per-voxel grasp labels of a scene (the training target).

A grasp labels the voxel that contains its TCP (pinch point): score f_g [N],
validness 1, and the TCP axes e_x, e_z in the task frame (the network regresses
them; R is rebuilt with paper Eq. 2).  Voxels without a grasp are invalid.
When several grasps fall in one voxel the one with the highest f_g is kept.
Voxel (i, j, k) covers [i, i+1) * voxel_size along x (likewise y, z) from the
task-frame origin at the corner of the cube, so its centre is
origin + (i + 0.5, j + 0.5, k + 0.5) * voxel_size.
"""

import numpy as np

from ..physics.scenes import VOLUME_SIZE_M

RESOLUTION = 40


def voxel_index(points_task, size_m=VOLUME_SIZE_M, resolution=RESOLUTION):
    """(N, 3) int64: the voxel (i, j, k) that contains each task-frame point (N, 3); may
    lie outside [0, resolution)."""
    return np.floor(np.asarray(points_task, dtype=float) / (size_m / resolution)).astype(np.int64)


def voxel_labels(X_task_tcp, scores_g, size_m=VOLUME_SIZE_M, resolution=RESOLUTION):
    """Best grasp per voxel.

    X_task_tcp: (N, 4, 4) grasp poses in the task frame; scores_g: (N,) f_g [N].
    Returns a dict of arrays, one row per labelled voxel, sorted by voxel index:
      index (K, 3) uint8, score (K,) float32 [N], e_x (K, 3) float32,
      e_z (K, 3) float32, grasp (K,) int64 = row of the chosen grasp in the input.
    Grasps outside the volume or with a non-finite score are ignored.
    """
    X = np.asarray(X_task_tcp, dtype=float).reshape(-1, 4, 4)
    f = np.asarray(scores_g, dtype=float).reshape(-1)
    ijk = voxel_index(X[:, :3, 3], size_m, resolution)
    ok = np.isfinite(f) & ((ijk >= 0) & (ijk < resolution)).all(axis=1)
    rows = np.flatnonzero(ok)
    flat = np.ravel_multi_index(ijk[rows].T, (resolution,) * 3) if len(rows) else np.zeros(0, np.int64)
    # best score first, ties by input order; then the first row of each voxel wins
    order = np.lexsort((rows, -f[rows], flat))
    flat, rows = flat[order], rows[order]
    first = np.ones(len(flat), dtype=bool)
    first[1:] = flat[1:] != flat[:-1]
    rows = rows[first]
    return {
        "index": ijk[rows].astype(np.uint8),
        "score": f[rows].astype(np.float32),
        "e_x": X[rows, :3, 0].astype(np.float32),
        "e_z": X[rows, :3, 2].astype(np.float32),
        "grasp": rows.astype(np.int64),
    }


def at_voxel_centres(X_task_tcp, size_m=VOLUME_SIZE_M, resolution=RESOLUTION):
    """(N, 4, 4): each pose moved to the centre of the voxel that contains its TCP, same
    rotation. That is the pose detection publishes for the voxel this grasp labels, so
    the pose the robot executes: up to half a voxel off the simulated one on each axis."""
    X = np.array(X_task_tcp, dtype=float).reshape(-1, 4, 4)
    X[:, :3, 3] = (voxel_index(X[:, :3, 3], size_m, resolution) + 0.5) * (size_m / resolution)
    return X


def label_poses(scene, voxel_size_m=VOLUME_SIZE_M / RESOLUTION):
    """(K, 4, 4): each label of a scene file (label_e_x, label_e_z, label_index) as the
    TCP pose at its voxel centre, the pose detection publishes for that voxel."""
    e_x = scene["label_e_x"] / np.linalg.norm(scene["label_e_x"], axis=1, keepdims=True)
    e_z = scene["label_e_z"] / np.linalg.norm(scene["label_e_z"], axis=1, keepdims=True)
    X = np.repeat(np.eye(4)[None], len(e_x), axis=0)
    X[:, :3, 0], X[:, :3, 1], X[:, :3, 2] = e_x, np.cross(e_z, e_x), e_z
    X[:, :3, 3] = (np.asarray(scene["label_index"], float) + 0.5) * voxel_size_m
    return X


def dense_labels(labels, resolution=RESOLUTION):
    """Dense (score, validness, e_x, e_z) volumes from sparse labels, for training.

    Returns score (R,R,R) float32, valid (R,R,R) float32 in {0,1},
    e_x (3,R,R,R) and e_z (3,R,R,R) float32 (zero where invalid).
    """
    shape = (resolution,) * 3
    score = np.zeros(shape, np.float32)
    valid = np.zeros(shape, np.float32)
    e_x = np.zeros((3,) + shape, np.float32)
    e_z = np.zeros((3,) + shape, np.float32)
    i, j, k = np.asarray(labels["index"], dtype=np.int64).T
    score[i, j, k] = labels["score"]
    valid[i, j, k] = 1.0
    e_x[:, i, j, k] = np.asarray(labels["e_x"]).T
    e_z[:, i, j, k] = np.asarray(labels["e_z"]).T
    return score, valid, e_x, e_z
