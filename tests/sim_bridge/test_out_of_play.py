"""Objects out of play (sim_bridge.world.out_of_play) leave the physics: the two ways
12 procedural_v4 rounds ended in "SceneGraph encountered a non-finite value"
(sim_bridge/doc/results.md), each cut down to one object and a few simulated seconds."""
import numpy as np
import pytest
from pydrake.multibody.math import SpatialVelocity

from sim_bridge.physics.objects import procedural_object
from sim_bridge.physics.scenes import TABLE_HEIGHT_M
from sim_bridge.world import SceneConfig, SimWorld, WorldSettings, pose
from sim_bridge.world.out_of_play import PARKING_M

pytestmark = pytest.mark.drake


def one_object_world(spec):
    X = pose(p=(0.15, 0.15, TABLE_HEIGHT_M + spec.collision_mesh().extents[2] / 2 + 0.001))
    return SimWorld(SceneConfig(objects=((spec, X),)), WorldSettings())


def body_state(world):
    """(position, |v|, |w|) of the world's one object, whatever the world reports of it."""
    plant, pc = world._model.plant, world._plant_context()
    body = world._model.object_bodies[0]
    V = plant.EvalBodySpatialVelocityInWorld(pc, body)
    return (plant.EvalBodyPoseInWorld(pc, body).translation(), np.linalg.norm(V.translational()),
            np.linalg.norm(V.rotational()))


def test_a_removed_light_box_stays_at_rest_out_of_play():
    """Dropped 0.2 m onto the old parking shelf, this 0.1 kg box (the box of procedural_v4's
    box_with_handle) was thrown back up at 20 m/s and 250 rad/s, 0.19 s after removal."""
    world = one_object_world(procedural_object("box", (0.1021, 0.0448, 0.0621), mass_kg=0.1))
    (name,) = world.object_names()
    checkpoint = world.checkpoint()
    world.remove_object(name)
    world.advance(0.3)
    p, v, w = body_state(world)
    np.testing.assert_allclose(p, PARKING_M, atol=1e-4)
    assert v < 0.02 and w == 0.0  # at most one step of gravity (1 ms: 1 cm/s) before it is held again
    assert world.object_states() == [] and not world.needs_stepping()
    world.rewind(checkpoint)  # back in play, on the table, as before the removal
    world.advance(0.1)
    (state,) = world.object_states()
    assert not state.out_of_workspace and abs(state.height_above_table_m) < 3e-3


def test_an_object_thrown_off_the_table_spinning_is_taken_out_of_play():
    """A thin capsule spinning in free fall spins up (Drake's discrete step) until its pose
    goes non-finite: at 300 rad/s within 3 s. procedural_v4's pile_006 had two such objects
    roll off the table and fall for 36 s. Here it is out of play within a few steps of
    leaving the table, still reported as off the table (the benchmark's fell_off)."""
    capsule = procedural_object("capsule", (0.0268, 0.1722), mass_kg=1.5)
    world = one_object_world(capsule)
    plant, pc = world._model.plant, world._plant_context()
    plant.SetFreeBodySpatialVelocity(pc, world._model.object_bodies[0],
                                     SpatialVelocity(np.array([250.0, 150.0, 50.0]), np.array([0.0, 4.0, 1.0])))
    world.advance(3.0)  # old code: RuntimeError (SceneGraph encountered a non-finite value)
    (state,) = world.object_states()
    assert state.out_of_workspace and not state.in_hand
    p, v, w = body_state(world)
    assert np.isfinite(p).all() and v < 0.02 and w == 0.0
