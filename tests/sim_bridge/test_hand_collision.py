import numpy as np
import pytest
import trimesh

from sim_bridge.physics import hand_collision
from sim_bridge.physics.hand_model import MAX_STROKE_M


def top_down(p):
    """TCP at p, approaching straight down (z_tcp = -z_task)."""
    X = np.eye(4)
    X[:3, :3] = np.diag([1.0, -1.0, -1.0])
    X[:3, 3] = p
    return X


def test_points_between_the_open_pads_are_free_and_palm_collides():
    X = np.eye(4)
    inside_grip = [0.0, MAX_STROKE_M / 2 - 0.003, 0.0]
    assert not hand_collision.collides(X, np.array([inside_grip]))[0]
    assert not hand_collision.collides(X, np.array([[0.0, 0.0, 0.02]]))[0]  # beyond the tips
    on_pad = [0.0, MAX_STROKE_M / 2 + 0.005, 0.0]
    assert hand_collision.collides(X, np.array([on_pad]))[0]
    at_palm = [0.0, 0.0, hand_collision.PALM_FACE_Z_M - 0.002]
    assert hand_collision.collides(X, np.array([at_palm]))[0]


def test_approach_sweep_catches_what_the_fingers_pass_through():
    X = np.eye(4)
    beside_links = np.array([[0.0, 0.05, -0.10]])  # beside the housing, behind the fingers
    assert not hand_collision.collides(X, beside_links, approach_m=0.0)[0]
    assert hand_collision.collides(X, beside_links, approach_m=0.06)[0]


@pytest.mark.parametrize("approach_m, margin_m", [(0.0, 0.0), (0.05, 0.002)])
def test_the_indexed_check_finds_exactly_the_points_inside_any_box(approach_m, margin_m):
    """collides queries a k-d tree piece by piece; it must agree with testing every point
    against every box of the swept hand, near the boundary too."""
    rng = np.random.default_rng(3)
    box = trimesh.creation.box((0.05, 0.07, 0.12))
    box.apply_translation([0.15, 0.15, 0.11])
    pts = hand_collision.surface_points(box)
    X = np.repeat(top_down([0.15, 0.15, 0.15])[None], 600, axis=0)
    X[:, :3, 3] += rng.normal(0, 0.04, (600, 3))
    for i in range(len(X)):  # random tilts up to ~45 deg
        axis = rng.normal(size=3)
        X[i, :3, :3] = trimesh.transformations.rotation_matrix(rng.uniform(0, 0.8), axis)[:3, :3] @ X[i, :3, :3]
    boxes = hand_collision._swept_boxes(approach_m)
    lo, hi = boxes[:, 0] - margin_m, boxes[:, 1] + margin_m
    q = np.einsum("nij,nmi->nmj", X[:, :3, :3], pts[None] - X[:, None, :3, 3])  # (N, M, 3) TCP frame
    brute = ((q[:, :, None] >= lo) & (q[:, :, None] <= hi)).all(-1).any((1, 2))
    fast = hand_collision.collides(X, pts, approach_m=approach_m, margin_m=margin_m)
    assert 0.2 < brute.mean() < 0.95  # both outcomes well represented
    np.testing.assert_array_equal(fast, brute)


def test_table_plane():
    tip = hand_collision.FINGER_TIP_Z_M
    assert not hand_collision.collides(top_down([0.1, 0.1, 0.05 + tip + 0.001]), table_z_m=0.05)[0]
    assert hand_collision.collides(top_down([0.1, 0.1, 0.05 + tip - 0.002]), table_z_m=0.05)[0]
    # approaching horizontally, TCP 2 cm above the table, closing axis vertical:
    # the housing (half height 42 mm along y_tcp) hits the table
    X = np.eye(4)
    X[:3, :3] = [[0, 0, 1], [1, 0, 0], [0, 1, 0]]  # x_tcp = y_task, y_tcp = z_task, z_tcp = x_task
    X[:3, 3] = [0.1, 0.1, 0.07]
    assert hand_collision.collides(X, table_z_m=0.05)[0]


