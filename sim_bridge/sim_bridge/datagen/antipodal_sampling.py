"""Antipodal grasp candidates for the Robotiq 2F-85 on an object mesh.

1. Sample surface points p (area-uniform) and a closing direction u inside the
   friction cone around the inward normal at p (half-angle atan(mu), mu = 0.75).
2. Find where the fingers would touch along the closing line: cast rays from
   outside toward the object from both sides (starting `stroke` away), so the
   internal faces of convex-decomposed meshes are never hit.  The pair (a, b)
   is antipodal when u lies in both friction cones and |b - a| fits the stroke.
3. TCP pose: origin at the midpoint (the pinch point), y = u (closing axis), the
   approach z at a random angle about y, x = y x z.
4. Perturb so power-grasp candidates arise: insert deeper along the approach
   (half of the candidates to the deepest depth at which the open hand still
   clears the object, the rest uniform), shift sideways and tilt a little.
   Candidates whose open hand (or its approach) intersects the object are dropped.

`sample_grasp_candidates_at_rest` samples where the grasp will be used: each
candidate belongs to a resting pose of the object on a table (drawn by its
probability, `resting_poses`), its approach is drawn inside the executor's cone
around straight down (rotating about the closing axis; a closing axis too close
to vertical has no such approach and is skipped), and the open hand with its
approach must also clear the table in that pose.  `sample_grasp_candidates`
(approach at any angle about the closing axis, no table) is the unconditioned
sampler, kept for comparison (`bench_datagen`).

Everything is deterministic for a seed.
"""

from dataclasses import dataclass

import numpy as np
import open3d as o3d
import trimesh

from ..physics import hand_collision

FRICTION_COEFFICIENT = 0.75
MAX_WIDTH_M = 0.085          # 2F-85 stroke


@dataclass(frozen=True)
class SamplingSettings:
    mu: float = FRICTION_COEFFICIENT
    max_width_m: float = MAX_WIDTH_M
    width_margin_m: float = 0.005      # keep the pads clear of the surface when open
    deep_fraction: float = 0.5         # share of candidates pushed to the deepest free depth
    min_depth_m: float = 0.0           # the others: uniform in [min(min_depth_m, deepest), deepest]
    depth_step_m: float = 0.004        # resolution of the deepest-free-depth search
    lateral_sigma_m: float = 0.004     # sideways shift (x, y of the TCP frame)
    tilt_sigma_rad: float = np.deg2rad(8.0)
    approach_m: float = 0.05           # straight approach checked for collisions
    clearance_m: float = 0.002         # open hand at least this far from the sampled surface
    max_rounds: int = 40
    sampler: str = "free"              # "free" (any approach) | "resting" (per resting pose, table, cone)
    rest_min_probability: float = 0.01 # resting poses rarer than this are not sampled
    approach_cone_deg: float = 80.0    # at rest: approach within this of straight down (executor's cone)
    table_clearance_m: float = 0.002   # at rest: open hand at least this far above the table
    # at rest: the pad tips, closed to where they will stop on the object, above the table
    # too (closing reaches up to 13.5 mm past the open hand; a pad that closes onto the
    # table presses into it and blocks the lift). Tables grown before it existed lack it.
    closed_tips_above_table: bool = True


def _rotation_about(axis, angle):
    axis = axis / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def _orthonormal_basis(u):
    """Two unit vectors orthogonal to unit u (and to each other)."""
    helper = np.where(np.abs(u[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    a = np.cross(u, helper)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    return a, np.cross(u, a)


class _RayCaster:
    def __init__(self, mesh):
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(
            o3d.core.Tensor(np.asarray(mesh.vertices, dtype=np.float32)),
            o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.uint32)))

    def cast(self, origins, directions):
        rays = o3d.core.Tensor(np.hstack([origins, directions]).astype(np.float32))
        ans = self.scene.cast_rays(rays)
        t = ans["t_hit"].numpy().astype(float)
        n = ans["primitive_normals"].numpy().astype(float)
        return t, n


def antipodal_pairs(mesh, count, rng, settings=SamplingSettings()):
    """Up to `count` antipodal contact pairs: (a, b, u) arrays, u = (b - a)/|b - a|."""
    caster = _RayCaster(mesh)  # built per call: open3d scenes do not pickle
    cone = np.arctan(settings.mu)
    pts, faces = trimesh.sample.sample_surface(mesh, count, seed=int(rng.integers(2**31)))
    normals = mesh.face_normals[faces]
    # closing direction inside the friction cone around the inward normal;
    # sqrt keeps the directions uniform over the cone's solid angle.
    theta = cone * np.sqrt(rng.uniform(0, 1, count)) * 0.95
    phi = rng.uniform(0, 2 * np.pi, count)
    e1, e2 = _orthonormal_basis(-normals)
    u = (np.cos(theta)[:, None] * -normals
         + np.sin(theta)[:, None] * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2))
    reach = settings.max_width_m + 0.02
    # finger on the p side comes along +u, the other along -u
    t_a, n_a = caster.cast(pts - reach * u, u)
    t_b, n_b = caster.cast(pts + reach * u, -u)
    a = pts - reach * u + t_a[:, None] * u
    b = pts + reach * u - t_b[:, None] * u
    width = np.einsum("ij,ij->i", b - a, u)
    ok = np.isfinite(t_a) & np.isfinite(t_b)
    # a ray must meet an outward-facing surface: otherwise it started inside,
    # i.e. the object is wider than the stroke along this line.
    ok &= (np.einsum("ij,ij->i", n_a, u) < 0) & (np.einsum("ij,ij->i", n_b, u) > 0)
    ok &= (width > 0.002) & (width <= settings.max_width_m - settings.width_margin_m)
    cos_cone = np.cos(cone)
    ok &= (np.einsum("ij,ij->i", -n_a, u) >= cos_cone) & (np.einsum("ij,ij->i", n_b, u) >= cos_cone)
    return a[ok], b[ok], u[ok]


