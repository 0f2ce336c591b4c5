"""Drake model of the Franka Emika (Panda) hand, the hand the paper's baselines (VGN,
VN-EdgeGraspNet) were made for, from the URDF and meshes their simulations use
(`baseline_files`: panda_hand/, loaded by path, not copied).

The URDF as it is: a hand link and two prismatic fingers, 0-40 mm each (80 mm stroke),
the right finger a `<mimic>` of the left (Drake: a coupler constraint, SAP only). Added
here: a force-limited actuator on each finger joint (each pushes with the grip force, so
the fingers squeeze an object with it; the coupler keeps them centred, as the real
hand's rack does), the TCP frame, and the paper's contact parameters on every collision
geometry. Drake collides an OBJ mesh as its convex hull, for point and hydroelastic
contact alike; the two fingers are not collided with each other (they meet at the
closed limit, where the joint limit stops them).

Frames (SI units), VGN's (simulation.py): the hand frame is the URDF's panda_hand frame
(the flange side of the hand), z along the approach, the fingers close along y (the
left finger on +y). The TCP is `HAND_TO_TCP_M` out along z, no rotation: VGN puts it
0.022 m from PyBullet's body frame, which is the hand's centre of mass (0.04 m up z).
VN-EdgeGraspNet's grasp pose is that body frame itself (its T_body_tcp is the identity),
0.022 m short of this TCP (benchmark/methods/vn_edge.py moves it). The fingertips are
`FINGER_DEPTH_M` beyond the TCP.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.geometry import CollisionFilterDeclaration, GeometrySet, RoleAssign, Sphere
from pydrake.math import RigidTransform
from pydrake.multibody.parsing import Parser
from pydrake.multibody.tree import FixedOffsetFrame

from .baseline_files import baseline_file

URDF = "panda_hand/hand.urdf"
MAX_OPENING_M = 0.08  # both fingers at their upper limit, 40 mm each
FINGER_TRAVEL_M = 0.04
HAND_TO_TCP_M = 0.062  # VGN: 0.022 m beyond the hand's centre of mass (0.04 m)
FINGER_JOINT_Z_M = 0.0584  # the URDF's finger joint origins
FINGER_LENGTH_M = 0.0538  # the collision finger mesh, joint origin to tip
FINGER_TIP_Z_M = FINGER_JOINT_Z_M + FINGER_LENGTH_M  # hand frame
FINGER_DEPTH_M = FINGER_TIP_Z_M - HAND_TO_TCP_M  # 0.050, VGN's finger_depth
PALM_FACE_Z_M = 0.066  # the hand's collision hull ends here, between the fingers (hand frame)
PAD_HALF_WIDTH_X_M = 0.0087  # the pad face's half width (finger mesh, flat at y = 0 for z >= 0.035)
PAD_Z_M = (0.035, FINGER_LENGTH_M)  # the flat pad face along the finger (finger frame)

# The open hand as boxes in the TCP frame, for a clearance check with the Panda's own
# geometry (the executor's is robotiq_driver.hand_geometry's 2F-85): the bounds of the
# collision meshes, fingers at 40 mm (tests/sim_bridge/test_panda_hand.py checks them),
# and, as for the 2F-85, a coarse stub for the arm's wrist behind the hand.
HAND_HALF_EXTENTS_M = (0.0316, 0.104)  # the hand's collision mesh, x and y
HAND_BACK_Z_M = -0.0259  # the hand's collision mesh reaches this far behind the hand frame
FINGER_HALF_WIDTH_X_M = 0.0105
FINGER_THICKNESS_M = 0.0264  # from the pad face outwards
WRIST_STUB_M = 0.08
HAND_PARTS = ("hand", "wrist", "right finger", "left finger")


def _open_hand_boxes_tcp() -> np.ndarray:
    hx, hy = HAND_HALF_EXTENTS_M
    z0, y0 = -HAND_TO_TCP_M, FINGER_TRAVEL_M  # the hand frame's z; the open pad face's y
    finger_z = (FINGER_JOINT_Z_M + z0, FINGER_TIP_Z_M + z0)
    left = [[-FINGER_HALF_WIDTH_X_M, y0, finger_z[0]], [FINGER_HALF_WIDTH_X_M, y0 + FINGER_THICKNESS_M, finger_z[1]]]
    right = [[-FINGER_HALF_WIDTH_X_M, -y0 - FINGER_THICKNESS_M, finger_z[0]], [FINGER_HALF_WIDTH_X_M, -y0, finger_z[1]]]
    return np.array([
        [[-hx, -hy, HAND_BACK_Z_M + z0], [hx, hy, PALM_FACE_Z_M + z0]],
        [[-0.045, -0.045, HAND_BACK_Z_M + z0 - WRIST_STUB_M], [0.045, 0.045, HAND_BACK_Z_M + z0]],
        right, left])


OPEN_HAND_BOXES_TCP = _open_hand_boxes_tcp()  # (lo, hi) corners [m], in the order of HAND_PARTS


def open_hand_hulls_tcp(baselines_dir=None) -> dict:
    """{part: trimesh} the open hand's collision geometry in the TCP frame, fingers at
    40 mm: the convex hull of each collision mesh, which is what Drake collides (and what
    PyBullet collided for VGN). Exact where OPEN_HAND_BOXES_TCP bounds; parts "hand",
    "right finger", "left finger"."""
    import trimesh  # lazy: only diagnostics need the meshes themselves

    def hull(mesh):
        return trimesh.load(baseline_file(f"panda_hand/meshes/collision/{mesh}.obj", baselines_dir),
                            force="mesh").convex_hull

    def moved(mesh, xyz, turn=False):
        X = np.eye(4)
        if turn:  # the URDF turns the right finger's mesh 180 deg about z
            X[:2, :2] = -np.eye(2)
        X[:3, 3] = np.add(xyz, (0.0, 0.0, -HAND_TO_TCP_M))
        return mesh.copy().apply_transform(X)
    finger = hull("finger")
    return {"hand": moved(hull("hand"), (0.0, 0.0, 0.0)),
            "right finger": moved(finger, (0.0, -FINGER_TRAVEL_M, FINGER_JOINT_Z_M), turn=True),
            "left finger": moved(finger, (0.0, FINGER_TRAVEL_M, FINGER_JOINT_Z_M))}

LEFT_LINKS = ("panda_leftfinger",)
RIGHT_LINKS = ("panda_rightfinger",)
PALM_LINKS = ("panda_hand",)
MOUNT_BODY = "panda_hand"


@dataclass
class PandaHand:
    """Handles into a plant holding one Panda hand (the fields SimWorld and the finger
    servo use, as hand_model.Hand's)."""

    model_instance: object
    driver_joints: tuple  # (left, right) prismatic joints; q = one finger's opening [m]
    actuators: tuple
    tcp_frame: object
    mount_body: object  # the hand link: welded, or the floating body

    def finger_opening_m(self, plant, plant_context) -> float:
        """The fingers' opening (pad gap) [m]: both joints' travel."""
        return float(sum(j.get_translation(plant_context) for j in self.driver_joints))


def add_panda_hand(plant, scene_graph, proximity_properties, X_W_hand=None, floating=False,
                   pad_contact_points=False, baselines_dir=None) -> PandaHand:
    """Add the Panda hand to `plant` (before Finalize), from `baselines_dir`/panda_hand
    (default: baseline_files.baselines_dir()).

    The hand frame is welded to the world at `X_W_hand` (4x4 or RigidTransform; default
    identity), or, with `floating=True`, left free (its default pose is `X_W_hand`).
    `proximity_properties` replaces every hand collision geometry's contact properties.
    `pad_contact_points`: for point contact, a 2 x 4 grid of 2 mm spheres flush with
    each pad face (hand_model.add_hand has why)."""
    urdf = baseline_file(URDF, baselines_dir)
    parser = Parser(plant, scene_graph)
    parser.SetAutoRenaming(True)
    (mi,) = parser.AddModels(str(urdf))
    hand = plant.GetBodyByName(MOUNT_BODY, mi)
    X = RigidTransform() if X_W_hand is None else RigidTransform(X_W_hand)
    if floating:
        plant.SetDefaultFloatingBaseBodyPose(hand, X)
    else:
        plant.WeldFrames(plant.world_frame(), hand.body_frame(), X)
    joints = tuple(plant.GetJointByName(f"panda_finger_joint{i}", mi) for i in (1, 2))
    for j in joints:
        j.set_default_translation(FINGER_TRAVEL_M)  # open
    acts = tuple(plant.AddJointActuator(f"{j.name()}_motor", j) for j in joints)
    tcp = plant.AddFrame(FixedOffsetFrame("tcp", hand.body_frame(), RigidTransform([0.0, 0.0, HAND_TO_TCP_M]), mi))
    fingers = [plant.GetBodyByName(n, mi) for n in LEFT_LINKS + RIGHT_LINKS]
    if pad_contact_points:
        r = 0.002
        for finger, side in zip(fingers, (1.0, -1.0)):  # the right finger's mesh is turned 180 deg about z
            for i, x in enumerate((-0.005, 0.005)):
                for j, z in enumerate(np.linspace(PAD_Z_M[0] + r, PAD_Z_M[1] - r, 4)):
                    plant.RegisterCollisionGeometry(finger, RigidTransform([x, side * r, z]), Sphere(r),
                                                    f"{finger.name()}_pad_point_{i}{j}", proximity_properties)
    for body_index in plant.GetBodyIndices(mi):
        for gid in plant.GetCollisionGeometriesForBody(plant.get_body(body_index)):
            scene_graph.AssignRole(plant.get_source_id(), gid, proximity_properties, RoleAssign.kReplace)
    between = GeometrySet([g for f in fingers for g in plant.GetCollisionGeometriesForBody(f)])
    scene_graph.collision_filter_manager().Apply(CollisionFilterDeclaration().ExcludeWithin(between))
    return PandaHand(mi, joints, acts, tcp, hand)

