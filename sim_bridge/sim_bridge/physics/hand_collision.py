"""Fast collision model of the *open* Robotiq 2F-85 for filtering grasp poses.

The hand is the union of boxes in the TCP frame of `robotiq_driver.hand_geometry`
(sketch and dimensions there; the executor checks the same boxes against the TSDF).

A pose collides when a point of another body (sampled on its surface, spacing a
few mm) is inside a box, or a box corner is below the table plane.  The approach
is checked by sweeping the boxes back along -z by `approach_m` (the hand moves
along +z from the pre-grasp pose), which for boxes is just a longer box.
This is a conservative filter; the grasp simulation itself uses the full hand.
"""

import itertools

import numpy as np
import trimesh
from scipy.spatial import cKDTree

# The open-hand boxes are shared with the executor's TSDF check (one source).
from robotiq_driver.hand_geometry import (  # noqa: F401  (re-exported)
    FINGER_TIP_Z_M, MAX_STROKE_M, OPEN_HAND_BOXES_TCP, PAD_WIDTH_M, PALM_FACE_Z_M, closed_pad_tips_tcp,
    closed_tips_lowest_z, closing_opening_m, lowest_z_m, pad_tip_z_m, swept_boxes as _swept_boxes)

POINT_SPACING_M = 0.003     # surface sampling: well below the thinnest box (20 mm)


def surface_points(mesh, spacing_m=POINT_SPACING_M, seed=0):
    """Points on a trimesh surface about `spacing_m` apart, plus its vertices."""
    count = int(np.clip(mesh.area / spacing_m**2, 100, 200_000))
    pts, _ = trimesh.sample.sample_surface(mesh, count, seed=seed)
    return np.vstack([pts, mesh.vertices]).astype(np.float64)


