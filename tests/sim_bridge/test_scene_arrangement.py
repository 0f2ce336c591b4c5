"""Packed and pile arrangements settle on the table (real Drake, gravity)."""

import numpy as np
import pytest
import trimesh

from sim_bridge.physics.objects import procedural_object
from sim_bridge.physics.scenes import (TABLE_HEIGHT_M, VOLUME_SIZE_M, SceneSettings, arrange, footprint,
                                       packed_poses, polygons_apart)

pytestmark = pytest.mark.drake


def posed_vertices(obj, X):
    v = obj.collision_mesh().vertices
    return v @ X[:3, :3].T + X[:3, 3]


def objects():
    return [procedural_object("box", (0.05, 0.06, 0.08), mass_kg=0.2),
            procedural_object("cylinder", (0.05, 0.10), mass_kg=0.2),
            procedural_object("box", (0.04, 0.04, 0.04), mass_kg=0.1)]


def test_packed_objects_stand_upright_on_the_table_apart():
    objs = objects()
    keep, poses = arrange(objs, "packed", np.random.default_rng(1))
    assert keep == [0, 1, 2]
    for i, X in zip(keep, poses):
        v = posed_vertices(objs[i], X)
        assert abs(v[:, 2].min() - TABLE_HEIGHT_M) < 0.003  # resting on the table
        assert X[2, 2] > 0.99  # still upright
        assert v[:, :2].min() >= 0 and v[:, :2].max() <= VOLUME_SIZE_M
    xy = np.array([X[:2, 3] for X in poses])
    assert min(np.linalg.norm(a - b) for k, a in enumerate(xy) for b in xy[k + 1:]) > 0.04


def test_pile_settles_inside_the_workspace_and_is_deterministic():
    objs = objects()
    keep, poses = arrange(objs, "pile", np.random.default_rng(2))
    assert len(keep) >= 1
    for i, X in zip(keep, poses):
        v = posed_vertices(objs[i], X)
        assert v[:, 2].min() > TABLE_HEIGHT_M - 0.003  # not sunk into the table
        assert v[:, :2].min() >= 0 and v[:, :2].max() <= VOLUME_SIZE_M
    # a pile rests: the lowest point of some object is on the table
    assert min(posed_vertices(objs[i], X)[:, 2].min() for i, X in zip(keep, poses)) < TABLE_HEIGHT_M + 0.003
    keep2, poses2 = arrange(objs, "pile", np.random.default_rng(2))
    assert keep2 == keep
    np.testing.assert_array_equal(np.array(poses2), np.array(poses))


def test_packed_footprints_are_polygons_so_long_objects_lying_down_fit():
    """Bounding circles made a 14 cm bar a 14 cm disc: at most two fit the 26 cm table
    area. With their footprints (convex hulls seen from above) three or more do, apart."""
    bar = trimesh.creation.box((0.14, 0.03, 0.03))
    settings = SceneSettings()
    poses = packed_poses([bar] * 4, np.random.default_rng(0), settings)
    placed = [X for X in poses if X is not None]
    assert len(placed) >= 3
    feet = [footprint((bar.vertices @ X[:3, :3].T + X[:3, 3])[:, :2]) for X in placed]
    for k, a in enumerate(feet):
        assert a.min() >= settings.margin_m - 1e-9 and a.max() <= VOLUME_SIZE_M - settings.margin_m + 1e-9
        for b in feet[k + 1:]:
            assert polygons_apart(a, b, settings.packed_gap_m)


def test_polygons_apart_reads_overlap_and_gaps():
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float) * 0.02
    assert polygons_apart(square, square + [0.025, 0.0], 0.005)        # 5 mm apart
    assert not polygons_apart(square, square + [0.024, 0.0], 0.005)    # 4 mm: too close
    assert not polygons_apart(square, square + [0.01, 0.01], 0.0)      # overlapping
    diamond = np.array([[0.0, -1], [1, 0], [0, 1], [-1, 0]]) * 0.01 + [0.04, 0.01]
    assert polygons_apart(square, diamond, 0.005) and not polygons_apart(square, diamond, 0.015)
