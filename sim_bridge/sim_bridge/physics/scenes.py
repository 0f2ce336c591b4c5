"""Table-top scenes of 1-5 objects, settled under gravity in Drake.

Task frame: gravity-aligned, z up, origin at a corner of the 0.30 m workspace
cube (the TSDF volume).  The table top is the plane z = TABLE_HEIGHT_M = 0.05 m
inside the cube (as in VGN), leaving 0.25 m above it for objects.

Arrangements (as VGN's):
- "packed": objects in one of their resting poses (drawn by probability, see
  resting_poses; upright, object-frame z up, for objects without any), random
  yaw, placed side by side on the table without overlapping footprints, then
  settled (tall thin ones may tip over; that is physics).
- "pile": objects at random orientations dropped from staggered heights above
  the table centre and settled.
Objects that end up outside the workspace are removed and the rest settled again.

The Drake model: one MultibodyPlant (point contact, SAP, gravity) with the table
welded to the world and every object a free body; `build_scene_diagram` makes the
diagram, `settle` simulates it until every body is at rest. (Both import pydrake
themselves, so that the table and the arrangements can be read without loading Drake,
which costs a process seconds and ~70 MB.)
"""

from dataclasses import dataclass

import numpy as np

VOLUME_SIZE_M = 0.30
TABLE_HEIGHT_M = 0.05
TABLE_FRICTION = 0.75
ARRANGEMENTS = ("packed", "pile")


@dataclass(frozen=True)
class SceneSettings:
    time_step_s: float = 2e-3
    settle_speed: float = 5e-3        # all generalized velocities below this (m/s, rad/s) ...
    settle_hold_s: float = 0.1        # ... for this long = settled
    max_settle_time_s: float = 4.0
    margin_m: float = 0.02            # keep objects this far inside the cube's side walls
    packed_gap_m: float = 0.005       # between footprints of packed objects
    pile_radius_m: float = 0.05       # drop points within this of the table centre
    pile_height_m: float = 0.07       # lowest drop point above the table (object centre)
    pile_box_m: float = 0.22          # temporary box around a falling pile
    hydroelastic_modulus_pa: float = 1e7


@dataclass
class SceneDiagram:
    diagram: object
    plant: object
    bodies: list


def build_scene_diagram(objects, settings=SceneSettings(), pile_box_m=None):
    """Diagram with the table (a box whose top is z = TABLE_HEIGHT_M) and the objects
    as free bodies under gravity.  pile_box_m: inner width of a temporary square box
    around the table centre that keeps a pile together while it falls (VGN does the
    same), or None."""
    # lazy: pydrake (see the module doc)
    from pydrake.geometry import (AddCompliantHydroelasticProperties, AddContactMaterial,
                                  AddRigidHydroelasticProperties, Box, ProximityProperties)
    from pydrake.math import RigidTransform
    from pydrake.multibody.plant import AddMultibodyPlant, CoulombFriction, MultibodyPlantConfig
    from pydrake.systems.framework import DiagramBuilder

    builder = DiagramBuilder()
    # Hydroelastic: point contact between flat faces (box on table) rocks between
    # single contact points and never comes to rest.
    plant, _ = AddMultibodyPlant(MultibodyPlantConfig(
        time_step=settings.time_step_s, discrete_contact_approximation="sap",
        contact_model="hydroelastic_with_fallback"), builder)
    friction = CoulombFriction(TABLE_FRICTION, TABLE_FRICTION)
    table_props = ProximityProperties()
    AddContactMaterial(dissipation=5.0, friction=friction, properties=table_props)
    AddRigidHydroelasticProperties(0.01, table_props)
    object_props = ProximityProperties()
    AddContactMaterial(dissipation=5.0, friction=friction, properties=object_props)
    AddCompliantHydroelasticProperties(0.01, settings.hydroelastic_modulus_pa, object_props)
    # 1 m wide so objects that leave the workspace still land (and are then removed)
    X_table = RigidTransform([VOLUME_SIZE_M / 2, VOLUME_SIZE_M / 2, TABLE_HEIGHT_M - 0.025])
    plant.RegisterCollisionGeometry(plant.world_body(), X_table, Box(1.0, 1.0, 0.05), "table", table_props)
    if pile_box_m:
        c, t, h = VOLUME_SIZE_M / 2, 0.01, 1.0
        for k, (dx, dy) in enumerate([(1, 0), (-1, 0), (0, 1), (0, -1)]):
            off = pile_box_m / 2 + t / 2
            size = (t, pile_box_m + 2 * t, h) if dx else (pile_box_m + 2 * t, t, h)
            X = RigidTransform([c + dx * off, c + dy * off, TABLE_HEIGHT_M + h / 2])
            plant.RegisterCollisionGeometry(plant.world_body(), X, Box(*size), f"pile_wall{k}", table_props)
    bodies = [obj.add_to_plant(plant, name=f"scene_obj{i}", proximity_properties=object_props)
              for i, obj in enumerate(objects)]
    plant.Finalize()
    return SceneDiagram(builder.Build(), plant, bodies)


