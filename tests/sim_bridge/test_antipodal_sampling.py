import numpy as np
import trimesh

from sim_bridge.datagen.antipodal_sampling import SamplingSettings, antipodal_pairs, sample_grasp_candidates
from sim_bridge.physics import hand_collision


def test_pairs_are_on_the_surface_inside_both_friction_cones_and_fit_the_stroke():
    box = trimesh.creation.box((0.05, 0.04, 0.12))
    a, b, u = antipodal_pairs(box, 2000, np.random.default_rng(0))
    assert len(a) > 200
    half = np.array([0.025, 0.02, 0.06])
    for p in (a, b):  # on the surface: some coordinate at +-half extent, none beyond
        np.testing.assert_allclose((np.abs(p) / half).max(axis=1), 1.0, atol=1e-4)
    width = np.linalg.norm(b - a, axis=1)
    assert width.max() <= 0.085 - 0.005 + 1e-9
    # on a box the closing line must join opposite faces: the 50 mm or the 40 mm pair
    # (never the 120 mm one), tilted at most atan(0.75) from the normal
    axis = np.abs(u).argmax(axis=1)
    assert set(axis) <= {0, 1}
    cos_cone = np.cos(np.arctan(0.75))
    assert (np.abs(u).max(axis=1) >= cos_cone - 1e-9).all()


def test_candidates_are_valid_poses_clear_of_the_object_and_deterministic():
    cyl = trimesh.creation.cylinder(radius=0.025, height=0.12, sections=48)
    X = sample_grasp_candidates(cyl, 60, seed=3)
    assert X.shape == (60, 4, 4)
    R = X[:, :3, :3]
    np.testing.assert_allclose(np.einsum("nji,njk->nik", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-9)
    pts = hand_collision.surface_points(cyl, seed=1)
    assert not hand_collision.collides(X, pts, approach_m=0.05).any()
    np.testing.assert_array_equal(X, sample_grasp_candidates(cyl, 60, seed=3))
    assert not np.array_equal(X, sample_grasp_candidates(cyl, 60, seed=4))


def test_deep_insertion_yields_power_candidates():
    # a 50 mm cylinder fits between the open fingers down to the palm: a good share of
    # candidates must sit near the palm (a few mm deeper would hit it)
    cyl = trimesh.creation.cylinder(radius=0.025, height=0.12, sections=48)
    X = sample_grasp_candidates(cyl, 60, seed=3)
    pts = hand_collision.surface_points(cyl, seed=1)
    deeper = X.copy()
    deeper[:, :3, 3] += 0.012 * X[:, :3, 2]
    near_palm = hand_collision.collides(deeper, pts)
    assert 0.2 < near_palm.mean() < 0.95
    # depth of the object centre behind the TCP along the approach: spread over the fingers
    depth = np.einsum("ni,ni->n", -X[:, :3, 3], X[:, :3, 2])
    assert depth.max() - depth.min() > 0.02


def test_object_wider_than_the_stroke_everywhere_gives_no_candidates():
    big = trimesh.creation.box((0.12, 0.12, 0.12))
    assert len(antipodal_pairs(big, 2000, np.random.default_rng(0))[0]) == 0
    assert sample_grasp_candidates(big, 10, seed=0, settings=SamplingSettings(max_rounds=3)).shape == (0, 4, 4)
