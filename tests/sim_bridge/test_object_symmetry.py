"""Rotational and mirror symmetries found on meshes, grasp copies, and their cache."""

import numpy as np
import pytest
import trimesh

from sim_bridge.datagen import object_symmetry
from sim_bridge.datagen.object_symmetry import (cached_symmetry_transforms, copy_scores, is_mirror, replicate,
                                                symmetry_transforms)


def surface_distance(mesh, points):
    """Unsigned distance [m] of points to a mesh surface (Open3D ray-casting scene)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)),
                        o3d.core.Tensor(np.asarray(mesh.faces, np.uint32)))
    return scene.compute_distance(o3d.core.Tensor(np.asarray(points, np.float32))).numpy()


def _check_group(mesh, T):
    assert np.allclose(T[0], np.eye(4))
    pts = mesh.sample(400, seed=3)
    for X in T:
        R = X[:3, :3]
        assert np.allclose(R.T @ R, np.eye(3), atol=1e-9) and abs(np.linalg.det(R)) == pytest.approx(1)
        np.testing.assert_allclose(X[:3, :3] @ mesh.center_mass + X[:3, 3], mesh.center_mass, atol=1e-9)
        assert surface_distance(mesh, pts @ R.T + X[:3, 3]).max() < 0.003


def test_a_box_has_its_three_half_turns():
    m = trimesh.creation.box((0.05, 0.06, 0.08))
    m.apply_transform(trimesh.transformations.rotation_matrix(0.4, [1, 2, 3]))  # not in its frame's axes
    m.apply_translation([0.01, -0.02, 0.03])
    T = symmetry_transforms(m, m.center_mass, mirrors=False)
    assert len(T) == 4
    _check_group(m, T)
    angles = sorted(np.degrees(np.arccos(np.clip((np.trace(X[:3, :3]) - 1) / 2, -1, 1))) for X in T)
    np.testing.assert_allclose(angles, [0, 180, 180, 180], atol=1e-6)
    # and its 3 mirror planes and the point reflection, after the rotations
    full = symmetry_transforms(m, m.center_mass)
    _check_group(m, full)
    assert list(is_mirror(full)) == [False] * 4 + [True] * 4
    np.testing.assert_allclose(full[:4], T)


def test_a_can_turns_about_its_axis_and_end_over_end():
    m = trimesh.creation.cylinder(radius=0.03, height=0.12, sections=48)
    T = symmetry_transforms(m, m.center_mass, mirrors=False)
    assert len(T) == object_symmetry.MAX_ROTATIONS
    _check_group(m, T)
    axes_z = [X for X in T if np.allclose(X[:3, 2], [0, 0, 1])]
    assert len(axes_z) == 24  # 15 degree steps about the axis
    full = symmetry_transforms(m, m.center_mass)
    mirrored = is_mirror(full)
    assert len(full) == object_symmetry.MAX_ELEMENTS and mirrored.sum() >= 12
    assert list(mirrored) == sorted(mirrored)  # rotations first
    _check_group(m, full)


def test_a_mug_keeps_only_the_half_turn_about_its_handle_and_an_l_block_keeps_none():
    body = trimesh.creation.cylinder(radius=0.04, height=0.10, sections=48)
    handle = trimesh.creation.box((0.03, 0.012, 0.06))
    handle.apply_translation([0.05, 0, 0])
    mug = trimesh.boolean.union([body, handle], engine="manifold") if trimesh.boolean.engines_available else \
        trimesh.util.concatenate([body, handle])
    T = symmetry_transforms(mug, mug.center_mass, mirrors=False)
    assert len(T) == 2
    np.testing.assert_allclose(T[1][:3, 0], [1, 0, 0], atol=1e-6)  # the handle's axis stays
    full = symmetry_transforms(mug, mug.center_mass)  # + the planes y = 0 and z = 0 through the handle
    _check_group(mug, full)
    assert len(full) == 4 and is_mirror(full).sum() == 2
    a, b = trimesh.creation.box((0.08, 0.03, 0.03)), trimesh.creation.box((0.03, 0.06, 0.03))
    b.apply_translation([0.025, 0.045, 0])
    L = trimesh.util.concatenate([a, b])
    assert len(symmetry_transforms(L, L.center_mass, mirrors=False)) == 1
    full = symmetry_transforms(L, L.center_mass)  # an extruded L: only its mid-plane
    assert len(full) == 2 and is_mirror(full)[1]
    np.testing.assert_allclose(full[1][:3, :3], np.diag([1.0, 1, -1]), atol=1e-9)


def test_copies_are_symmetry_major_and_keep_their_source_row():
    X = np.stack([np.eye(4)] * 3)
    X[:, 0, 3] = [1, 2, 3]
    T = np.stack([np.eye(4), np.diag([-1.0, -1, 1, 1])])
    out, src = replicate(X, T)
    assert out.shape == (6, 4, 4) and list(src) == [0, 1, 2, 0, 1, 2]
    np.testing.assert_allclose(out[3:, 0, 3], [-1, -2, -3])


def test_a_mirror_copy_is_a_proper_pose_of_the_mirrored_hand_with_x_scores_exchanged():
    rng = np.random.default_rng(0)
    X = np.eye(4)
    X[:3, :3] = trimesh.transformations.random_rotation_matrix(rng.random(3))[:3, :3]
    X[:3, 3] = [0.01, 0.02, 0.03]
    S = np.diag([1.0, -1, 1, 1])  # the plane y = 0
    out, _ = replicate(X, np.stack([np.eye(4), S]))
    copy = out[1]
    assert np.linalg.det(copy[:3, :3]) == pytest.approx(1.0)
    # the mirrored hand occupies the mirror image of the original: the TCP's y-z plane
    # (both fingers) goes to its mirror image, the approach and closing axes too
    np.testing.assert_allclose(copy[:3, 3], S[:3, :3] @ X[:3, 3])
    np.testing.assert_allclose(copy[:3, 1:3], S[:3, :3] @ X[:3, 1:3])
    np.testing.assert_allclose(copy[:3, 0], -(S[:3, :3] @ X[:3, 0]))
    scores = np.arange(12.0).reshape(2, 6)
    np.testing.assert_array_equal(copy_scores(scores, [False, True]), [[0, 1, 2, 3, 4, 5], [7, 6, 8, 9, 10, 11]])


def test_the_cache_is_reused_until_the_shape_changes(tmp_path, monkeypatch):
    m = trimesh.creation.box((0.05, 0.06, 0.08))
    T = cached_symmetry_transforms(tmp_path, "box", "sha-a", m, m.center_mass)
    assert (tmp_path / "box.npz").exists() and len(T) == 8

    def fail(*a, **k):
        raise AssertionError("recomputed")

    monkeypatch.setattr(object_symmetry, "symmetry_transforms", fail)
    np.testing.assert_array_equal(cached_symmetry_transforms(tmp_path, "box", "sha-a", m, m.center_mass), T)
    with pytest.raises(AssertionError, match="recomputed"):
        cached_symmetry_transforms(tmp_path, "box", "sha-b", m, m.center_mass)
