"""Objects at rest away from the hand are frozen ("asleep"), so that a clutter round does
not pay full contact resolution for a table that nothing touches.

Where a round's CPU goes (sim_bridge/doc/benchmark-speed.md): every 1 ms SAP step solves
the contacts of every object with the table and with each other, whether the hand is near
them or not; with the hand at home over five resting objects a step costs as much as one
during the lift. An asleep object:

- keeps the pose it had when it fell asleep, with zero velocity (reset after every step,
  as the hand's stand-in is set before it);
- has its contacts with the table and with other asleep objects filtered out of the
  geometry queries (a transient SceneGraph collision filter), so SAP never sees them; its
  contacts with the hand and with awake objects stay, and it wakes before those begin.

An object falls asleep once it has been slower than SLEEP_SPEED_MPS (and
SLEEP_ANGULAR_RAD_S) for REST_BEFORE_SLEEP_S with its bounding box (of its hull, in the task
frame) more than SLEEP_GAP_M from the hand (a bounding sphere per hand geometry) and from
every moving object's box (faster than WAKE_SPEED_MPS or
WAKE_ANGULAR_RAD_S). It wakes as soon as one of those comes within WAKE_GAP_M (checked every CHECK_EVERY_STEPS steps: at the stand-in's 0.5 m/s cap
the hand moves 2.5 mm between checks). Waking restores the contacts it had, from exactly
the state it had, so a resting object behaves as if it had never slept. What this changes
in the benchmark's outcomes is measured, not assumed: `execution_settings_study`.

No locking here: SimWorld calls it under its lock.
"""

from __future__ import annotations

import numpy as np
from pydrake.geometry import Box, Capsule, CollisionFilterDeclaration, Convex, Cylinder, GeometrySet, Mesh, Sphere
from pydrake.multibody.math import SpatialVelocity

SLEEP_SPEED_MPS = 5e-3
SLEEP_ANGULAR_RAD_S = 0.1
# An awake object wakes its neighbours only when it moves faster than this: SAP's contact
# jitter of an object at rest (up to ~3 mm/s, 0.05 rad/s at 1.5 kg) must not.
WAKE_SPEED_MPS = 0.02
WAKE_ANGULAR_RAD_S = 0.3
REST_BEFORE_SLEEP_S = 0.1
WAKE_GAP_M = 0.02
SLEEP_GAP_M = 0.04
CHECK_EVERY_STEPS = 5


def _bounding_sphere(points) -> tuple:
    """(centre [3], radius) of the points' bounding box, in their frame."""
    p = np.asarray(points, float).reshape(-1, 3)
    c = (p.min(axis=0) + p.max(axis=0)) / 2
    return c, float(np.linalg.norm(p - c, axis=1).max())


def _shape_points(shape) -> np.ndarray:
    """Points whose bounding sphere encloses the shape (its own frame)."""
    if isinstance(shape, Box):
        return np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * shape.size() / 2
    if isinstance(shape, Sphere):
        return np.array([[-1, 0, 0], [1, 0, 0]]) * shape.radius()
    if isinstance(shape, (Cylinder, Capsule)):
        r, h = shape.radius(), shape.length() / 2 + (shape.radius() if isinstance(shape, Capsule) else 0.0)
        return np.array([[x, y, z] for x in (-r, r) for y in (-r, r) for z in (-h, h)])
    if isinstance(shape, (Convex, Mesh)):
        hull = shape.GetConvexHull()
        return np.array([hull.vertex(i) for i in range(hull.num_vertices())], float).reshape(-1, 3)
    raise TypeError(f"resting_objects: no bound for a {type(shape).__name__} collision shape")


