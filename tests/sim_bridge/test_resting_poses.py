"""Sampling where the grasp will be used: resting poses of objects on a table
(trimesh prior confirmed by a Drake settle) and grasp candidates per resting pose,
approach inside the executor's cone, open hand clear of the table."""

import numpy as np
import pytest

from sim_bridge.datagen.antipodal_sampling import SamplingSettings, sample_grasp_candidates, sample_grasp_candidates_at_rest
from sim_bridge.datagen.resting_poses import find_resting_poses
from sim_bridge.physics import hand_collision
from sim_bridge.physics.objects import procedural_object
from sim_bridge.physics.scenes import TABLE_HEIGHT_M, arrange

pytestmark = pytest.mark.drake

RESTING = SamplingSettings(sampler="resting")


@pytest.fixture(scope="module")
def box():
    return procedural_object("box", (0.04, 0.06, 0.10), mass_kg=0.3)


@pytest.fixture(scope="module")
def box_rest(box):
    return find_resting_poses(box)


def test_a_box_rests_on_each_pair_of_faces_with_more_weight_on_the_largest(box, box_rest):
    # up to yaw the box has 3 distinct poses (a face and its opposite are congruent)
    assert len(box_rest) == 3
    assert abs(box_rest.probability.sum() - 1) < 1e-9 and box_rest.confirmed.all()
    ups = np.abs(box_rest.up_object())
    assert np.allclose(np.sort(ups, axis=1)[:, :2], 0, atol=1e-6)  # up is a face normal
    axis_of = ups.argmax(axis=1)
    assert sorted(axis_of) == [0, 1, 2]
    # lying on its largest face (0.06 x 0.10, normal x) is the most likely
    assert axis_of[np.argmax(box_rest.probability)] == 0
    # the pose puts the box on the plane z = 0
    for X in box_rest.X_table_object:
        v = box.collision_mesh().vertices @ X[:3, :3].T + X[:3, 3]
        assert abs(v[:, 2].min()) < 1e-9


def test_a_cylinder_lies_on_its_side_or_stands_and_its_facets_merge():
    cyl = procedural_object("cylinder", (0.03, 0.14), mass_kg=0.3)
    rest = find_resting_poses(cyl)
    assert len(rest) == 2
    up = rest.up_object()
    side = np.argmax(rest.probability)
    assert abs(up[side, 2]) < 0.2          # on its side: the axis is horizontal
    assert abs(abs(up[1 - side, 2]) - 1) < 1e-3


def test_candidates_at_rest_approach_from_above_and_clear_the_table(box, box_rest):
    X, pose = sample_grasp_candidates_at_rest(box.collision_mesh(), box_rest, 48, 3, RESTING)
    assert len(X) == 48 and pose.shape == (48,)
    X_rest = box_rest.X_table_object[pose] @ X
    angle_from_down = np.degrees(np.arccos(np.clip(-X_rest[:, 2, 2], -1, 1)))
    assert angle_from_down.max() <= RESTING.approach_cone_deg + 1e-6
    assert (hand_collision.lowest_point_z(X_rest, RESTING.approach_m) >= 0).all()
    pts = hand_collision.surface_points(box.collision_mesh())
    assert not hand_collision.collides(X, pts, approach_m=RESTING.approach_m).any()
    # the most likely pose gets the most candidates
    assert np.bincount(pose, minlength=3).argmax() == np.argmax(box_rest.probability)
    # deterministic for a seed
    X2, pose2 = sample_grasp_candidates_at_rest(box.collision_mesh(), box_rest, 48, 3, RESTING)
    np.testing.assert_array_equal(X, X2)
    np.testing.assert_array_equal(pose, pose2)


def test_candidates_at_rest_keep_the_closed_fingers_above_the_table():
    """Closing moves the pad tips up to 13.5 mm past the open hand's: on a flat box the
    open-hand check alone lets some candidates close a pad onto the table."""
    flat = procedural_object("box", (0.03, 0.06, 0.10), mass_kg=0.3)
    rest = find_resting_poses(flat)
    pts = hand_collision.surface_points(flat.collision_mesh())

    def lowest_closed_tip_z(settings):
        X, pose = sample_grasp_candidates_at_rest(flat.collision_mesh(), rest, 48, 3, settings)
        assert len(X) == 48
        opening = hand_collision.closing_opening_m(X, pts, np.full(len(X), 0.085))
        assert (opening > 0.05).mean() > 0.5  # mostly across the 60 mm side, not the 30 mm height
        return hand_collision.closed_tips_lowest_z(rest.X_table_object[pose] @ X, opening)

    checked = lowest_closed_tip_z(RESTING)
    unchecked = lowest_closed_tip_z(SamplingSettings(sampler="resting", closed_tips_above_table=False))
    # (the sampler judges the opening before the depth and tilt: within a millimetre)
    assert checked.min() > -0.001 and (unchecked < -0.001).sum() >= 2


def test_resting_candidates_survive_the_table_more_often_than_free_ones(box, box_rest):
    """Why the resting sampler exists: the same number of candidates, every one judged
    in every resting pose (weighted by probability), as a scene projects a table."""
    free = sample_grasp_candidates(box.collision_mesh(), 48, 3)
    at_rest, _ = sample_grasp_candidates_at_rest(box.collision_mesh(), box_rest, 48, 3, RESTING)

    def table_free_share(X):
        share = [np.mean(hand_collision.lowest_point_z(T[None] @ X, RESTING.approach_m) >= 0)
                 for T in box_rest.X_table_object]
        return float(box_rest.probability @ share)

    assert table_free_share(at_rest) > table_free_share(free) + 0.15


def test_packed_scenes_place_objects_in_their_resting_poses(box, box_rest):
    rng = np.random.default_rng(5)
    keep, poses = arrange([box, box], "packed", rng, rest=[box_rest, box_rest])
    assert keep == [0, 1]
    ups = box_rest.up_object()
    for X in poses:
        up = X[2, :3]                      # table up in the object frame, after settling
        assert (ups @ up).max() > np.cos(np.deg2rad(5))
        v = box.collision_mesh().vertices @ X[:3, :3].T + X[:3, 3]
        assert abs(v[:, 2].min() - TABLE_HEIGHT_M) < 3e-3
