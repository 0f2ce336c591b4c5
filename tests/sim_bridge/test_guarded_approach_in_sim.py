"""The executor's guarded approach (ExecutionLimits.close_on_contact_within_m) in Drake.

A grasp commanded 4 mm too deep for a standing cylinder: the palm lands on its top before
the TCP reaches the grasp pose, and the arm's contact stop (60 N) halts the approach.
Without the guard the executor backs out (UNREACHABLE, a jam in the benchmark); with it,
the hand closes 1 mm back from where it stopped and lifts the cylinder.
"""
import pytest

from gravgrasp_detector.execution import executor as ge
from sim_bridge.benchmark.sim_cell import SimArm, SimGripper
from sim_bridge.physics.objects import procedural_object
from sim_bridge.physics.scenes import TABLE_HEIGHT_M
from sim_bridge.world import R_TOP_DOWN, SceneConfig, SimWorld, WorldSettings, pose

pytestmark = pytest.mark.drake

CENTRE = (0.15, 0.15)
HEIGHT_M = 0.12
PALM_BEHIND_TCP_M = 0.055  # where the palm meets an object's top, from the TCP (test_world)
TOO_DEEP_M = 0.004


def run(close_on_contact_within_m):
    cylinder = procedural_object("cylinder", (0.05, HEIGHT_M), mass_kg=0.3)
    world = SimWorld(SceneConfig(objects=((cylinder, pose(p=(*CENTRE, TABLE_HEIGHT_M + HEIGHT_M / 2 + 0.001))),)),
                     WorldSettings())
    limits = ge.ExecutionLimits(arm_timeout_s=60.0, empty_closed_width_m=0.0011,
                                close_on_contact_within_m=close_on_contact_within_m)
    executor = ge.GraspExecutor(SimArm(world), lambda: SimGripper(world), limits)
    executor.arm_motion(True)
    X = pose(R_TOP_DOWN, (*CENTRE, TABLE_HEIGHT_M + HEIGHT_M - PALM_BEHIND_TCP_M - TOO_DEEP_M))
    return executor.execute(X), world


def test_without_the_guard_the_palm_on_the_top_backs_out():
    outcome, world = run(0.0)
    assert outcome.code == ge.ResultCode.UNREACHABLE, outcome.message
    assert "stopped by contact" in outcome.message and outcome.message.endswith("backed out to the pre-grasp")
    assert not any(s.in_hand for s in world.object_states())


def test_with_the_guard_the_hand_closes_where_the_palm_stopped_and_lifts():
    outcome, world = run(0.01)
    assert outcome.code == ge.ResultCode.SUCCESS, outcome.message
    assert "short of the grasp pose" in outcome.message, outcome.message
    (state,) = world.object_states()
    assert state.in_hand and state.lifted, state  # the ground truth agrees