def _poses(center, y_axis, z_axis):
    X = np.tile(np.eye(4), (len(center), 1, 1))
    X[:, :3, 0] = np.cross(y_axis, z_axis)
    X[:, :3, 1] = y_axis
    X[:, :3, 2] = z_axis
    X[:, :3, 3] = center
    return X


def _approach_in_cone(u, down, cone_rad, rng):
    """Approach directions z perpendicular to the closing axes u (both (n,3), object
    frame) and within cone_rad of `down`, drawn uniformly in the angle about u that
    the cone allows.  Returns (z, ok); ok is False where no such z exists."""
    d_perp = down - np.einsum("ij,ij->i", down, u)[:, None] * u
    n = np.linalg.norm(d_perp, axis=1)
    ok = n > np.cos(cone_rad) + 1e-9   # the nearest perpendicular approach is inside the cone
    z_star = d_perp / np.maximum(n, 1e-12)[:, None]
    # z(delta) = cos(delta) z* + sin(delta) (u x z*); angle to down: cos = cos(delta) |d_perp|
    delta_max = np.arccos(np.clip(np.cos(cone_rad) / np.maximum(n, 1e-12), -1.0, 1.0))
    delta = rng.uniform(-1, 1, len(u)) * delta_max
    z = np.cos(delta)[:, None] * z_star + np.sin(delta)[:, None] * np.cross(u, z_star)
    return z, ok


def sample_grasp_candidates(mesh, count, seed, settings=SamplingSettings()):
    """(N <= count, 4, 4) candidate X_object_tcp for `mesh` (object frame, metres),
    approach at any angle about the closing axis (the unconditioned sampler).

    Returns fewer than `count` (possibly 0) when the object offers few grasps.
    """
    return _sample(mesh, count, seed, settings, None)[0]


def sample_grasp_candidates_at_rest(mesh, rest, count, seed, settings=SamplingSettings()):
    """Candidates for an object lying on a table in one of its resting poses.

    rest: resting_poses.RestingPoses of the object.  Returns (X_object_tcp (N, 4, 4),
    rest_index (N,) int: the pose each candidate was drawn for).  Each X, posed by
    rest.X_table_object[rest_index], approaches within settings.approach_cone_deg of
    straight down, and its open hand (with its approach) clears the object and the table.
    """
    return _sample(mesh, count, seed, settings, rest)


