"""The baselines' Franka Emika (Panda) hand in the simulated cell (WorldSettings(hand="panda")),
tested as the 2F-85 is: the model against VGN's hand facts, a cylinder held through a
lift, closing on nothing read as nothing, the grip force measured; and one clear error
for a hand that does not exist or a missing baseline file. Needs the baselines'
panda_hand/ (../shared/baselines by default; skipped without it)."""
import numpy as np
import pytest

from sim_bridge.physics import panda_hand
from sim_bridge.physics.baseline_files import BaselineFileMissing, baselines_dir
from sim_bridge.physics.objects import procedural_object
from sim_bridge.physics.scenes import TABLE_HEIGHT_M
from sim_bridge.world import R_TOP_DOWN, SceneConfig, SimWorld, WorldSettings, pose
from baselines import needs_panda  # tests/support

pytestmark = pytest.mark.drake

CENTRE = (0.15, 0.15)
DIAMETER_M, HEIGHT_M, MASS_KG = 0.04, 0.10, 0.3
GRIP_N = 40.0


@pytest.fixture(scope="module")
def world():
    """One Panda world for the module: a 40 mm cylinder, 0.3 kg, upright at the centre."""
    cylinder = procedural_object("cylinder", (DIAMETER_M, HEIGHT_M), mass_kg=MASS_KG)
    X = pose(p=(*CENTRE, TABLE_HEIGHT_M + HEIGHT_M / 2 + 0.001))
    return SimWorld(SceneConfig(objects=((cylinder, X),)), WorldSettings(hand="panda"))


def close(world, target_m=0.0, max_s=2.0):
    world.command_fingers(target_m, 0.1, GRIP_N)
    for _ in range(int(max_s / 0.01)):
        world.advance(0.01)
        width, state = world.finger_status()
        if state != "moving":
            return width, state
    raise AssertionError(f"fingers still moving after {max_s} s: {world.finger_status()}")


def open_and_go_home(world):
    world.command_fingers(panda_hand.MAX_OPENING_M, 0.1, GRIP_N)
    world.advance(1.0)
    ok, message = world.move_tcp(pose(R_TOP_DOWN, (*CENTRE, 0.45)), 0.25)
    assert ok, message


@needs_panda
def test_the_model_is_vgns_panda_hand():
    """TCP 0.062 m out of the hand frame (VGN's 0.022 m past the centre of mass), the
    fingertips VGN's finger depth (0.05 m) beyond it, 0-40 mm per finger."""
    from pydrake.geometry import ProximityProperties
    from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
    from pydrake.systems.framework import DiagramBuilder

    plant, scene_graph = AddMultibodyPlant(MultibodyPlantConfig(time_step=2e-3), DiagramBuilder())
    hand = panda_hand.add_panda_hand(plant, scene_graph, ProximityProperties())
    plant.Finalize()
    ctx = plant.CreateDefaultContext()
    X_hand_tcp = plant.CalcRelativeTransform(ctx, hand.mount_body.body_frame(), hand.tcp_frame)
    np.testing.assert_allclose(X_hand_tcp.GetAsMatrix4(), pose(p=(0, 0, 0.062)), atol=1e-12)
    assert hand.finger_opening_m(plant, ctx) == pytest.approx(0.08)  # open by default
    for joint in hand.driver_joints:
        assert (joint.position_lower_limits()[0], joint.position_upper_limits()[0]) == (0.0, 0.04)
    inspector = scene_graph.model_inspector()
    (finger_geometry,) = plant.GetCollisionGeometriesForBody(plant.GetBodyByName("panda_leftfinger"))
    import trimesh
    tip_finger = trimesh.load(inspector.GetShape(finger_geometry).source().path(), force="mesh").bounds[1, 2]
    tip_hand = panda_hand.FINGER_JOINT_Z_M + tip_finger
    assert tip_hand - 0.062 == pytest.approx(0.05, abs=5e-4)
    assert panda_hand.FINGER_DEPTH_M == pytest.approx(tip_hand - 0.062, abs=1e-4)
    # the fingers close on each other at 0, not on a collision between them
    assert inspector.CollisionFiltered(
        finger_geometry, *plant.GetCollisionGeometriesForBody(plant.GetBodyByName("panda_rightfinger")))


