"""The protocol's clear_hand (`benchmark --clear-hand`; off by default, as the paper has no
such step) for the project's models: publish only grasps whose open hand, swept from the
pre-grasp along the approach, clears the observed scene (the executor's own check,
perception.hand_clearance). A grasp that fails it is taken out of the candidates and the
ranking steps run again, so that non-maximum suppression no longer lets it hide the
neighbours the hand can reach (a grasp one voxel too deep in a glass suppressed 173 clear
ones around it, and the executor refused the only grasp published).

`clear_hand` is a `from_candidates` step of perception.detection.select_grasps. The
baselines' methods check their own hands with the same stand-off (vgn, vn_edge)."""

from __future__ import annotations

import numpy as np
import torch

from gravgrasp_detector.execution.executor import ExecutionLimits
from gravgrasp_detector.perception import hand_clearance

# where the swept hand starts: the executor's default pre-grasp stand-off [m]
PREGRASP_DISTANCE_M = ExecutionLimits.pregrasp_distance_m
CLEAR_HAND_ROUNDS = 8  # reruns of the ranking steps; what still collides after them is dropped


def clear_hand(grid, candidate, ranked, poses_at, voxel_size_m, nms_radius_voxels,
               pregrasp_distance_m=PREGRASP_DISTANCE_M):
    """(index, poses) of the grasps, best first, whose open hand clears the scene:
    take the grasps that collide out of `candidate` and rank again (`ranked`: candidate
    mask -> detection's steps 3-5), until the grasps kept clear it. A grasp that collides
    is checked with the candidates of its NMS neighbourhood (those it suppressed) at once:
    its neighbours one voxel deeper mostly collide too."""
    grasps = ranked(candidate)
    points = hand_clearance.occupied_points(np.asarray(grid), voxel_size_m)  # the grid's frame, as the poses
    candidate = candidate.clone()
    clear = torch.zeros_like(candidate)
    checked = torch.zeros_like(candidate)

    def check(index, poses):
        hit = hand_clearance.hands_collide(poses, points, voxel_size_m, pregrasp_distance_m)
        clear[tuple(index.T)] = torch.as_tensor(~hit)
        checked[tuple(index.T)] = True

    r = max(int(nms_radius_voxels), 0)
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