class RestingObjects:
    """Sleep and wake of one world diagram's objects (`diagram.WorldDiagram`). `names` and
    `hull_vertices` ({name: vertices in the object frame}) as SimWorld holds them."""

    def __init__(self, model, scene_graph_context, names, hull_vertices):
        self._model = model
        plant = model.plant
        inspector = model.scene_graph.model_inspector()
        # The hand: a bounding sphere per collision geometry, in its body's frame.
        self._hand = []
        for bi in plant.GetBodyIndices(model.hand.model_instance):
            body = plant.get_body(bi)
            for gid in plant.GetCollisionGeometriesForBody(body):
                X_BG = inspector.GetPoseInFrame(gid).GetAsMatrix4()
                c, r = _bounding_sphere(_shape_points(inspector.GetShape(gid)))
                self._hand.append((body, X_BG[:3, :3] @ c + X_BG[:3, 3], r))
        self._hand_radii = np.array([r for _, _, r in self._hand])
        self._objects = []  # (name, body, hull vertices in the body frame, collision GeometryIds)
        for name, body in zip(names, model.object_bodies):
            self._objects.append((name, body, np.asarray(hull_vertices[name], float),
                                  list(plant.GetCollisionGeometriesForBody(body))))
        self._world_geometries = list(plant.GetCollisionGeometriesForBody(plant.world_body()))
        self._filters = model.scene_graph.collision_filter_manager(scene_graph_context)
        self._filter_id = None
        self._asleep = {}  # index -> RigidTransform it is frozen at
        self._resting_since = {}  # index -> sim time it was first seen at rest
        self._steps = 0

    def asleep(self) -> list:
        """Names of the objects asleep now."""
        return [self._objects[i][0] for i in sorted(self._asleep)]

    def after_step(self, plant_context, time_s: float) -> None:
        """After every time step: re-freeze the asleep; every few steps, wake and sleep."""
        self._freeze(plant_context)
        self._steps += 1
        if self._steps % CHECK_EVERY_STEPS == 0 and self._update(plant_context, time_s):
            self._apply_filter()
            self._freeze(plant_context)

    def moved(self, plant_context, name: str) -> None:
        """An object was put somewhere by hand (removed: out_of_play): if asleep, it stays
        asleep where it is now."""
        for i, (n, body, *_rest) in enumerate(self._objects):
            if n == name and i in self._asleep:
                self._asleep[i] = self._model.plant.EvalBodyPoseInWorld(plant_context, body)

    def wake_all(self) -> None:
        if self._asleep:
            self._asleep.clear()
            self._apply_filter()

    def saved(self) -> tuple:
        """What asleep, since when and under which filter: with a copy of the Drake context
        (which holds the filter itself, in SceneGraph's state), enough to `restore` to."""
        return dict(self._asleep), dict(self._resting_since), self._steps, self._filter_id

    def restore(self, saved: tuple, scene_graph_context) -> None:
        """Back to `saved`; the caller has put the context saved with it back first. The
        filter manager is taken anew: the copy replaced the geometry state it pointed into."""
        self._filters = self._model.scene_graph.collision_filter_manager(scene_graph_context)
        asleep, since, self._steps, self._filter_id = saved
        self._asleep, self._resting_since = dict(asleep), dict(since)

    # -- sleep and wake ---------------------------------------------------------------

    def _update(self, plant_context, time_s) -> bool:
        """Wake the asleep that something comes near, put to sleep the long at rest;
        True if any changed."""
        plant = self._model.plant
        hand = self._hand_spheres(plant_context)
        boxes, movers = [], []
        for i, (_, body, vertices, _) in enumerate(self._objects):
            X = plant.EvalBodyPoseInWorld(plant_context, body).GetAsMatrix4()
            p = vertices @ X[:3, :3].T + X[:3, 3]
            boxes.append((p.min(axis=0), p.max(axis=0)))
            if i in self._asleep:
                continue
            V = plant.EvalBodySpatialVelocityInWorld(plant_context, body)
            v, w = np.linalg.norm(V.translational()), np.linalg.norm(V.rotational())
            if v < SLEEP_SPEED_MPS and w < SLEEP_ANGULAR_RAD_S:
                self._resting_since.setdefault(i, time_s)
            else:
                self._resting_since.pop(i, None)
            if v > WAKE_SPEED_MPS or w > WAKE_ANGULAR_RAD_S:
                movers.append(i)

        def gap(i):  # to the hand and to every moving object
            lo, hi = boxes[i]
            to_hand = _sphere_box_gap(hand, lo, hi)
            return min([to_hand, *(_gap(lo, hi, *boxes[j]) for j in movers if j != i)])

        changed = False
        for i in list(self._asleep):
            if gap(i) < WAKE_GAP_M:
                del self._asleep[i]
                self._resting_since.pop(i, None)
                changed = True
        for i, since in list(self._resting_since.items()):
            if i not in self._asleep and time_s - since >= REST_BEFORE_SLEEP_S and gap(i) > SLEEP_GAP_M:
                self._asleep[i] = plant.EvalBodyPoseInWorld(plant_context, self._objects[i][1])
                changed = True
        return changed

    def _freeze(self, plant_context):
        plant = self._model.plant
        zero = SpatialVelocity(np.zeros(3), np.zeros(3))
        for i, X in self._asleep.items():
            body = self._objects[i][1]
            plant.SetFreeBodyPose(plant_context, body, X)
            plant.SetFreeBodySpatialVelocity(plant_context, body, zero)

    def _hand_spheres(self, plant_context) -> tuple:
        """(centres [N, 3], radii [N]) of the hand's geometry bounds, task frame."""
        plant = self._model.plant
        poses, centres = {}, []
        for body, c, _ in self._hand:
            X = poses.get(body.index())
            if X is None:
                X = poses[body.index()] = plant.EvalBodyPoseInWorld(plant_context, body)
            centres.append(X.multiply(c))
        return np.array(centres), self._hand_radii

    def _apply_filter(self):
        """One transient filter: no contact within {asleep objects, table}."""
        if self._filter_id is not None:
            self._filters.RemoveDeclaration(self._filter_id)
            self._filter_id = None
        if self._asleep:
            ids = list(self._world_geometries)
            for i in self._asleep:
                ids += self._objects[i][3]
            self._filter_id = self._filters.ApplyTransient(
                CollisionFilterDeclaration().ExcludeWithin(GeometrySet(ids)))


def _sphere_box_gap(spheres, lo, hi) -> float:
    """Smallest distance from any of the spheres ((centres, radii)) to a box (0: touching)."""
    centres, radii = spheres
    nearest = np.clip(centres, lo, hi)
    return float(max(0.0, (np.linalg.norm(centres - nearest, axis=1) - radii).min()))


def _gap(lo_a, hi_a, lo_b, hi_b) -> float:
    """Distance between two axis-aligned boxes (0 when they overlap)."""
    d = np.maximum(0.0, np.maximum(lo_a - hi_b, lo_b - hi_a))
    return float(np.linalg.norm(d))
