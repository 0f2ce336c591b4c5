"""Does the open hand hit what the TSDF has seen? The executor's collision check.

Occupied space is what the camera saw as surface or just behind it: voxels in the
truncation band with a value below 0.5 (tsdf.py's convention: 0.5 on the surface,
< 0.5 behind it, 0 = unobserved or far from any surface). Unobserved space counts as
free, as in VGN's execution: the network has already judged the grasp, and the
occluded back of an object is where fingers often go. The hand is a box model of the
open hand (`HandGeometry`; default the 2F-85's, robotiq_driver.hand_geometry), swept
along the approach. The fingertip-against-table check models the 2F-85's linkage only.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from robotiq_driver import hand_geometry as robotiq_2f85
from robotiq_driver.hand_geometry import HAND_PARTS, OPEN_HAND_BOXES_TCP, closed_tips_lowest_z, closing_opening_m


@dataclasses.dataclass(frozen=True, eq=False)
class HandGeometry:
    """What the executor knows of the hand it runs: how wide it opens, and the open hand
    as boxes in the TCP frame (z = approach, fingers closing along y) for the clearance
    check. The executor imports no simulation: a caller with another hand (the sim
    bridge's Panda) builds one from that hand's facts."""
    name: str
    open_width_m: float           # what the executor opens the fingers to
    parts: tuple                  # a name per box, for the refusal's words
    open_boxes_tcp: np.ndarray    # (len(parts), 2, 3): (lo, hi) corners [m]
    # closed_tips_below_table's model of where the fingertips go while closing is this
    # hand's (the 2F-85's linkage swings them along the approach)
    closing_tips_modelled: bool = False

    def __post_init__(self):
        boxes = np.asarray(self.open_boxes_tcp, dtype=float)
        if boxes.shape != (len(self.parts), 2, 3) or not np.all(boxes[:, 0] < boxes[:, 1]):
            raise ValueError(f"hand {self.name!r}: give one (lo, hi) box per part, lo < hi on every axis "
                             f"({len(self.parts)} parts, boxes of shape {boxes.shape})")
        if not (np.isfinite(self.open_width_m) and self.open_width_m > 0):
            raise ValueError(f"hand {self.name!r}: open_width_m {self.open_width_m}: give the opening [m], > 0")
        object.__setattr__(self, "open_boxes_tcp", boxes)

    def swept_boxes(self, approach_m: float) -> np.ndarray:
        """The open-hand boxes extended back along -z by `approach_m`: what the hand
        sweeps from the pre-grasp pose to the grasp pose."""
        boxes = self.open_boxes_tcp.copy()
        boxes[:, 0, 2] -= approach_m
        return boxes


ROBOTIQ_2F85 = HandGeometry("2f85", robotiq_2f85.MAX_STROKE_M, HAND_PARTS, OPEN_HAND_BOXES_TCP,
                            closing_tips_modelled=True)

# Voxels with values below this are "behind a surface". A little under 0.5 so that
# voxels whose centre sits right on the surface do not count as collisions.
OCCUPIED_BELOW = 0.45


def occupied_points(grid: np.ndarray, voxel_size_m: float, origin=np.zeros(3)) -> np.ndarray:
    """Task-frame centres of occupied voxels of a (R,R,R) network grid."""
    ijk = np.argwhere((grid > 0.0) & (grid < OCCUPIED_BELOW))
    return np.asarray(origin) + (ijk + 0.5) * voxel_size_m


def points_in_hand(X_task_tcp: np.ndarray, points_task: np.ndarray, boxes_tcp=OPEN_HAND_BOXES_TCP,
                   margin_m: float = 0.0, parts=HAND_PARTS) -> dict[str, int]:
    """Points inside each part of the hand at this pose: {part name: count}, hits only.
    `parts`: the names of `boxes_tcp`, in order."""
    if len(points_task) == 0:
        return {}
    p = (points_task - X_task_tcp[:3, 3]) @ X_task_tcp[:3, :3]  # into the TCP frame
    hits = {}
    for name, (lo, hi) in zip(parts, boxes_tcp):
        n = int(np.all((p > lo + margin_m) & (p < hi - margin_m), axis=1).sum())
        if n:
            hits[name] = hits.get(name, 0) + n
    return hits


def collisions(poses: dict, tsdf, hand: HandGeometry = ROBOTIQ_2F85) -> dict[str, dict[str, int]]:
    """Occupied TSDF voxels inside the open hand, {check: {part: count}}, checks with hits
    only: the hand at the pre-grasp pose, and swept along the approach to the grasp pose
    (whose boxes contain the pre-grasp's). `tsdf`: (grid, voxel_size_m, origin)."""
    grid, voxel_size_m, origin = tsdf
    points = occupied_points(grid, voxel_size_m, origin)
    # Shrink boxes by half a voxel: a voxel centre half a voxel inside a box may be free.
    margin = 0.5 * voxel_size_m
    approach_m = float(np.linalg.norm(poses["grasp"][:3, 3] - poses["pregrasp"][:3, 3]))
    checks = [("pre-grasp pose", poses["pregrasp"], hand.open_boxes_tcp),
              ("approach and grasp pose", poses["grasp"], hand.swept_boxes(approach_m))]
    found = {name: points_in_hand(X, points, boxes, margin, hand.parts) for name, X, boxes in checks}
    return {name: hits for name, hits in found.items() if hits}


def first_collision(poses: dict, tsdf, hand: HandGeometry = ROBOTIQ_2F85) -> str:
    """'' if the hand is clear at pre-grasp, along the approach and at the grasp;
    otherwise a sentence saying where it collides. `tsdf`: (grid, voxel_size_m, origin)."""
    for name, hits in collisions(poses, tsdf, hand).items():
        where = ", ".join(f"{part}: {n}" for part, n in hits.items())
        return (f"the open hand collides with the scene at the {name} (occupied TSDF voxels "
                f"inside the {where}): pick another grasp")
    return ""


def hands_collide(poses_tcp: np.ndarray, points: np.ndarray, voxel_size_m: float, approach_m: float,
                  hand: HandGeometry = ROBOTIQ_2F85) -> np.ndarray:
    """(N,) bool: whether the open hand, swept `approach_m` back along its approach from
    each grasp pose (N, 4, 4), contains any of the occupied voxel centres `points` (M, 3):
    first_collision's verdict for many grasps at once (the swept boxes contain the
    pre-grasp's)."""
    poses_tcp = np.asarray(poses_tcp, float).reshape(-1, 4, 4)
    if len(points) == 0 or len(poses_tcp) == 0:
        return np.zeros(len(poses_tcp), bool)
    boxes = hand.swept_boxes(approach_m)
    margin = 0.5 * voxel_size_m  # as first_collision
    outer_lo, outer_hi = boxes[:, 0].min(axis=0), boxes[:, 1].max(axis=0)  # the box around every part
    hit = np.zeros(len(poses_tcp), bool)
    for n, X in enumerate(poses_tcp):
        # only the points in the box around the whole hand go to the per-part test
        p = (points - X[:3, 3]) @ X[:3, :3]
        near = points[np.all((p > outer_lo) & (p < outer_hi), axis=1)]
        hit[n] = bool(points_in_hand(X, near, boxes, margin, hand.parts))
    return hit


def closed_tips_estimate(X_grasps, tsdf, table_z_m: float):
    """-> (opening (N,), lowest pad tip z (N,)) [m] of the fingers closed at each grasp
    (N, 4, 4) of the 2F-85 (HandGeometry.closing_tips_modelled): closing swings the tips up to 13.5 mm further along the approach, more the
    less there is between the pads (hand_geometry.pad_tip_z_m); the pads stop at the
    extent of the occupied voxels between them, above the table. None seen (no `tsdf`,
    or the object hidden from the camera): they close fully, the deepest case."""
    X = np.asarray(X_grasps, dtype=float).reshape(-1, 4, 4)
    points = np.zeros((0, 3))
    if tsdf is not None:
        grid, voxel_size_m, origin = tsdf
        points = occupied_points(grid, voxel_size_m, origin)
        points = points[points[:, 2] > table_z_m + voxel_size_m]  # the table's own voxels stop nothing
    opening = closing_opening_m(X, points, np.zeros(len(X)))
    return opening, closed_tips_lowest_z(X, opening)


def closed_tips_below_table(X_grasp: np.ndarray, tsdf, table_z_m: float) -> str:
    """'' if the pad tips stay above the table top `table_z_m` (task frame) once the
    fingers close at this grasp (closed_tips_estimate); otherwise a sentence saying how
    far they would press into it."""
    opening, low = (float(v[0]) for v in closed_tips_estimate(X_grasp, tsdf, table_z_m))
    if low >= table_z_m:
        return ""
    return (f"closing would press a fingertip {1000 * (table_z_m - low):.0f} mm into the table: the pads stop "
            f"at a {1000 * opening:.0f} mm opening (what the TSDF shows between them) with their tips at "
            f"z = {low:.3f} m, below the table top at {table_z_m:.3f} m (parameter table_z_m): pick another grasp")
