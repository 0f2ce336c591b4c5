"""Paper Eq. 1 on hand-computed cases."""

import numpy as np
import pytest

from sim_bridge.physics.gravity_projection import GRAVITY_PROJECTION_EPS, gravity_rejection_score

SCORES = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])  # +x -x +y -y +z -z


def rot_x(deg):
    c, s = np.cos(np.deg2rad(deg)), np.sin(np.deg2rad(deg))
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def test_tcp_aligned_with_scene_loads_minus_z_only():
    # gravity (0,0,-1) is the TCP's -z direction: f_g = f_-z / 1
    assert gravity_rejection_score(SCORES, np.eye(3)) == pytest.approx(6.0)


def test_top_down_grasp_loads_plus_z():
    # approach pointing down (TCP z = -task z): gravity pulls the object along +z_tcp
    assert gravity_rejection_score(SCORES, rot_x(180)) == pytest.approx(5.0)


def test_tilted_grasp_divides_by_cosine_and_takes_min():
    # Rx(45): R^T g = (0, -0.7071, -0.7071): -y and -z loaded, each with cos 0.7071
    # f_g = min(4, 6) / 0.7071 = 5.657
    assert gravity_rejection_score(SCORES, rot_x(45)) == pytest.approx(4.0 / np.sqrt(0.5))
    weak_z = SCORES.copy()
    weak_z[5] = 1.0  # now -z is the weak direction: 1 / 0.7071
    assert gravity_rejection_score(weak_z, rot_x(45)) == pytest.approx(np.sqrt(2.0))


def test_directions_within_eps_of_perpendicular_are_ignored():
    # Rx(88): cos(-z) = cos 88 = 0.0349 < eps, cos(-y) = sin 88 = 0.9994
    assert np.cos(np.deg2rad(88)) < GRAVITY_PROJECTION_EPS
    scores = SCORES.copy()
    scores[5] = 0.01  # nearly perpendicular, must not decide the min
    assert gravity_rejection_score(scores, rot_x(88)) == pytest.approx(4.0 / np.sin(np.deg2rad(88)))
    # with eps = 0 it would: 0.01 / 0.0349
    assert gravity_rejection_score(scores, rot_x(88), eps=0.0) == pytest.approx(
        0.01 / np.cos(np.deg2rad(88)))


def test_custom_gravity_direction():
    # gravity along task +x with identity rotation loads only +x
    assert gravity_rejection_score(SCORES, np.eye(3), n_g=[2.0, 0, 0]) == pytest.approx(1.0)


def test_batch_matches_single_and_is_never_empty():
    rng = np.random.default_rng(0)
    q, _ = np.linalg.qr(rng.normal(size=(200, 3, 3)))
    q *= np.sign(np.linalg.det(q))[:, None, None]
    scores = rng.uniform(0.0, 30.0, (200, 6))
    batch = gravity_rejection_score(scores, q)
    single = [gravity_rejection_score(s, r) for s, r in zip(scores, q)]
    np.testing.assert_allclose(batch, single)
    assert np.isfinite(batch).all()
    # bounded by the strongest loaded axis: some cos >= 1/sqrt(3)
    assert (batch <= scores.max(axis=1) * np.sqrt(3) + 1e-9).all()


def test_shape_mismatch_is_a_clear_error():
    with pytest.raises(ValueError, match="shapes"):
        gravity_rejection_score(np.ones(5), np.eye(3))
