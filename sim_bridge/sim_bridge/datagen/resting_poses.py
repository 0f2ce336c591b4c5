"""Resting poses of an object on a table: where its grasps will be used.

A grasp is only worth simulating if the robot can reach it when the object lies
on a table, so candidates are sampled per resting pose (antipodal_sampling) and
scenes place objects in these poses (scenes.packed_poses).

1. `trimesh.poses.compute_stable_poses` on the collision hull with the object's
   own centre of mass: the hull faces the COM projects into, each with the
   quasi-static probability that a random drop ends on it.
2. Each candidate is confirmed by a short Drake settle on the table (the scene
   model of `scenes`): an object that tips or rolls away gives the pose's
   probability to the pose it came to rest in (matched by its up direction in the
   object frame, or kept as a new pose).
3. Poses below `min_probability` are dropped and the rest renormalised.

Pose convention: X_table_object places the object with its lowest point on the
table plane z = 0 and its centre of mass above the origin (yaw is arbitrary: a
scene draws it).
"""

from dataclasses import dataclass

import numpy as np
import trimesh

from ..physics.scenes import TABLE_HEIGHT_M, VOLUME_SIZE_M, SceneSettings, build_scene_diagram, settle

MATCH_ANGLE_DEG = 10.0  # two poses with up directions this close are the same pose (a round
                        # object rolls a few degrees while it settles)


@dataclass(frozen=True)
class RestingPoses:
    X_table_object: np.ndarray   # (P, 4, 4)
    probability: np.ndarray      # (P,) sums to 1
    confirmed: np.ndarray        # (P,) bool: a Drake settle ended in this pose

    def __len__(self):
        return len(self.probability)

    def up_object(self):
        """(P, 3) the table's up direction in the object frame, per pose."""
        return self.X_table_object[:, 2, :3].copy()

    def sample(self, rng, count):
        """Indices of `count` poses drawn by probability."""
        return rng.choice(len(self), size=count, p=self.probability)


def _normalised(X, com_m, mesh):
    """Pose with the COM above the origin and the lowest hull point on z = 0."""
    X = np.array(X, float)
    v = mesh.vertices @ X[:3, :3].T
    com = X[:3, :3] @ com_m
    X[:3, 3] = [-com[0], -com[1], -v[:, 2].min()]
    return X


def _tilt_only(R_settled, R_ref):
    """The settled rotation's up direction with the reference's yaw: drops the spin
    a settle adds about the vertical."""
    up = R_settled[2]                      # table z in the object frame
    x_ref = R_ref[0] - (R_ref[0] @ up) * up
    if np.linalg.norm(x_ref) < 1e-6:
        x_ref = R_ref[1] - (R_ref[1] @ up) * up
    x_ref /= np.linalg.norm(x_ref)
    R = np.stack([x_ref, np.cross(up, x_ref), up])
    return R


def _signature(X, hull):
    """Heights and distances from the vertical COM axis of the posed hull's vertices,
    sorted: equal for poses that differ only by a symmetry of the shape and a yaw."""
    v = hull.vertices @ X[:3, :3].T + X[:3, 3]
    return np.sort(v[:, 2]), np.sort(np.linalg.norm(v[:, :2], axis=1))


def stable_pose_prior(spec, max_poses=64, tolerance_m=1e-3):
    """(X (P,4,4), probability (P,)) from the convex hull, most probable first.
    Poses congruent up to yaw (a cylinder's side facets) are merged into one."""
    hull = spec.collision_mesh().convex_hull
    com = np.asarray(spec.com_m, float)
    X, p = trimesh.poses.compute_stable_poses(hull, center_mass=com)
    X = [_normalised(x, com, hull) for x in np.asarray(X, float)]
    merged, probs, sigs = [], [], []
    for x, pi in sorted(zip(X, np.asarray(p, float)), key=lambda t: -t[1]):
        z, r = _signature(x, hull)
        for k, (zk, rk) in enumerate(sigs):
            if np.abs(z - zk).max() < tolerance_m and np.abs(r - rk).max() < tolerance_m:
                probs[k] += pi
                break
        else:
            merged.append(x)
            probs.append(pi)
            sigs.append((z, r))
    order = np.argsort(-np.array(probs), kind="stable")[:max_poses]
    p = np.array(probs)[order]
    return np.array(merged)[order], p / p.sum()


def find_resting_poses(spec, min_probability=0.01, max_poses=64, confirm=True, settle_time_s=1.5):
    """RestingPoses of an ObjectSpec (see the module docstring)."""
    hull = spec.collision_mesh().convex_hull
    com = np.asarray(spec.com_m, float)
    X, p = stable_pose_prior(spec, max_poses)
    keep = p >= min_probability
    X, p = X[keep], p[keep]
    if not confirm:
        return RestingPoses(X, p / p.sum(), np.zeros(len(p), bool))
    settings = SceneSettings(max_settle_time_s=settle_time_s)
    scene = build_scene_diagram([spec], settings)
    offset = np.eye(4)
    offset[:3, 3] = [VOLUME_SIZE_M / 2, VOLUME_SIZE_M / 2, TABLE_HEIGHT_M + 0.001]
    poses, probs, confirmed = list(X), list(p), [False] * len(p)
    cos_match = np.cos(np.deg2rad(MATCH_ANGLE_DEG))
    moved = np.zeros(len(X), bool)
    ends = []
    for i in range(len(X)):
        (X_end,), _ = settle(scene, [offset @ X[i]], settings)
        up_end = X_end[2, :3]
        ups = np.array([q[2, :3] for q in poses])
        j = int(np.argmax(ups @ up_end))
        if ups[j] @ up_end < cos_match:
            # came to rest in a pose the prior did not list
            R = _tilt_only(X_end[:3, :3], X[i][:3, :3])
            Xn = np.eye(4)
            Xn[:3, :3] = R
            poses.append(_normalised(Xn, com, hull))
            probs.append(0.0)
            confirmed.append(False)
            j = len(poses) - 1
        ends.append(j)
        moved[i] = j != i
    for i, j in enumerate(ends):
        confirmed[j] = True
        if moved[i]:
            probs[j] += probs[i]
            probs[i] = 0.0
    poses, probs, confirmed = np.array(poses), np.array(probs), np.array(confirmed)
    keep = (probs >= min_probability) & confirmed
    if not keep.any():   # nothing stayed put (e.g. a ball): keep the most probable end
        keep = probs == probs.max()
    order = np.flatnonzero(keep)[np.argsort(-probs[keep], kind="stable")]
    return RestingPoses(poses[order], probs[order] / probs[order].sum(), confirmed[order])