def collides(X_world_tcp, points_world=None, table_z_m=None, approach_m=0.0,
             margin_m=0.0):
    """(N,) bool: does the open hand at each pose (or on its approach) hit anything?

    X_world_tcp: (N, 4, 4) or (4, 4) hand poses.
    points_world: (M, 3) surface points of the obstacles, or None.
    table_z_m: height of the table plane (obstacle below), or None.
    approach_m: length of the straight approach along +z that ends at the pose.
    margin_m: grow every box by this much.
    """
    X = np.asarray(X_world_tcp, dtype=float)
    if X.ndim == 2:
        X = X[None]
    boxes = _swept_boxes(approach_m)
    boxes[:, 0] -= margin_m
    boxes[:, 1] += margin_m
    hit = np.zeros(len(X), dtype=bool)
    if table_z_m is not None:
        hit |= lowest_point_z(X, approach_m, margin_m) < table_z_m
    if points_world is not None and len(points_world):
        P = np.asarray(points_world, dtype=float)
        tree, grid = cKDTree(P), _PointCounts(P)
        todo = np.flatnonzero(~hit)
        # fingers first (HAND_PARTS reversed): they hit most, and a pose that hit is done
        for lo, hi in (piece for box in boxes[::-1] for piece in _cube_like_pieces(*box)):
            for chunk in np.array_split(todo, max(1, len(todo) // POSES_PER_QUERY)):
                hit[chunk] = _points_in_box(X[chunk], P, tree, grid, lo, hi)
            todo = todo[~hit[todo]]
    return hit


POSES_PER_QUERY = 1024  # bounds the (pose, point) pairs held at once


def _cube_like_pieces(lo, hi):
    """The box lo..hi cut into pieces about as long as its shortest side, which tile it
    exactly (neighbours share their faces' values): a long finger box swept along the
    approach is queried as a few small cubes rather than one cube as long as it is."""
    side = max(float(np.min(hi - lo)), 0.01)
    edges = [np.linspace(a, b, max(1, int(np.ceil((b - a) / side - 1e-9))) + 1) for a, b in zip(lo, hi)]
    return [(np.array([ex[i], ey[j], ez[k]]), np.array([ex[i + 1], ey[j + 1], ez[k + 1]]))
            for ex, ey, ez in [edges]
            for i in range(len(ex) - 1) for j in range(len(ey) - 1) for k in range(len(ez) - 1)]


class _PointCounts:
    """Point counts of a grid over the points, summed (a 3D summed-area table): how many
    points lie in a block of cells is 8 look-ups, for any number of blocks at once. Most
    (pose, box) queries of a scene find no point (~90 %); this answers those without the
    k-d tree, exactly: a cube's covering cells hold every point of the cube."""

    CELL_M = 0.005

    def __init__(self, P):
        self.origin = P.min(axis=0)
        cells = self._cells(P)
        self.shape = cells.max(axis=0) + 1
        grid = np.zeros(self.shape, np.int64)
        np.add.at(grid, tuple(cells.T), 1)
        self.sums = np.zeros(self.shape + 1, np.int64)  # sums[i, j, k]: cells below (i, j, k)
        self.sums[1:, 1:, 1:] = grid.cumsum(0).cumsum(1).cumsum(2)

    def _cells(self, x):
        # floor((x - origin) / cell) is monotone in x, so a point between two bounds lies
        # in a cell between theirs
        return np.floor((x - self.origin) / self.CELL_M).astype(np.int64)

    def any_in_cubes(self, centres, radii):
        """(N,) bool: may a point lie within Chebyshev distance radii of centres? False is exact."""
        first = np.clip(self._cells(centres - radii[:, None]), 0, self.shape)
        last = np.clip(self._cells(centres + radii[:, None]) + 1, 0, self.shape)  # exclusive
        empty = (last <= first).any(axis=1)  # the cube misses the grid, so every point
        s, (a0, a1, a2), (b0, b1, b2) = self.sums, first.T, last.T
        total = (s[b0, b1, b2] - s[a0, b1, b2] - s[b0, a1, b2] - s[b0, b1, a2]
                 + s[a0, a1, b2] + s[a0, b1, a2] + s[b0, a1, a2] - s[a0, a1, a2])
        return (total > 0) & ~empty


def _points_in_box(X, P, tree, grid, lo, hi):
    """(N,) bool: is any point of P inside the box lo..hi (TCP frame) at each pose X?
    Only the points in a cube around the box's world bounding box are tested (Chebyshev
    ball query): a hand sweeps a few centimetres of a scene ~30 cm across. The poses
    whose cube `grid` (_PointCounts of P) finds empty skip the query."""
    hit = np.zeros(len(X), dtype=bool)
    R, t = X[:, :3, :3], X[:, :3, 3]
    centres = R @ ((lo + hi) / 2) + t
    radii = (np.abs(R) @ ((hi - lo) / 2)).max(axis=1)  # of the box's world AABB
    maybe = np.flatnonzero(grid.any_in_cubes(centres, radii))
    near = tree.query_ball_point(centres[maybe], radii[maybe], p=np.inf, return_sorted=False)
    counts = np.fromiter((len(n) for n in near), dtype=np.int64, count=len(near))
    if not counts.any():
        return hit
    owner = np.repeat(maybe, counts)
    index = np.fromiter(itertools.chain.from_iterable(near), dtype=np.int64, count=int(counts.sum()))
    q = np.einsum("nij,ni->nj", R[owner], P[index] - t[owner])  # into the TCP frame
    hit[owner[((q >= lo) & (q <= hi)).all(axis=1)]] = True
    return hit


def lowest_point_z(X_world_tcp, approach_m=0.0, margin_m=0.0):
    """(N,) world height of the lowest point of the open hand (with its approach) at
    each pose.  Shifting a pose by o along its own +z lowers it by -o * X[2, 2]."""
    X = np.asarray(X_world_tcp, dtype=float).reshape(-1, 4, 4)
    boxes = _swept_boxes(approach_m)
    boxes[:, 0] -= margin_m
    boxes[:, 1] += margin_m
    # 8 corners of every box: a convex box is above a plane iff all its corners are
    corners = np.stack(np.meshgrid([0, 1], [0, 1], [0, 1], indexing="ij"), -1).reshape(-1, 3)
    pts = np.where(corners[None, :, :] == 0, boxes[:, None, 0, :], boxes[:, None, 1, :]).reshape(-1, 3)
    return lowest_z_m(X, pts)


def collides_along_approach(X_world_tcp, points_world, offsets_m, approach_m=0.0, margin_m=0.0):
    """(N, K) bool: `collides` for each pose shifted by each offset along its own +z.

    The same as calling `collides` on every shifted pose, but the points are moved
    into each TCP frame once (a shift along z only moves them along z).
    """
    X = np.asarray(X_world_tcp, dtype=float).reshape(-1, 4, 4)
    offsets = np.asarray(offsets_m, dtype=float)
    boxes = _swept_boxes(approach_m)
    boxes[:, 0] -= margin_m
    boxes[:, 1] += margin_m
    hit = np.zeros((len(X), len(offsets)), dtype=bool)
    if points_world is None or not len(points_world):
        return hit
    P = np.asarray(points_world, dtype=float)
    lo_all, hi_all = boxes[:, 0].min(0), boxes[:, 1].max(0)
    radius = np.linalg.norm(np.maximum(np.abs(lo_all), np.abs(hi_all))) + np.abs(offsets).max()
    for k in range(len(X)):
        R, t = X[k, :3, :3], X[k, :3, 3]
        d = P - t
        q = d[np.einsum("mj,mj->m", d, d) < radius**2] @ R
        if not len(q):
            continue
        # a point inside a box in x, y is hit by offset o iff lo_z <= q_z - o <= hi_z
        for b, (lo, hi) in enumerate(boxes):
            inside_xy = ((q[:, :2] >= lo[:2]) & (q[:, :2] <= hi[:2])).all(axis=1)
            z = q[inside_xy, 2]
            if not len(z):
                continue
            hit[k] |= ((z[None] - offsets[:, None] >= lo[2]) & (z[None] - offsets[:, None] <= hi[2])).any(axis=1)
    return hit
