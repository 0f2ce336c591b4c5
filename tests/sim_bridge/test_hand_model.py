"""The 2F-85 Drake model: exported dimensions match the model, flange placement."""

import numpy as np
import pytest
from pydrake.geometry import AddCompliantHydroelasticProperties, ProximityProperties
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
from pydrake.systems.framework import DiagramBuilder

from sim_bridge.physics import hand_model

pytestmark = pytest.mark.drake


def build(**kw):
    plant, sg = AddMultibodyPlantSceneGraph(DiagramBuilder(), 2e-3)
    props = ProximityProperties()
    AddCompliantHydroelasticProperties(0.01, 1e8, props)
    hand = hand_model.add_hand(plant, sg, props, **kw)
    plant.Finalize()
    return plant, hand, plant.CreateDefaultContext()


def test_exported_dimensions_match_the_model():
    plant, hand, ctx = build()
    X_tcp_W = plant.CalcRelativeTransform(ctx, hand.tcp_frame, plant.world_frame())
    faces, tops = [], []
    for side in ("left", "right"):
        pad = plant.GetBodyByName(f"{side}_pad")
        X_W_pad = plant.EvalBodyPoseInWorld(ctx, pad)
        # Menagerie pad box: inner face at y = -6.6 mm, spans z 0..37.5 mm in the pad frame
        faces.append((X_tcp_W @ X_W_pad).multiply([0.0, -0.0066, 0.01875]))
        tops.append((X_tcp_W @ X_W_pad).multiply([0.0, -0.0066, 0.0375]))
    assert np.linalg.norm(faces[0] - faces[1]) == pytest.approx(hand_model.MAX_STROKE_M, abs=1e-3)
    assert faces[0][1] == pytest.approx(-faces[1][1], abs=1e-6)  # symmetric about the TCP
    assert tops[0][2] == pytest.approx(hand_model.FINGER_LENGTH_M - hand_model.PALM_TO_TCP_M, abs=1e-3)
    X_flange_tcp = plant.CalcRelativeTransform(ctx, hand.flange_frame, hand.tcp_frame)
    np.testing.assert_allclose(X_flange_tcp.GetAsMatrix4(), hand_model.X_flange_tcp(), atol=1e-9)
    # the closing axis (TCP y) points at the right finger
    right = plant.EvalBodyPoseInWorld(ctx, plant.GetBodyByName("right_pad")).translation()
    assert X_tcp_W.multiply(right)[1] > 0.03


def test_flange_can_be_placed_or_floating():
    X = RigidTransform(RollPitchYaw(0.3, -0.2, 1.0), [0.1, -0.2, 0.5])
    plant, hand, ctx = build(X_W_flange=X)
    X_W_tcp = plant.CalcRelativeTransform(ctx, plant.world_frame(), hand.tcp_frame)
    np.testing.assert_allclose(X_W_tcp.GetAsMatrix4(), X.GetAsMatrix4() @ hand_model.X_flange_tcp(), atol=1e-9)
    welded_dofs = plant.num_positions()
    plant_f, hand_f, ctx_f = build(X_W_flange=X, floating=True)
    assert plant_f.num_positions() == welded_dofs + 7
    X_W_tcp_f = plant_f.CalcRelativeTransform(ctx_f, plant_f.world_frame(), hand_f.tcp_frame)
    np.testing.assert_allclose(X_W_tcp_f.GetAsMatrix4(), X_W_tcp.GetAsMatrix4(), atol=1e-9)


def test_underactuation_is_restored():
    plant, hand, ctx = build()
    assert plant.num_actuators() == 2
    # two ball constraints (linkage closures) + one coupler (one motor, two fingers)
    assert plant.num_constraints() == 3
    spring = plant.GetJointByName("left_spring_link_joint")
    assert spring.position_lower_limits()[0] == pytest.approx(-0.2967, abs=1e-3)
    assert hand.driver_joints[0].position_upper_limits()[0] == pytest.approx(hand_model.DRIVER_CLOSED_RAD)


@pytest.mark.parametrize("pad_contact_points", [False, True])
def test_hand_geometry_links_are_valid_after_finalize(pad_contact_points):
    """add_hand's GeometryId -> link map must still name every hand collision geometry
    after more geometry (the pad sphere grid, an object) was registered and the plant
    finalized (the pad boxes' ids used to read as garbage with the sphere grid)."""
    from pydrake.geometry import Box
    from pydrake.multibody.plant import CoulombFriction
    from pydrake.multibody.tree import SpatialInertia

    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, time_step=1e-3)
    props = ProximityProperties()
    hand = hand_model.add_hand(plant, scene_graph, props, pad_contact_points=pad_contact_points)
    body = plant.AddRigidBody("obj", plant.AddModelInstance("obj"), SpatialInertia.SolidBoxWithMass(0.1, 0.03, 0.03, 0.03))
    plant.RegisterCollisionGeometry(body, RigidTransform(), Box(0.03, 0.03, 0.03), "obj", CoulombFriction(0.5, 0.5))
    plant.Finalize()
    stored = {int(g.get_value()): name for g, name in hand.geometry_links.items()}
    assert stored == hand.collision_geometry_links(plant)
    assert sum(n.endswith("_pad") for n in stored.values()) >= (18 if pad_contact_points else 2)



