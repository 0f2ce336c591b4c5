"""Where did a pick sit in the view it was chosen from, and what would its approach hit?
The geometry behind studies.before_lift_diagnosis (issue 42): no physics, no ROS.

- `View`: one view's TSDF as the volume holds it (TSDFVolume.tsdf_and_weights: d /
  truncation in [-1, 1] and the integration weight), which tells apart what the network
  grid (0 = unobserved AND far from any surface) cannot. `surface_class` of a point:
    inside      behind the observed surface, within the truncation band (d < 0)
    band        in front of the surface, within the truncation band (0 <= d < 0.98)
    free        observed free space beyond the band (seen, d at the band's edge)
    unobserved  never integrated: occluded deeper than the band behind a surface
                (a power grasp's TCP inside a large object), or outside the camera's view
- `vgn_keeps`: VGN's mask (detection.py of ethz-asl/vgn, as benchmark.methods.vgn applies
  it): a voxel counts only within 2 six-connected dilations of observed free space
  (grid > 0.5) that do not enter observed inside (1e-3 < grid < 0.5). VGN's TCP is the
  Panda's finger base, its finger tips 5 cm ahead; the 2F-85's TCP is the pinch point
  between the pads, at an object's middle. So `diagnose_pick` tests the mask twice: at the
  TCP (the mask applied to this network's voxels as they are) and at the point where VGN's
  TCP would sit on the same approach (vgn's `FINGER_BASE_Z_M`, 5 cm behind the finger tips).
- `first_contact`: the open hand's boxes (perception.hand_clearance.HandGeometry, the
  executor's model of the hand) moved from the pre-grasp along the approach to the grasp
  pose against the true objects (surface samples) and the table plane: the approach
  distance at which something first enters a box, found exactly per sample (a point
  enters a box at one distance along a straight approach), so its error is the spacing of
  the samples (SAMPLE_SPACING_M), not a step. The boxes are coarse: they bound the real
  links, so a computed contact can be a few mm early.
- `same_pick`: two grasps within 2 cm and 30 deg (the 2F-85 is symmetric under a half
  turn about the approach).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import trimesh

from gravgrasp_detector.perception.detection import CLOSING_REGION_TCP
from gravgrasp_detector.perception.tsdf import to_network_grid

from ..benchmark.methods.vgn import FINGER_BASE_Z_M, free_space_band

SURFACE_CLASSES = ("inside", "band", "free", "unobserved")
BAND_LIMIT = 0.98  # |d| / truncation at which the grid drops a voxel (tsdf.to_network_grid)
SAMPLE_SPACING_M = 0.002  # object surface samples this far apart (about)
MAX_SAMPLES = 60_000  # per object: a 0.24 m^2 surface at 2 mm
SAME_PICK_M, SAME_PICK_DEG = 0.02, 30.0


@dataclasses.dataclass(frozen=True, eq=False)
class View:
    """One integrated view: tsdf (d / truncation in [-1, 1]) and weights (0 = never
    observed), each (R, R, R); voxel (i, j, k) centre = origin + (ijk + 0.5) * voxel_size_m."""
    tsdf: np.ndarray
    weights: np.ndarray
    voxel_size_m: float
    origin: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))

    def __post_init__(self):
        if np.shape(self.tsdf) != np.shape(self.weights) or np.ndim(self.tsdf) != 3:
            raise ValueError(f"tsdf {np.shape(self.tsdf)} and weights {np.shape(self.weights)}: give two (R, R, R) "
                             "arrays of one view (TSDFVolume.tsdf_and_weights())")

    @property
    def grid(self) -> np.ndarray:
        """What the network read (tsdf.py's convention)."""
        return to_network_grid(self.tsdf, self.weights)

    def voxels_of(self, points) -> tuple:
        """((N, 3) voxel indices, (N,) inside the volume) of task-frame points."""
        ijk = np.floor((np.asarray(points, float).reshape(-1, 3) - self.origin) / self.voxel_size_m).astype(int)
        return ijk, np.all((ijk >= 0) & (ijk < np.array(self.tsdf.shape)), axis=1)

    def centres(self, ijk) -> np.ndarray:
        return np.asarray(self.origin, float) + (np.asarray(ijk) + 0.5) * self.voxel_size_m


def surface_class(view: View, points) -> np.ndarray:
    """(N,) class names (SURFACE_CLASSES) of task-frame points; outside the volume: unobserved."""
    ijk, ok = view.voxels_of(points)
    out = np.full(len(ijk), "unobserved", dtype=object)
    i, j, k = ijk[ok].T
    d, w = view.tsdf[i, j, k], view.weights[i, j, k]
    out[ok] = np.where(w <= 0, "unobserved", np.where(d < 0, "inside", np.where(d < BAND_LIMIT, "band", "free")))
    return out


def vgn_mask(grid) -> np.ndarray:
    """(R, R, R) bool: the voxels VGN's detection keeps (module doc)."""
    return free_space_band(grid).numpy()


def vgn_keeps(view: View, point, mask=None) -> bool:
    (ijk,), (ok,) = view.voxels_of(point)
    mask = vgn_mask(view.grid) if mask is None else mask
    return bool(ok and mask[tuple(ijk)])


def closing_region_classes(view: View, X_task_tcp) -> dict:
    """{class: voxels} of the voxel centres in the open hand's closing region at X_task_tcp."""
    lo, hi = CLOSING_REGION_TCP
    X = np.asarray(X_task_tcp, float)
    # the voxels around the region's bounding sphere, then the exact box test
    r = float(np.linalg.norm(np.maximum(np.abs(lo), np.abs(hi))))
    (c,), _ = view.voxels_of(X[:3, 3])
    n = int(np.ceil(r / view.voxel_size_m)) + 1
    axes = [np.arange(max(c[a] - n, 0), min(c[a] + n + 1, view.tsdf.shape[a])) for a in range(3)]
    ijk = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    q = (view.centres(ijk) - X[:3, 3]) @ X[:3, :3]
    ijk = ijk[np.all((q >= lo) & (q <= hi), axis=1)]
    classes = surface_class(view, view.centres(ijk))
    return {name: int((classes == name).sum()) for name in SURFACE_CLASSES}


def surface_distance_m(view: View, point) -> float:
    """From a point to the nearest observed on-or-behind-surface voxel centre (0 < grid
    <= 0.5, what the detector's closing-region step counts); inf if none."""
    g = view.grid
    centres = view.centres(np.argwhere((g > 0) & (g <= 0.5)))
    if not len(centres):
        return float("inf")
    return float(np.min(np.linalg.norm(centres - np.asarray(point, float).reshape(3), axis=1)))


def sample_surface(mesh: trimesh.Trimesh, spacing_m: float = SAMPLE_SPACING_M, seed: int = 0) -> np.ndarray:
    """Surface samples of a mesh (its own frame), about `spacing_m` apart."""
    n = int(np.clip(mesh.area / spacing_m ** 2, 500, MAX_SAMPLES))
    return trimesh.sample.sample_surface(mesh, n, seed=seed)[0]


def first_contact(X_grasp, approach_m: float, hand, object_points: dict, table_z_m: float) -> dict | None:
    """The first thing the open hand meets moving `approach_m` along its approach (TCP z)
    from the pre-grasp to the grasp pose X_grasp: {approach_m: how far it got (0 = already
    touching at the pre-grasp), short_m: approach_m left to the grasp pose, what: an
    object's name or "table", part: the hand's box}, or None when it reaches the grasp pose
    touching nothing. hand: a HandGeometry; object_points: {name: (M, 3) task-frame
    surface samples}; the table: the plane z = table_z_m."""
    X = np.asarray(X_grasp, float)
    R, t, d = X[:3, :3], X[:3, 3], float(approach_m)
    best = (np.inf, None, None)
    for part, (lo, hi) in zip(hand.parts, hand.open_boxes_tcp):
        for name, points in object_points.items():
            q = (np.asarray(points, float) - t) @ R  # in the TCP frame at the grasp pose
            # at approach s the hand's TCP is d - s short of the grasp: the point sits at
            # q_z + d - s in its frame, inside the box for s in [q_z + d - hi_z, q_z + d - lo_z]
            across = np.all((q[:, :2] > lo[:2]) & (q[:, :2] < hi[:2]), axis=1)
            enter, leave = q[:, 2] + d - hi[2], q[:, 2] + d - lo[2]
            hit = across & (leave >= 0) & (enter <= d)
            if hit.any():
                s = max(float(enter[hit].min()), 0.0)
                if s < best[0]:
                    best = (s, name, part)
        # the table: a box corner's height falls linearly along the approach
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        a_z = R[2, 2]
        z0 = t[2] + corners @ R[2, :] - d * a_z  # corner heights at the pre-grasp (s = 0)
        if np.any(z0 <= table_z_m):
            s = 0.0
        elif a_z < 0:
            s = float(np.min((table_z_m - z0) / a_z))
        else:
            continue
        if s <= d and s < best[0]:
            best = (s, "table", part)
    if best[1] is None:
        return None
    return {"approach_m": round(best[0], 4), "short_m": round(d - best[0], 4), "what": best[1], "part": best[2]}


def entry_along_approach(q_tcp, hull, approach_m: float) -> np.ndarray:
    """(N,) the approach distance (0..approach_m from the pre-grasp) at which each point
    first lies in a convex hull (trimesh, TCP frame) moving with the TCP; inf if never.
    q_tcp: the points in the TCP frame at the grasp pose, where the hull has come
    approach_m - s short at approach s, so a point sits at q + (approach_m - s) z. Each
    face plane n.x <= offset bounds s on one side, so the answer is exact per point."""
    q, d = np.asarray(q_tcp, float).reshape(-1, 3), float(approach_m)
    n = hull.face_normals
    offset = np.einsum("ij,ij->i", n, hull.vertices[hull.faces[:, 0]])
    lhs = q @ n.T + d * n[:, 2] - offset  # n.(q + d z) - offset - s n_z <= 0
    nz = np.broadcast_to(n[:, 2], lhs.shape)
    flat = np.abs(nz) < 1e-12
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = lhs / np.where(flat, 1.0, nz)
    lo = np.max(np.where(nz > 0, bound, -np.inf), axis=1, initial=-np.inf)
    hi = np.min(np.where(nz < 0, bound, np.inf), axis=1, initial=np.inf)
    ok = np.all(~flat | (lhs <= 1e-12), axis=1) & (lo <= hi) & (hi >= 0) & (lo <= d)
    return np.where(ok, np.maximum(lo, 0.0), np.inf)


def first_contact_hulls(X_grasp, approach_m: float, hulls: dict, object_points: dict) -> dict | None:
    """first_contact with the hand's true convex hulls ({part: trimesh in the TCP frame},
    e.g. physics.panda_hand.open_hand_hulls_tcp()) instead of its boxes, objects only:
    {approach_m, short_m, what, part, point_tcp_m: the surface point met, in the TCP
    frame at the grasp pose}, or None when the approach reaches the grasp pose clear."""
    X = np.asarray(X_grasp, float)
    best = None
    for name, points in object_points.items():
        q = (np.asarray(points, float) - X[:3, 3]) @ X[:3, :3]
        for part, hull in hulls.items():
            s = entry_along_approach(q, hull, approach_m)
            i = int(np.argmin(s))
            if np.isfinite(s[i]) and (best is None or s[i] < best["approach_m"]):
                best = {"approach_m": float(s[i]), "what": name, "part": part, "point_tcp_m": q[i]}
    if best is None:
        return None
    return {**best, "approach_m": round(best["approach_m"], 4), "short_m": round(approach_m - best["approach_m"], 4),
            "point_tcp_m": np.round(best["point_tcp_m"], 4).tolist()}


def same_pick(X_a, X_b, max_distance_m: float = SAME_PICK_M, max_angle_deg: float = SAME_PICK_DEG) -> bool:
    """Whether two grasps are the same pick: TCPs within max_distance_m and orientations
    within max_angle_deg, either of a parallel hand's two symmetric orientations."""
    A, B = np.asarray(X_a, float), np.asarray(X_b, float)
    if np.linalg.norm(A[:3, 3] - B[:3, 3]) > max_distance_m:
        return False
    flip = np.diag([-1.0, -1.0, 1.0])  # a half turn about the approach
    for Rb in (B[:3, :3], B[:3, :3] @ flip):
        cos = (np.trace(A[:3, :3].T @ Rb) - 1) / 2
        if np.degrees(np.arccos(np.clip(cos, -1, 1))) <= max_angle_deg:
            return True
    return False


def diagnose_pick(view: View, X_grasp, approach_m: float, hand, object_points: dict, table_z_m: float,
                  mask=None) -> dict:
    """Where the pick sat in its view and what its approach meets (module doc). `mask`:
    vgn_mask(view.grid), when the caller diagnoses several picks of one view."""
    X = np.asarray(X_grasp, float)
    tcp = X[:3, 3]
    (ijk,), (ok,) = view.voxels_of(tcp)
    return {"tcp_class": str(surface_class(view, tcp)[0]),
            "tcp_grid": round(float(view.grid[tuple(ijk)]), 3) if ok else None,
            "surface_distance_mm": round(1000 * surface_distance_m(view, tcp), 1),
            "vgn_keeps": vgn_keeps(view, tcp, mask),
            "vgn_keeps_base": vgn_keeps(view, tcp + FINGER_BASE_Z_M * X[:3, 2], mask),
            "closing_region": closing_region_classes(view, X),
            "first_contact": first_contact(X, approach_m, hand, object_points, table_z_m)}