@needs_panda
def test_the_clearance_boxes_are_the_open_hands_collision_geometry():
    """Every collision vertex of the open hand lies in its part's box, and each box is
    hardly bigger than its part (the wrist stub behind the hand is the arm's, coarse)."""
    import trimesh
    from pydrake.geometry import ProximityProperties
    from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
    from pydrake.systems.framework import DiagramBuilder

    plant, scene_graph = AddMultibodyPlant(MultibodyPlantConfig(time_step=2e-3), DiagramBuilder())
    hand = panda_hand.add_panda_hand(plant, scene_graph, ProximityProperties())
    plant.Finalize()
    ctx, inspector = plant.CreateDefaultContext(), scene_graph.model_inspector()
    X_tcp_W = plant.CalcRelativeTransform(ctx, hand.tcp_frame, plant.world_frame()).GetAsMatrix4()
    boxes = dict(zip(panda_hand.HAND_PARTS, panda_hand.OPEN_HAND_BOXES_TCP))
    hulls = panda_hand.open_hand_hulls_tcp()
    for part, body in (("hand", "panda_hand"), ("left finger", "panda_leftfinger"), ("right finger", "panda_rightfinger")):
        body = plant.GetBodyByName(body)
        (g,) = plant.GetCollisionGeometriesForBody(body)
        v = trimesh.load(inspector.GetShape(g).source().path(), force="mesh").vertices
        X = X_tcp_W @ plant.EvalBodyPoseInWorld(ctx, body).GetAsMatrix4() @ inspector.GetPoseInFrame(g).GetAsMatrix4()
        v = v @ X[:3, :3].T + X[:3, 3]
        # the exact hulls (pick diagnosis) are these vertices' hulls, placed as Drake places them
        np.testing.assert_allclose(hulls[part].bounds, [v.min(0), v.max(0)], atol=1e-9)
        assert trimesh.convex.is_convex(hulls[part])
        assert hulls[part].volume == pytest.approx(trimesh.convex.convex_hull(v).volume, rel=1e-9)
        lo, hi = boxes[part]
        assert np.all(v.min(0) > lo - 2e-4) and np.all(v.max(0) < hi + 2e-4), part  # inside (pad face: -0.13 mm)
        # and tight: the hand's box is symmetric, its mesh reaches 100.4 mm to one side, 104 to the other
        assert np.all(v.min(0) - lo < 1e-3) and np.all(hi - v.max(0) < 4e-3), (part, v.min(0) - lo, hi - v.max(0))
    # the palm face 4 mm past the TCP, the fingertips at VGN's finger depth, 80 mm apart
    assert boxes["hand"][1][2] == pytest.approx(0.004) and boxes["left finger"][1][2] == pytest.approx(0.05, abs=5e-4)
    assert boxes["left finger"][0][1] - boxes["right finger"][1][1] == pytest.approx(0.08)


@needs_panda
def test_closing_on_nothing_reads_as_nothing(world):
    open_and_go_home(world)
    width, state = close(world)
    assert state == "at_target" and width == 0.0  # the target, reached
    world.advance(0.2)
    assert not world.fingers_busy()
    # the joint limit stops empty fingers at 0 (40 N push it 0.4 um past)
    assert world.finger_width_m() < 1e-4
    verdict = world.parallel_grip()
    assert not verdict.held and "nothing between them" in verdict.reason, verdict
    assert world.grip_force_n() == (0.0, 0.0)


