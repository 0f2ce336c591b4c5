"""UR5e inverse kinematics for the executor's reachability check."""
import numpy as np
import pytest

from gravgrasp_detector.execution.reachability import TWIN, ArmReachability


@pytest.fixture(scope="module")
def arm():
    # Base 0.5 m in front of the workspace corner, as in the sim bridge's default.
    X_task_base = np.eye(4)
    X_task_base[:3, 3] = [0.15, -0.45, 0.0]
    return ArmReachability(X_task_base)


def _top_down(p):
    X = np.eye(4)
    X[:3, :3] = np.diag([1.0, -1.0, -1.0])  # z (approach) down
    X[:3, 3] = p
    return X


def test_forward_then_inverse_returns_the_same_tcp_pose(arm):
    rng = np.random.default_rng(1)
    for _ in range(4):
        q = rng.uniform(-2.5, 2.5, 6)
        q[2] = rng.uniform(0.4, 2.4)  # away from the elbow singularity
        X = arm.forward(q)
        q_ik = arm.solve(X)
        assert q_ik is not None
        X_ik = arm.forward(q_ik)
        assert np.linalg.norm(X_ik[:3, 3] - X[:3, 3]) < 2e-3
        # Same orientation, or the 2F-85's 180-degree twin of it.
        err = min(np.linalg.norm(X_ik[:3, :3] - X[:3, :3]), np.linalg.norm(X_ik[:3, :3] - X[:3, :3] @ TWIN))
        assert err < 0.05
        assert np.all(q_ik >= arm.lower - 1e-9) and np.all(q_ik <= arm.upper + 1e-9)


def test_grasp_sequence_over_the_workspace_is_reachable(arm):
    grasp = _top_down([0.15, 0.15, 0.08])
    pregrasp, lift = grasp.copy(), grasp.copy()
    pregrasp[2, 3] += 0.05
    lift[2, 3] += 0.15
    result = arm.check({"pregrasp": pregrasp, "grasp": grasp, "lift": lift})
    assert result.reachable, result.message
    assert len(result.joint_positions) == 3
    # Consecutive configurations are close: no wrist flip between pre-grasp and grasp.
    assert np.abs(result.joint_positions[1] - result.joint_positions[0]).max() < 1.0


def test_pose_beyond_the_arm_is_unreachable_with_a_reason(arm):
    result = arm.check({"pregrasp": _top_down([0.15, 1.6, 0.1])})
    assert not result.reachable
    assert "pregrasp" in result.message and "m from the arm base" in result.message


def test_description_joint_axes_and_limits_are_the_ur5e_ones(arm):
    # Drake's MJCF parser drops class defaults; kinematics_mjcf restores them.
    axes = [arm.plant.GetJointByName(n).revolute_axis().tolist() for n in
            ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint",
             "wrist_3_joint")]
    assert axes == [[0, 0, 1], [0, 1, 0], [0, 1, 0], [0, 1, 0], [0, 0, 1], [0, 1, 0]]
    np.testing.assert_allclose(arm.upper, [6.28319, 6.28319, 3.1415, 6.28319, 6.28319, 6.28319])
    # Fully stretched horizontally: 0.425 + 0.392 m of links plus the wrist and tool.
    assert 0.9 < max(np.linalg.norm(arm.forward(q)[:2, 3] - arm.X_task_base[:2, 3])
                     for q in ([0, 0, 0, 0, 0, 0], [0, np.pi / 2, 0, 0, 0, 0])) < 1.3