def settle(scene: SceneDiagram, X_task_objects, settings=SceneSettings()):
    """Simulate from the given object poses until at rest; returns the poses (list of 4x4)
    and whether it settled within max_settle_time_s."""
    # lazy: pydrake (see the module doc)
    from pydrake.math import RigidTransform
    from pydrake.systems.analysis import Simulator

    simulator = Simulator(scene.diagram)
    ctx = simulator.get_mutable_context()
    pc = scene.plant.GetMyMutableContextFromRoot(ctx)
    for body, X in zip(scene.bodies, X_task_objects):
        scene.plant.SetFreeBodyPose(pc, body, RigidTransform(np.asarray(X)))
    simulator.Initialize()
    quiet_since, settled, t = None, False, 0.0
    step = 0.02
    while t < settings.max_settle_time_s:
        t += step
        simulator.AdvanceTo(t)
        v = scene.plant.GetVelocities(pc)
        if not np.isfinite(v).all():
            break
        if np.abs(v).max() < settings.settle_speed:
            quiet_since = t if quiet_since is None else quiet_since
            if t - quiet_since >= settings.settle_hold_s:
                settled = True
                break
        else:
            quiet_since = None
    poses = [scene.plant.EvalBodyPoseInWorld(pc, b).GetAsMatrix4() for b in scene.bodies]
    return poses, settled


def _yaw(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _random_rotation(rng):
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _pose(R, p):
    X = np.eye(4)
    X[:3, :3], X[:3, 3] = R, p
    return X


def packed_poses(meshes, rng, settings=SceneSettings(), rest=None):
    """Non-overlapping placements on the table: list of 4x4 or None (no room).
    rest: per mesh a resting_poses.RestingPoses (one is drawn) or None (upright).
    Footprints are the convex hulls of the posed meshes seen from above, kept
    settings.packed_gap_m apart (bounding circles, used before, left a 15 cm bottle lying
    on its side a 15 cm disc, and packed scenes kept 3 of 5 objects on average)."""
    lo, hi = settings.margin_m, VOLUME_SIZE_M - settings.margin_m
    placed = []  # footprints (K, 2) on the table
    out = []
    for k, mesh in enumerate(meshes):
        pose = None
        r = rest[k] if rest is not None else None
        R_rest = r.X_table_object[r.sample(rng, 1)[0], :3, :3] if r is not None and len(r) else np.eye(3)
        for _ in range(50):
            R = _yaw(rng.uniform(0, 2 * np.pi)) @ R_rest
            v = mesh.vertices @ R.T
            foot = footprint(v[:, :2])
            low, high = lo - foot.min(0), hi - foot.max(0)  # where the footprint's origin may go
            if np.any(low > high):
                continue  # does not fit the table at this yaw
            xy = rng.uniform(low, high)
            if all(polygons_apart(foot + xy, other, settings.packed_gap_m) for other in placed):
                placed.append(foot + xy)
                pose = _pose(R, np.r_[xy, TABLE_HEIGHT_M - v[:, 2].min() + 0.001])
                break
        out.append(pose)
    return out


def footprint(points_xy) -> np.ndarray:
    """(K, 2) convex hull of points on the table plane, counter-clockwise."""
    from scipy.spatial import ConvexHull  # lazy: only packing needs it
    return points_xy[ConvexHull(points_xy).vertices]


def polygons_apart(a, b, gap_m) -> bool:
    """Are convex polygons a, b (K, 2) at least gap_m apart along one of their edge
    normals? (Separating axes: exact for overlap; a gap across a corner-to-corner
    direction may be under-read, which only refuses a placement.)"""
    for poly in (a, b):
        edges = np.roll(poly, -1, axis=0) - poly
        normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1)
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        pa, pb = a @ normals.T, b @ normals.T
        if np.any((pb.min(0) - pa.max(0) >= gap_m) | (pa.min(0) - pb.max(0) >= gap_m)):
            return True
    return False