def hand_surfaces_tcp(driver_angles_rad):
    """Collision surface of the hand in its TCP frame at each driver angle: [[trimesh hull]]."""
    import trimesh
    from pydrake.geometry import Box, Convex, Mesh

    builder = DiagramBuilder()
    plant, sg = AddMultibodyPlantSceneGraph(builder, 1e-3)
    hand = hand_model.add_hand(plant, sg, ProximityProperties())
    plant.Finalize()
    diagram = builder.Build()
    ctx = diagram.CreateDefaultContext()
    pc = plant.GetMyContextFromRoot(ctx)
    shapes = {}
    out = []
    for angle in driver_angles_rad:
        for j in hand.driver_joints:
            j.set_angle(pc, angle)
        query = sg.get_query_output_port().Eval(sg.GetMyContextFromRoot(ctx))
        inspector = query.inspector()
        X_tcp_W = np.linalg.inv(hand.tcp_frame.CalcPoseInWorld(pc).GetAsMatrix4())
        hulls = []
        for gid in inspector.GetAllGeometryIds():
            if inspector.GetProximityProperties(gid) is None:
                continue
            if gid not in shapes:
                shape = inspector.GetShape(gid)
                if isinstance(shape, (Convex, Mesh)):
                    m = trimesh.load(shape.source().path(), force="mesh")
                    m.apply_scale(shape.scale3()[0])
                else:
                    assert isinstance(shape, Box), type(shape)
                    m = trimesh.creation.box(extents=[shape.width(), shape.depth(), shape.height()])
                shapes[gid] = m.convex_hull
            m = shapes[gid].copy()
            m.apply_transform(X_tcp_W @ query.GetPoseInWorld(gid).GetAsMatrix4())
            hulls.append(m)
        out.append(hulls)
    return out


def test_the_hand_is_its_own_mirror_image_about_the_tcp_yz_plane():
    """object_symmetry's mirror copies rest on this: x -> -x in the TCP frame maps the
    hand's collision geometry onto itself, open and closing (and z -> -z does not)."""
    import open3d as o3d

    for hulls in hand_surfaces_tcp([0.0, 0.4]):
        scene = o3d.t.geometry.RaycastingScene()
        for m in hulls:
            scene.add_triangles(o3d.core.Tensor(np.asarray(m.vertices, np.float32)),
                                o3d.core.Tensor(np.asarray(m.faces, np.uint32)))
        points = np.concatenate([m.sample(300, seed=i) for i, m in enumerate(hulls)])

        def off_surface_m(p):
            return scene.compute_distance(o3d.core.Tensor(p.astype(np.float32))).numpy()

        assert off_surface_m(points * [-1, 1, 1]).max() < 1e-4
        assert np.quantile(off_surface_m(points * [1, 1, -1] + [0, 0, 0.1]), 0.5) > 0.01


def test_finger_kinematics_puts_the_pad_tips_where_the_model_has_them():
    fk = hand_model.FingerKinematics()
    names = ("left_coupler", "left_driver", "left_follower", "left_spring_link",
             "right_coupler", "right_driver", "right_follower", "right_spring_link")
    # open (all joints at 0): tips at the open fingertip depth, inner faces the stroke apart
    open_tips = fk.pad_tips_tcp(names, np.zeros((1, 8)))[0]
    assert open_tips.shape == (8, 3)
    np.testing.assert_allclose(open_tips[:, 2], hand_model.FINGER_TIP_Z_M, atol=1e-3)
    assert np.abs(open_tips[:, 1]).min() == pytest.approx(hand_model.MAX_STROKE_M / 2, abs=1e-3)
    # closed in parallel, as the linkage does on nothing (coupler 0, follower ~ -0.96 x
    # driver, spring link = driver; grasp tables): the tips move 13-14 mm further out
    # along the approach and the pads nearly meet
    q = 0.76
    closed = fk.pad_tips_tcp(names, [[0.0, q, -0.96 * q, q] * 2])[0]
    assert closed[:, 2].max() == pytest.approx(0.018, abs=1.5e-3)
    assert np.abs(closed[:, 1]).min() < 0.005


def test_pad_tip_depth_by_opening_matches_the_linkage():
    """robotiq_driver.hand_geometry's table of where the pad tips reach when the fingers
    stop at an opening (the sampler's table check) against the Drake model."""
    from robotiq_driver import hand_geometry
    fk = hand_model.FingerKinematics()
    names = ("left_coupler", "left_driver", "left_follower", "left_spring_link",
             "right_coupler", "right_driver", "right_follower", "right_spring_link")
    q = np.linspace(0.0, 0.76, 9)
    tips = fk.pad_tips_tcp(names, [[0.0, a, -0.96 * a, a] * 2 for a in q])
    opening = 2 * np.abs(tips[:, :, 1]).min(axis=1)
    np.testing.assert_allclose(hand_geometry.pad_tip_z_m(opening), tips[:, :, 2].max(axis=1), atol=3e-4)
    table = hand_geometry.closed_pad_tips_tcp(opening)
    np.testing.assert_allclose(table[:, :, 2].max(axis=1), tips[:, :, 2].max(axis=1), atol=3e-4)
    np.testing.assert_allclose(np.abs(table[:, :, 1]).min(axis=1), opening / 2)