@needs_panda
def test_a_cylinder_is_held_through_a_lift_with_the_grip_force(world):
    open_and_go_home(world)
    (before,) = world.object_states()
    top_z = TABLE_HEIGHT_M + HEIGHT_M
    # VGN's TCP is 4 mm short of the palm's face: 8 mm above the top leaves the palm
    # 4 mm clear, the fingertips 42 mm down the cylinder.
    grasp = pose(R_TOP_DOWN, (*CENTRE, top_z + 0.008))
    above = pose(R_TOP_DOWN, (*CENTRE, top_z + 0.108))
    for target in (above, grasp):
        ok, message = world.move_tcp(target, 0.25)
        assert ok, message

    width, state = close(world)
    assert state == "blocked" and width == pytest.approx(DIAMETER_M, abs=1.5e-3)
    assert world.parallel_grip().held
    # The servo clips each finger's effort at 40 N; still, the squeeze equals it up to the
    # joint damping at the stall speed (60 N s/m x 2.5 mm/s = 0.15 N) and what the coupler
    # moves from one finger to the other (the cylinder's friction on the table).
    left, right = world.grip_force_n()
    assert (left + right) / 2 == pytest.approx(GRIP_N, abs=1.0), (left, right)
    assert left == pytest.approx(GRIP_N, abs=3.0) and right == pytest.approx(GRIP_N, abs=3.0)

    ok, message = world.move_tcp(above, 0.1)
    assert ok, message
    world.advance(0.3)  # hold
    (after,) = world.object_states()
    rise = after.X_task_object[2, 3] - before.X_task_object[2, 3]
    assert rise > 0.095, f"the cylinder rose {rise:.3f} m of the 0.10 m lift"
    assert after.in_hand and after.lifted and after.grasp_mode == "precision"  # the palm stayed clear
    verdict = world.parallel_grip()
    assert verdict.held and verdict.objects == (after.name,), verdict
    # what touches the hand, by name: the two fingers, the cylinder, nothing else
    assert {(hand, other) for hand, other, _ in world.hand_touches()} == {
        ("panda_leftfinger", after.name), ("panda_rightfinger", after.name)}
    assert world.finger_status()[1] == "blocked"
    assert np.mean(world.grip_force_n()) == pytest.approx(GRIP_N, abs=1.0)
    # what a wrist sensor reads: the weight, pulling down
    assert world.hand_contact_force_n()[2] == pytest.approx(-MASS_KG * 9.81, rel=0.05)

    # put it down and let go
    ok, message = world.move_tcp(pose(R_TOP_DOWN, (*CENTRE, top_z + 0.011)), 0.1)
    assert ok, message
    world.command_fingers(panda_hand.MAX_OPENING_M, 0.1, GRIP_N)
    world.advance(1.0)
    (put_down,) = world.object_states()
    assert not put_down.in_hand and put_down.height_above_table_m < 0.005
    verdict = world.parallel_grip()
    assert not verdict.held and "no object touches both fingers" in verdict.reason, verdict


def test_an_unknown_hand_is_one_clear_error():
    with pytest.raises(ValueError, match=r"hand 'ur5e' does not exist: use one of '2f85' .*, 'panda' "):
        WorldSettings(hand="ur5e").validate()


def test_a_missing_baseline_file_says_which_and_where_to_get_it(tmp_path, monkeypatch):
    with pytest.raises(BaselineFileMissing, match=rf"baseline file {tmp_path}/panda_hand/hand.urdf not found: get "
                                                   r"panda_hand/hand.urdf from github.com/HaojHuang/Edge-Grasp-Network"):
        WorldSettings(hand="panda", baselines_dir=str(tmp_path)).validate()
    WorldSettings(hand="2f85", baselines_dir=str(tmp_path)).validate()  # the 2F-85 needs none
    # the default: ../shared/baselines beside the project root, or GRAVGRASP_BASELINES
    monkeypatch.delenv("GRAVGRASP_BASELINES", raising=False)
    monkeypatch.setenv("GRAVGRASP_ROOT", str(tmp_path / "project"))
    assert baselines_dir() == (tmp_path / "shared" / "baselines").resolve()
    monkeypatch.setenv("GRAVGRASP_BASELINES", str(tmp_path / "elsewhere"))
    assert baselines_dir() == tmp_path / "elsewhere"