def _sample(mesh, count, seed, settings, rest):
    rng = np.random.default_rng(seed)
    obstacles = hand_collision.surface_points(mesh, seed=int(rng.integers(2**31)))
    depths = np.arange(0.0, -hand_collision.PALM_FACE_Z_M + 1e-9, settings.depth_step_m)
    cone = np.deg2rad(settings.approach_cone_deg)
    found, found_pose = [], []
    n_found = 0
    fruitless = 0
    if rest is not None:
        # each candidate slot goes to a resting pose drawn by its probability, so a
        # pose that offers few grasps does not hand its share to rarer poses
        quota = rng.multinomial(count, rest.probability)
    for _ in range(settings.max_rounds):
        if n_found >= count or fruitless >= 3:  # 3 rounds without a single pose: give up
            break
        if rest is not None and quota.sum() == 0:
            break
        fruitless += 1
        batch = max(64, 2 * (count - n_found))
        a, b, u = antipodal_pairs(mesh, batch * 4, rng, settings)
        if not len(a):
            continue
        pick = rng.permutation(len(a))[:batch]
        a, b, u = a[pick], b[pick], u[pick]
        if rest is None:
            # approach at a random angle about the closing axis
            e1, e2 = _orthonormal_basis(u)
            psi = rng.uniform(0, 2 * np.pi, len(u))[:, None]
            z = np.cos(psi) * e1 + np.sin(psi) * e2
            pose = np.full(len(u), -1)
        else:
            pose = rng.choice(len(quota), size=len(u), p=quota / quota.sum())
            z, ok = _approach_in_cone(u, -rest.up_object()[pose], cone, rng)
            a, b, u, z, pose = a[ok], b[ok], u[ok], z[ok], pose[ok]
            if not len(a):
                continue
        X = _poses((a + b) / 2, u, z)
        # deepest insertion at which the open hand (with its approach) is free
        free = ~hand_collision.collides_along_approach(X, obstacles, depths, approach_m=settings.approach_m,
                                                       margin_m=settings.clearance_m)
        closed_check = rest is not None and settings.closed_tips_above_table
        # where the pads will stop: the object's extent between them (else the contacts' distance)
        opening = (hand_collision.closing_opening_m(X, obstacles, np.linalg.norm(a - b, axis=1)) if closed_check
                   else np.zeros(len(X)))
        if rest is not None:
            X_rest = rest.X_table_object[pose] @ X
            low = hand_collision.lowest_point_z(X_rest, settings.approach_m, settings.table_clearance_m)
            if closed_check:
                low = np.minimum(low, hand_collision.closed_tips_lowest_z(X_rest, opening))
            free &= low[:, None] + depths[None, :] * X_rest[:, 2, 2][:, None] >= 0.0
        # contiguous free prefix: the hand cannot pass through a collision
        prefix = np.cumprod(free, axis=1).astype(bool)
        n_free = prefix.sum(axis=1)
        usable = n_free > 0
        X, n_free, pose, opening = X[usable], n_free[usable], pose[usable], opening[usable]
        if not len(X):
            continue
        deepest = depths[n_free - 1]
        deep = rng.uniform(0, 1, len(X)) < settings.deep_fraction
        shallowest = np.minimum(settings.min_depth_m, deepest)
        depth = np.where(deep, deepest, shallowest + rng.uniform(0, 1, len(X)) * (deepest - shallowest))
        X[:, :3, 3] += depth[:, None] * X[:, :3, 2]
        # sideways shift and small tilt about a random axis through the TCP
        shift = rng.normal(0, settings.lateral_sigma_m, (len(X), 2))
        X[:, :3, 3] += shift[:, :1] * X[:, :3, 0] + shift[:, 1:] * X[:, :3, 1]
        axes = rng.normal(size=(len(X), 3))
        angles = np.clip(rng.normal(0, settings.tilt_sigma_rad, len(X)),
                         -2.5 * settings.tilt_sigma_rad, 2.5 * settings.tilt_sigma_rad)
        for i in range(len(X)):
            X[i, :3, :3] = _rotation_about(axes[i], angles[i]) @ X[i, :3, :3]
        if closed_check:
            # the tilt may have lowered a pad tip below the table: back off along the approach
            X_rest = rest.X_table_object[pose] @ X
            below = np.maximum(0.0, -hand_collision.closed_tips_lowest_z(X_rest, opening))
            X[:, :3, 3] -= (below / np.maximum(-X_rest[:, 2, 2], 1e-6))[:, None] * X[:, :3, 2]
        ok = ~hand_collision.collides(X, obstacles, approach_m=settings.approach_m,
                                      margin_m=settings.clearance_m)
        if rest is not None:
            X_rest = rest.X_table_object[pose] @ X
            ok &= hand_collision.lowest_point_z(X_rest, settings.approach_m, settings.table_clearance_m) >= 0.0
            if closed_check:
                ok &= hand_collision.closed_tips_lowest_z(X_rest, opening) >= 0.0
            ok &= -X_rest[:, 2, 2] >= np.cos(cone)   # still inside the cone after the tilt
            # at most each pose's remaining quota, in sampling order
            rank = np.zeros(len(pose), int)
            for k in np.unique(pose[ok]):
                sel = np.flatnonzero(ok & (pose == k))
                rank[sel] = np.arange(len(sel))
            ok &= rank < quota[pose]
            quota = quota - np.bincount(pose[ok], minlength=len(quota))
        found.append(X[ok])
        found_pose.append(pose[ok])
        n_found += int(ok.sum())
        fruitless = 0 if ok.any() else fruitless
    if not found:
        return np.zeros((0, 4, 4)), np.zeros(0, int)
    return np.concatenate(found)[:count], np.concatenate(found_pose)[:count]
