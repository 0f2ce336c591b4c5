"""The executor's held/not-held verdict against Drake ground truth, in simulated time.

Replays "attempt 2" of issue 17 deterministically: `make demo` (seed 1) executed grasp
#2 (37.4 N) on the 37 g cylinder obj002 after obj001 was taken out. The fingertips
pinched it at 6.7 mm; during the lift it slid out and the fingers closed on to 3.7 mm,
where they touch each other (folded, not at the 1.1 mm where they meet from open), and
the gripper kept reporting an object (gOBJ 2). A fixed 3 mm limit called that SUCCESS;
the empty-closed calibration calls it DROPPED, and the ground truth agrees.
"""
import numpy as np
import pytest

from gravgrasp_detector.execution import executor as ge
from sim_bridge.benchmark.sim_cell import SimArm, SimGripper
from sim_bridge.world import SceneConfig, SimWorld, WorldSettings

pytestmark = pytest.mark.drake

ATTEMPT_2_POSE = [0.18374999589286745, 0.16874999622814357, 0.1762499960605055,
                  0.8358444544943904, -0.242684961399421, -0.47382294037862444, -0.13401447150398044]


@pytest.fixture(scope="module")
def world():
    w = SimWorld(SceneConfig(seed=1, n_objects=3, arrangement="packed"), WorldSettings())
    assert w.object_names() == ["obj000_cylinder", "obj001_cylinder", "obj002_cylinder"]
    w.remove_object("obj001_cylinder")  # lifted in attempt 1
    return w


def test_fingertip_pinch_that_slips_out_is_dropped_not_success(world):
    X = ge.pose_to_matrix(ATTEMPT_2_POSE[:3], ATTEMPT_2_POSE[3:])
    executor = ge.GraspExecutor(SimArm(world), lambda: SimGripper(world), ge.ExecutionLimits(arm_timeout_s=60.0))
    executor.arm_motion(True)
    outcome = executor.execute(X)
    # The sim's fingers meet at 1.1 mm when closing on nothing from open.
    assert executor.calibration.width_m == pytest.approx(0.0011, abs=0.0005)
    assert outcome.code == ge.ResultCode.DROPPED, outcome.message
    assert "3.7 mm" in outcome.message and "where they close on nothing" in outcome.message
    world.advance(1.0)
    held = [s.name for s in world.object_states() if s.in_hand]
    assert held == [], f"the ground truth says {held} is still in the hand"
    assert np.isclose(world.finger_width_m(), 0.0037, atol=0.0005)  # still 3.7 mm, gOBJ 2: only the calibration tells
