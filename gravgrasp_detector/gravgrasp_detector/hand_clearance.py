"""Does the open 2F-85 hit what the TSDF has seen? The executor's collision check.

Occupied space is what the camera saw as surface or just behind it: voxels in the
truncation band with a value below 0.5 (tsdf.py's convention: 0.5 on the surface,
< 0.5 behind it, 0 = unobserved or far from any surface). Unobserved space counts as
free, as in VGN's execution: the network has already judged the grasp, and the
occluded back of an object is where fingers often go. The hand is the box model of
robotiq_driver.hand_geometry, swept along the approach.
"""
from __future__ import annotations

import numpy as np

from robotiq_driver.hand_geometry import HAND_PARTS, OPEN_HAND_BOXES_TCP, swept_boxes

# Voxels with values below this are "behind a surface". A little under 0.5 so that
# voxels whose centre sits right on the surface do not count as collisions.
OCCUPIED_BELOW = 0.45


def occupied_points(grid: np.ndarray, voxel_size_m: float, origin=np.zeros(3)) -> np.ndarray:
    """Task-frame centres of occupied voxels of a (R,R,R) network grid."""
    ijk = np.argwhere((grid > 0.0) & (grid < OCCUPIED_BELOW))
    return np.asarray(origin) + (ijk + 0.5) * voxel_size_m


def points_in_hand(X_task_tcp: np.ndarray, points_task: np.ndarray, boxes_tcp=OPEN_HAND_BOXES_TCP,
                   margin_m: float = 0.0) -> dict[str, int]:
    """Points inside each part of the hand at this pose: {part name: count}, hits only."""
    if len(points_task) == 0:
        return {}
    p = (points_task - X_task_tcp[:3, 3]) @ X_task_tcp[:3, :3]  # into the TCP frame
    hits = {}
    for name, (lo, hi) in zip(HAND_PARTS, boxes_tcp):
        n = int(np.all((p > lo + margin_m) & (p < hi - margin_m), axis=1).sum())
        if n:
            hits[name] = hits.get(name, 0) + n
    return hits


def first_collision(poses: dict, tsdf) -> str:
    """'' if the hand is clear at pre-grasp, along the approach and at the grasp;
    otherwise a sentence saying where it collides. `tsdf`: (grid, voxel_size_m, origin)."""
    grid, voxel_size_m, origin = tsdf
    points = occupied_points(grid, voxel_size_m, origin)
    # Shrink boxes by half a voxel: a voxel centre half a voxel inside a box may be free.
    margin = 0.5 * voxel_size_m
    approach_m = float(np.linalg.norm(poses["grasp"][:3, 3] - poses["pregrasp"][:3, 3]))
    checks = [("pre-grasp pose", poses["pregrasp"], OPEN_HAND_BOXES_TCP),
              ("approach and grasp pose", poses["grasp"], swept_boxes(approach_m))]
    for name, X, boxes in checks:
        hits = points_in_hand(X, points, boxes, margin)
        if hits:
            where = ", ".join(f"{part}: {n}" for part, n in hits.items())
            return (f"the open hand collides with the scene at the {name} (occupied TSDF voxels "
                    f"inside the {where}): pick another grasp")
    return ""
