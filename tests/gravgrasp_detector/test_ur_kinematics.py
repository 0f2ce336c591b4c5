"""The nominal UR5e kinematics ur_arm judges the pendant's TCP with are the project's arm
model's (execution.reachability, Drake + MuJoCo Menagerie's UR5e), in the controller's frames."""
import numpy as np
import pytest

from gravgrasp_detector.execution.reachability import ArmReachability
from gravgrasp_detector.execution.ur_kinematics import flange_in_base


def test_dh_flange_is_the_arm_models_flange():
    arm = ArmReachability(tcp_offset_m=0.0)
    rng = np.random.default_rng(3)
    for q in [np.zeros(6), np.array([0.0, -1.57, 1.57, -1.57, -1.57, 0.0])] + [rng.uniform(-3, 3, 6) for _ in range(5)]:
        A, B = flange_in_base(q), arm.forward(q)
        assert np.linalg.norm(A[:3, 3] - B[:3, 3]) < 2e-3, (q, A, B)  # Menagerie's link lengths are rounded
        assert np.abs(A[:3, :3] - B[:3, :3]).max() < 2e-3
    # All joints at zero: the arm stretched along -x of the controller's base (UR's DH table).
    np.testing.assert_allclose(flange_in_base(np.zeros(6))[:3, 3], [-0.8172, -0.2329, 0.0628], atol=1e-9)


def test_bad_joint_vector_is_named():
    with pytest.raises(ValueError, match="a UR5e has 6 joints"):
        flange_in_base([0.0] * 5)
