"""Symmetries of an object: labels that need no simulation.

If a rotation S about the object's centre of mass maps its surface onto itself
(a can about its axis, a box by half turns), the hand at S X_object_tcp meets
the same surface, with the same mass distribution, as at X_object_tcp: the grasp
holds or fails alike and its six disturbance-rejection scores, which live in the
TCP frame, are the same.  So every simulated grasp of a symmetric object gives
one grasp per symmetry for free; the scene stage places all of them
(`scene_dataset`), and `symmetry_study` checks the claim by simulating copies.

Mirror symmetries count too.  A reflection S (through a plane through the centre
of mass) maps a mirror-symmetric object onto itself but turns a right hand into a
left one; the 2F-85 is itself mirror-symmetric about the TCP's y-z plane (the
plane of both finger linkages; its collision geometry to 0.02 mm, open and
closed: tests/sim_bridge/test_hand_model.py), so the hand at S X_object_tcp M,
with M = HAND_MIRROR_TCP (x -> -x), is a proper pose that occupies the mirror
image of the original hand.  Physics is mirror-invariant, so that grasp holds
alike, with its +x and -x scores exchanged (`copy_scores`).

Candidate rotations are k/n turns (n = 2, 3, 4, 6, 12, 24) about the object's
principal inertia axes, its oriented-bounding-box axes (square-section boxes have
no unique inertia axes; skipped for hulls of > 1000 faces) and frame axes;
candidate reflections are through the planes through the centre of mass normal to
the same axes; then products of accepted ones.  A candidate is accepted only if
surface points moved by it stay on the surface: 99 % within `tol_m` and all within
3 `tol_m` (so a tessellated can passes a 30 degree turn, a mug with a handle does
not).  The result is a finite group, identity first, capped at MAX_ROTATIONS rotations and
`max_elements` elements in all.
"""

import pathlib

import numpy as np
import open3d as o3d
import trimesh
from gravgrasp_detector import atomic_files

TOL_M = 0.001
TURNS = (2, 3, 4, 6, 12, 24)  # 24: 15 degree steps move a point 3 cm off the axis by a voxel (7.8 mm)
MAX_ROTATIONS = 48
MAX_ELEMENTS = 96  # rotations and reflections
N_POINTS = 1500
# The hand's own mirror symmetry, in the TCP frame: x -> -x (z approach, y closing).
HAND_MIRROR_TCP = np.diag([-1.0, 1.0, 1.0, 1.0])
# Scores of a mirrored copy: its +x is the original's -x (disturbance_rejection.DIRECTION_NAMES
# order +x, -x, +y, -y, +z, -z).
MIRRORED_SCORE_ORDER = np.array([1, 0, 2, 3, 4, 5])


def _about(axis, angle, centre):
    X = np.eye(4)
    X[:3, :3] = trimesh.transformations.rotation_matrix(angle, axis)[:3, :3]
    X[:3, 3] = centre - X[:3, :3] @ centre
    return X


def _through(normal, centre):
    X = np.eye(4)
    X[:3, :3] = np.eye(3) - 2 * np.outer(normal, normal)
    X[:3, 3] = centre - X[:3, :3] @ centre
    return X


def is_mirror(transforms):
    """(S,) bool: which rigid motions are reflections (determinant -1)."""
    return np.linalg.det(np.asarray(transforms, float).reshape(-1, 4, 4)[:, :3, :3]) < 0


def _candidate_axes(mesh):
    axes = list(np.asarray(mesh.principal_inertia_vectors, float))
    if len(mesh.convex_hull.faces) <= 1000:  # OBB search is slow on round hulls; they have inertia axes
        axes += list(np.asarray(mesh.bounding_box_oriented.primitive.transform, float)[:3, :3].T)
    axes += list(np.eye(3))
    out = []
    for a in axes:
        a = a / np.linalg.norm(a)
        if all(abs(a @ b) < 0.999 for b in out):
            out.append(a)
    return out


class _SurfaceCheck:
    """Does a rigid motion keep the mesh surface on itself?"""

    def __init__(self, mesh, tol_m, n_points, seed):
        self.points, _ = trimesh.sample.sample_surface(mesh, n_points, seed=seed)
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)),
                                 o3d.core.Tensor(np.asarray(mesh.faces, np.uint32)))
        self.tol_m = tol_m

    def keeps(self, X):
        moved = self.points @ X[:3, :3].T + X[:3, 3]
        d = self.scene.compute_distance(o3d.core.Tensor(moved.astype(np.float32))).numpy()
        return bool(np.quantile(d, 0.99) <= self.tol_m and d.max() <= 3 * self.tol_m)