def test_batch_and_surface_points():
    import trimesh
    box = trimesh.creation.box((0.04, 0.04, 0.04))
    pts = hand_collision.surface_points(box)
    assert len(pts) > 500
    Xs = np.stack([np.eye(4), np.eye(4)])
    Xs[1, :3, 3] = [0, 0, 0.05]  # box now sits against the palm
    np.testing.assert_array_equal(hand_collision.collides(Xs, pts), [False, True])


def test_shifted_poses_match_the_direct_check():
    import trimesh
    rng = np.random.default_rng(0)
    pts = hand_collision.surface_points(trimesh.creation.cylinder(radius=0.03, height=0.1))
    q, _ = np.linalg.qr(rng.normal(size=(20, 3, 3)))
    q *= np.sign(np.linalg.det(q))[:, None, None]
    X = np.tile(np.eye(4), (20, 1, 1))
    X[:, :3, :3] = q
    X[:, :3, 3] = rng.uniform(-0.08, 0.08, (20, 3))
    offsets = np.linspace(0, 0.06, 7)
    fast = hand_collision.collides_along_approach(X, pts, offsets, approach_m=0.05, margin_m=0.002)
    for j, o in enumerate(offsets):
        Xo = X.copy()
        Xo[:, :3, 3] += o * X[:, :3, 2]
        np.testing.assert_array_equal(fast[:, j], hand_collision.collides(Xo, pts, approach_m=0.05, margin_m=0.002))
    assert fast.any() and not fast.all()


def test_the_opening_the_pads_stop_at_is_the_objects_extent_between_them():
    box = trimesh.creation.box((0.03, 0.05, 0.08))  # x, y (the closing axis below), z
    pts = hand_collision.surface_points(box)
    X = np.eye(4)
    X[:3, :3] = np.diag([1.0, -1.0, -1.0])  # approach down, closing along y
    X[2, 3] = 0.02  # 2 cm below the top face: the pads span the sides
    assert hand_collision.closing_opening_m(X, pts, [0.0])[0] == pytest.approx(0.05, abs=1e-6)
    X[2, 3] = 0.08  # 4 cm above the box: nothing between the pads, the fallback
    assert hand_collision.closing_opening_m(X, pts, [0.07])[0] == 0.07
    # closed that far, the pad tips reach hand_geometry's depth for a 50 mm opening
    low = hand_collision.closed_tips_lowest_z(X, [0.05])[0]
    assert low == pytest.approx(0.08 - hand_collision.pad_tip_z_m(0.05), abs=1e-9)


def test_point_counts_never_miss_a_point_in_a_cube():
    """The grid prefilter of collides may say "maybe" for an empty cube, never "empty" for
    a cube holding a point: on its faces, across the grid's edges and outside it."""
    rng = np.random.default_rng(5)
    P = rng.uniform(0.0, 0.2, (3000, 3))
    counts = hand_collision._PointCounts(P)
    centres = np.concatenate([rng.uniform(-0.05, 0.25, (4000, 3)), P[:500]])  # some on a point
    radii = np.concatenate([rng.uniform(0.0, 0.03, 4000), np.zeros(500)])
    inside = (np.abs(P[None] - centres[:, None]) <= radii[:, None, None]).all(-1).any(-1)
    maybe = counts.any_in_cubes(centres, radii)
    assert inside.sum() > 500 and (~inside).sum() > 1000
    assert not (inside & ~maybe).any()
    assert (maybe & ~inside).sum() < 0.5 * (~inside).sum()  # and it does skip most empty ones
    assert not counts.any_in_cubes(np.array([[1.0, 1.0, 1.0], [-1.0, 0.1, 0.1]]), np.array([0.1, 0.1])).any()
