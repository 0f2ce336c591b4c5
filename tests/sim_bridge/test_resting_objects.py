"""Objects at rest away from the hand are frozen (sim_bridge.world.resting_objects), woken
when the hand comes near, and a grasp with freezing on does what it does without."""
import numpy as np
import pytest

from sim_bridge.physics.objects import procedural_object
from sim_bridge.physics.scenes import TABLE_HEIGHT_M
from sim_bridge.world import R_TOP_DOWN, SceneConfig, SimFingerPlant, SimWorld, WorldSettings, pose
from sim_bridge.world.resting_objects import WAKE_GAP_M

pytestmark = pytest.mark.drake

LEFT, RIGHT = (0.08, 0.15), (0.22, 0.15)


def two_object_world(freeze=True):
    box = procedural_object("box", (0.05, 0.05, 0.05), mass_kg=0.3)
    cylinder = procedural_object("cylinder", (0.05, 0.12), mass_kg=0.3)
    objects = ((box, pose(p=(*LEFT, TABLE_HEIGHT_M + 0.026))),
               (cylinder, pose(p=(*RIGHT, TABLE_HEIGHT_M + 0.061))))
    return SimWorld(SceneConfig(objects=objects), WorldSettings(freeze_resting_objects=freeze))


@pytest.fixture(scope="module")
def world():
    return two_object_world()


def positions(world):
    return {s.name: s.X_task_object[:3, 3].copy() for s in world.object_states()}


def test_objects_at_rest_away_from_the_hand_fall_asleep_and_stay_where_they_were(world):
    world.advance(0.5)
    assert sorted(world.asleep_objects()) == sorted(world.object_names())
    before = positions(world)
    world.advance(0.3)
    after = positions(world)
    for name in before:
        np.testing.assert_array_equal(before[name], after[name])
    assert not world.needs_stepping()  # asleep reads as still, as the real-time runner needs


def test_the_hand_coming_near_wakes_only_the_object_it_nears(world):
    world.advance(0.3)
    box, cylinder = world.object_names()
    above_cylinder = pose(R_TOP_DOWN, (*RIGHT, TABLE_HEIGHT_M + 0.12 + 0.02))
    ok, message = world.move_tcp(above_cylinder, 0.25)
    assert ok, message
    asleep = world.asleep_objects()
    assert cylinder not in asleep, f"the hand is within {WAKE_GAP_M * 1e3:.0f} mm of the cylinder but it sleeps"
    assert box in asleep


def test_a_grasp_lifts_the_same_with_and_without_freezing():
    """Same scene, same grasp: the cylinder rises the same and the box stays put."""
    results = []
    for freeze in (False, True):
        w = two_object_world(freeze)
        w.advance(0.4)
        top_z = TABLE_HEIGHT_M + 0.12
        for target in (pose(R_TOP_DOWN, (*RIGHT, top_z + 0.07)), pose(R_TOP_DOWN, (*RIGHT, top_z - 0.03))):
            assert w.move_tcp(target, 0.25)[0]
        plant = SimFingerPlant(w)
        width = 0.085
        for _ in range(300):
            reading = plant.advance(0.01, width, 0.0, 0.1, 40.0)
            width = reading.width_m
            if reading.current_a == 0.0:
                break
        assert reading.blocked
        assert w.move_tcp(pose(R_TOP_DOWN, (*RIGHT, top_z + 0.07)), 0.1)[0]
        states = {s.name: s for s in w.object_states()}
        results.append(states)
    (box, cylinder) = results[0]
    for name in (box, cylinder):
        np.testing.assert_allclose(results[1][name].X_task_object[:3, 3], results[0][name].X_task_object[:3, 3],
                                   atol=1e-3)
    assert results[1][cylinder].lifted and results[0][cylinder].lifted


def test_a_removed_object_asleep_stays_on_the_shelf():
    w = two_object_world()
    w.advance(0.5)
    box = w.object_names()[0]
    assert box in w.asleep_objects()
    w.remove_object(box)
    w.advance(0.2)
    X = w._model.plant.EvalBodyPoseInWorld(w._plant_context(), w._model.object_bodies[0]).translation()
    assert X[0] > 4.0, f"the removed box is at {X}, not on the parking shelf"


def test_rewind_to_a_checkpoint_replays_a_grasp_the_same_way():
    """The execution-settings study runs one attempt twice from one state: after `rewind`,
    time, object poses, the hand and what is frozen are as they were at `checkpoint`."""
    w = two_object_world()
    w.advance(0.4)
    checkpoint, t0, before = w.checkpoint(), w.time_s, positions(w)
    asleep = sorted(w.asleep_objects())
    runs = []
    for _ in range(2):
        ok, message = w.move_tcp(pose(R_TOP_DOWN, (*RIGHT, TABLE_HEIGHT_M + 0.09)), 0.25)
        assert ok, message
        w.command_fingers(0.0, 0.1, 40.0)
        w.advance(0.4)
        runs.append((w.time_s, positions(w), w.tcp_pose().copy(), w.finger_width_m()))
        w.rewind(checkpoint)
        assert w.time_s == pytest.approx(t0)
        assert sorted(w.asleep_objects()) == asleep
        for name, p in before.items():
            np.testing.assert_array_equal(positions(w)[name], p)
    (t_a, p_a, X_a, width_a), (t_b, p_b, X_b, width_b) = runs
    assert t_a == pytest.approx(t_b)
    assert width_a == pytest.approx(width_b, abs=1e-6) and width_a < 0.06  # closed on the cylinder
    np.testing.assert_allclose(X_a, X_b, atol=1e-9)
    for name in p_a:
        np.testing.assert_allclose(p_a[name], p_b[name], atol=1e-6)