def _same(A, B):
    return np.abs(A - B).max() < 1e-6


def symmetry_transforms(mesh, com_m, tol_m=TOL_M, max_elements=MAX_ELEMENTS, n_points=N_POINTS, seed=0,
                        mirrors=True):
    """(S, 4, 4) object-frame isometries about `com_m` that map `mesh` onto itself, the
    identity first, rotations before reflections (S = 1: no symmetry found); with
    `mirrors=False` rotations only.  Deterministic for a given seed."""
    mesh = mesh if isinstance(mesh, trimesh.Trimesh) else trimesh.util.concatenate(mesh)
    com = np.asarray(com_m, float)
    check = _SurfaceCheck(mesh, tol_m, n_points, seed)
    group = [np.eye(4)]
    cap = min(MAX_ROTATIONS, max_elements)

    def add(X):
        if len(group) < cap and not any(_same(X, G) for G in group) and check.keeps(X):
            group.append(X)
            return True
        return False

    def close():  # under products (a can: turns about its axis times the end-over-end half turn)
        grew = True
        while grew and len(group) < cap:
            grew = False
            for A in list(group):
                for B in list(group):
                    if add(A @ B):
                        grew = True

    axes = _candidate_axes(mesh)
    for axis in axes:
        for n in TURNS:
            # a k/n turn passes only if the 1/n turn does (its powers are in the group)
            if add(_about(axis, 2 * np.pi / n, com)):
                for k in range(2, n):
                    add(_about(axis, 2 * np.pi * k / n, com))
    close()
    if mirrors:
        cap = max_elements
        for axis in axes:
            add(_through(axis, com))
        close()
        group = [group[i] for i in np.argsort(is_mirror(group), kind="stable")]  # rotations first
    return np.asarray(group)


def replicate(X_object_tcp, transforms):
    """(S*N, 4, 4) grasp poses S_s X_object_tcp_i (s-major; S_s X_object_tcp_i M for a
    reflection S_s, M = HAND_MIRROR_TCP, so every copy is a proper pose) and (S*N,)
    index i of the source grasp."""
    X = np.asarray(X_object_tcp, float).reshape(-1, 4, 4)
    T = np.asarray(transforms, float).reshape(-1, 4, 4)
    out = np.einsum("sij,njk->snik", T, X)
    out[is_mirror(T)] = out[is_mirror(T)] @ HAND_MIRROR_TCP
    return out.reshape(-1, 4, 4), np.tile(np.arange(len(X)), len(T))


def copy_scores(scores_n, mirrored):
    """Six disturbance-rejection scores (N, 6) of copies, the rows where `mirrored` is
    true moved by a reflection: their +x and -x exchange."""
    scores_n = np.array(scores_n, copy=True)
    mirrored = np.asarray(mirrored, bool)
    scores_n[mirrored] = scores_n[mirrored][:, MIRRORED_SCORE_ORDER]
    return scores_n


def cached_symmetry_transforms(cache_dir, name, shape_sha256, mesh, com_m, tol_m=TOL_M):
    """symmetry_transforms (reflections included, after the rotations: drop them with
    `T[~is_mirror(T)]`, which keeps the rotations' indices), kept in
    `<cache_dir>/<name>.npz` next to the grasp tables (recomputed when the object's
    shape fingerprint, the tolerance or the group's cap changed, or the file predates
    reflections)."""
    path = pathlib.Path(cache_dir) / f"{name}.npz"
    if path.exists():
        with np.load(path) as z:
            if (str(z["shape_sha256"]) == shape_sha256 and float(z["tol_m"]) == tol_m
                    and "max_elements" in z and int(z["max_elements"]) == MAX_ELEMENTS):
                return z["transforms"]
    T = symmetry_transforms(mesh, com_m, tol_m)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_files.save_npz(path, transforms=T, shape_sha256=np.asarray(shape_sha256), tol_m=np.asarray(tol_m),
                          max_elements=np.asarray(MAX_ELEMENTS))
    return T