def pile_poses(meshes, rng, settings=SceneSettings()):
    """Random orientations above the table centre, stacked so they start apart."""
    out = []
    z = TABLE_HEIGHT_M + settings.pile_height_m
    c = VOLUME_SIZE_M / 2
    for mesh in meshes:
        R = _random_rotation(rng)
        v = mesh.vertices @ R.T
        mid = (v.max(0) + v.min(0)) / 2
        half_h = (v[:, 2].max() - v[:, 2].min()) / 2
        r, a = settings.pile_radius_m * np.sqrt(rng.uniform()), rng.uniform(0, 2 * np.pi)
        r = min(r, max(0.0, settings.pile_box_m / 2 - np.abs(v[:, :2] - mid[:2]).max()))
        z = max(z, TABLE_HEIGHT_M + half_h + 0.005)
        out.append(_pose(R, np.r_[c + r * np.cos(a), c + r * np.sin(a), z + half_h] - mid))
        z += 2 * half_h + 0.01
    return out


def in_workspace(mesh, X, settings=SceneSettings()):
    """Is the posed mesh inside the cube (x, y within the walls, on the table, below the top)?"""
    v = mesh.vertices @ X[:3, :3].T + X[:3, 3]
    return bool((v[:, :2].min() >= 0.0) and (v[:, :2].max() <= VOLUME_SIZE_M)
                and v[:, 2].min() >= TABLE_HEIGHT_M - 0.01 and v[:, 2].max() <= VOLUME_SIZE_M)


def arrange(objects, arrangement, rng, settings=SceneSettings(), rest=None):
    """Place and settle `objects` (ObjectSpec list); rest: per object its
    RestingPoses or None (used by "packed").

    Returns (kept indices into objects, their settled X_task_object list).
    Objects that found no room or left the workspace are dropped.
    """
    if arrangement not in ARRANGEMENTS:
        raise ValueError(f"arrangement {arrangement!r}: use one of {ARRANGEMENTS}")
    meshes = [o.collision_mesh() for o in objects]
    poses = (packed_poses(meshes, rng, settings, rest) if arrangement == "packed"
             else pile_poses(meshes, rng, settings))
    keep = [i for i, X in enumerate(poses) if X is not None]
    if arrangement == "pile" and keep:
        # drop inside the temporary box, then remove it and let the pile relax
        scene = build_scene_diagram([objects[i] for i in keep], settings, pile_box_m=settings.pile_box_m)
        for i, X in zip(keep, settle(scene, [poses[i] for i in keep], settings)[0]):
            poses[i] = X
    for _ in range(3):
        if not keep:
            return [], []
        scene = build_scene_diagram([objects[i] for i in keep], settings)
        settled_poses, _ = settle(scene, [poses[i] for i in keep], settings)
        inside = [in_workspace(meshes[i], X, settings) for i, X in zip(keep, settled_poses)]
        for i, X in zip(keep, settled_poses):
            poses[i] = X
        if all(inside):
            return keep, [poses[i] for i in keep]
        keep = [i for i, ok in zip(keep, inside) if ok]
    return [], []
