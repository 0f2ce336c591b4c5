"""Objects out of play: taken off the table after a successful grasp (`SimWorld.remove_object`),
or gone past the table (fallen over its edge, or thrown away). Such an object is taken out
of the physics: it is put far out of the camera's view, its contacts with everything are
filtered out of the geometry queries (a transient SceneGraph collision filter), and it is
held there at rest (its pose and zero velocity set again after every step, as the hand's
stand-in is set before it).

Why not leave it to Drake (sim_bridge/doc/simulation-failures.md):

- Nothing is under the 1 m table, so an object that rolled off it fell for the rest of the
  round. In free fall a tumbling thin body (a capsule, a thin cylinder) spins up: the
  discrete step adds energy to its rotation, slowly at first (1 %/s at 23 rad/s), and
  once it turns about a radian per step the pose goes non-finite ("SceneGraph encountered
  a non-finite value"), 36 s into procedural_v4's round ours 1.5 kg pile_006.
- Removed objects used to be dropped from 0.2 m onto a parking shelf. SAP throws a light
  box that lands flat on a flat face at 1.8 m/s back up faster than it came and spinning
  (a 0.1 kg box from 0.17 m: 20 m/s, 250 rad/s), and the spin then grows in flight until
  the pose goes non-finite, as in round binary 0.1 kg packed_003.

No locking here: SimWorld calls it under its lock.
"""

from __future__ import annotations

import numpy as np
from pydrake.geometry import CollisionFilterDeclaration, GeometrySet, Role
from pydrake.math import RigidTransform
from pydrake.multibody.math import SpatialVelocity

from ..physics.scenes import TABLE_HEIGHT_M, VOLUME_SIZE_M

# Where objects out of play are held: far out of the camera's view (its depth range is
# 3 m). Their contacts are filtered, so they may share the place.
PARKING_M = (5.0, 5.0, -5.0)
TABLE_UNDERSIDE_M = TABLE_HEIGHT_M - 0.05  # the table is 5 cm thick (diagram)
# An object farther than this from the table's centre has been thrown away: no object in
# play (on the table, or in the hand within the stand-in's reach) comes near it.
THROWN_BEYOND_M = 2.0
CHECK_EVERY_STEPS = 10  # a falling object moves at most ~3 cm between checks in its first second


class OutOfPlay:
    """Which objects of one world diagram (`diagram.WorldDiagram`) are out of play, and
    holding them. `names` and `hull_vertices` ({name: vertices in the object frame}) as
    SimWorld holds them."""

    def __init__(self, model, scene_graph_context, names, hull_vertices):
        self._model = model
        plant = model.plant
        self._bodies = dict(zip(names, model.object_bodies))
        # Bounding radius of each object about its body origin: an object is entirely below
        # a plane once its origin is that far below it.
        self._radius_m = {n: float(np.linalg.norm(np.asarray(hull_vertices[n], float), axis=1).max())
                          for n in names}
        self._geometries = {n: list(plant.GetCollisionGeometriesForBody(b)) for n, b in self._bodies.items()}
        self._all_geometries = list(model.scene_graph.model_inspector().GetAllGeometryIds(Role.kProximity))
        self._filters = model.scene_graph.collision_filter_manager(scene_graph_context)
        self._filter_id = None
        self._out = {}  # name -> why: "removed" or "fell"
        self._steps = 0

    def out(self) -> dict:
        """{name: "removed" or "fell"} of the objects out of play."""
        return dict(self._out)

    def take_out(self, plant_context, name: str, why: str) -> None:
        """Take `name` out of the physics (see the module doc); `why`: "removed" or "fell"."""
        self._out[name] = why
        self._hold(plant_context, name)
        self._apply_filter()

    def after_step(self, plant_context) -> list:
        """After every time step: hold the objects out of play; every few steps, take out
        those that went past the table. -> the names taken out now."""
        for name in self._out:
            self._hold(plant_context, name)
        self._steps += 1
        if self._steps % CHECK_EVERY_STEPS:
            return []
        gone = [n for n in self._bodies if n not in self._out and self._past_the_table(plant_context, n)]
        for name in gone:
            self.take_out(plant_context, name, "fell")
        return gone

    def saved(self) -> tuple:
        """What is out and under which filter: with a copy of the Drake context (which holds
        the filter itself, in SceneGraph's state), enough to `restore` to."""
        return dict(self._out), self._steps, self._filter_id

    def restore(self, saved: tuple, scene_graph_context) -> None:
        """Back to `saved`; the caller has put the context saved with it back first. The
        filter manager is taken anew: the copy replaced the geometry state it pointed into."""
        self._filters = self._model.scene_graph.collision_filter_manager(scene_graph_context)
        out, self._steps, self._filter_id = saved
        self._out = dict(out)

    def _past_the_table(self, plant_context, name) -> bool:
        p = self._model.plant.EvalBodyPoseInWorld(plant_context, self._bodies[name]).translation()
        below = p[2] + self._radius_m[name] < TABLE_UNDERSIDE_M
        centre = np.array([VOLUME_SIZE_M / 2, VOLUME_SIZE_M / 2, TABLE_HEIGHT_M])
        return bool(below or np.linalg.norm(p - centre) > THROWN_BEYOND_M)

    def _hold(self, plant_context, name):
        plant, body = self._model.plant, self._bodies[name]
        plant.SetFreeBodyPose(plant_context, body, RigidTransform(np.asarray(PARKING_M, float)))
        plant.SetFreeBodySpatialVelocity(plant_context, body, SpatialVelocity(np.zeros(3), np.zeros(3)))

    def _apply_filter(self):
        """One transient filter: no contact between an object out of play and anything."""
        if self._filter_id is not None:
            self._filters.RemoveDeclaration(self._filter_id)
        out = [g for n in self._out for g in self._geometries[n]]
        self._filter_id = self._filters.ApplyTransient(
            CollisionFilterDeclaration().ExcludeBetween(GeometrySet(out), GeometrySet(self._all_geometries)))
