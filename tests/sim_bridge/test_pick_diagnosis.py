"""analysis.pick_diagnosis on a box seen from straight above: where a pick sits
(inside / band / free / unobserved, VGN's mask) and how far its approach gets before the
open hand meets the box or the table, against the analytic answer."""

import numpy as np
import pytest
import trimesh

from gravgrasp_detector.perception.hand_clearance import ROBOTIQ_2F85
from robotiq_driver.hand_geometry import FINGER_TIP_Z_M
from sim_bridge.analysis import pick_diagnosis as pd

SIZE_M, RES, TRUNC_M = 0.30, 40, 0.03
TABLE_Z, TOP_Z = 0.05, 0.10  # the box: 10 x 10 cm footprint centred at (0.15, 0.15), 5 cm tall
VOXEL = SIZE_M / RES


def box_view() -> pd.View:
    """Open3D's integration of a depth image from straight above: d = signed distance
    along the ray / truncation, clipped to [-1, 1]; voxels deeper than the truncation
    behind the surface are never integrated (weight 0)."""
    c = (np.arange(RES) + 0.5) * VOXEL
    x, y, z = np.meshgrid(c, c, c, indexing="ij")
    on_box = (np.abs(x - 0.15) < 0.05) & (np.abs(y - 0.15) < 0.05)
    sdf = z - np.where(on_box, TOP_Z, TABLE_Z)  # > 0 above the surface
    return pd.View(np.clip(sdf / TRUNC_M, -1, 1).astype(np.float32), (sdf > -TRUNC_M).astype(np.float32), VOXEL)


def top_down(x, y, z):
    X = np.eye(4)
    X[:3, :3] = np.diag([1.0, -1.0, -1.0])  # approach (TCP z) straight down
    X[:3, 3] = (x, y, z)
    return X


def box_points():
    box = trimesh.creation.box(extents=(0.10, 0.10, TOP_Z - TABLE_Z))
    return {"box": pd.sample_surface(box) + (0.15, 0.15, (TOP_Z + TABLE_Z) / 2)}


def test_surface_classes_of_a_box_seen_from_above():
    view = box_view()
    points = [(0.15, 0.15, 0.09),   # 1 cm under the top: behind the surface, in the band
              (0.15, 0.15, 0.11),   # 1 cm above the top
              (0.15, 0.15, 0.25),   # 15 cm above: seen, empty
              (0.15, 0.15, 0.06),   # 4 cm deep in the box: never integrated
              (0.15, 0.15, 0.40)]   # above the volume
    assert list(pd.surface_class(view, points)) == ["inside", "band", "free", "unobserved", "unobserved"]
    mask = pd.vgn_mask(view.grid)
    # VGN keeps voxels near observed free space, none inside and none far above
    assert [pd.vgn_keeps(view, p, mask) for p in points[:3]] == [False, True, False]


def test_diagnosis_of_picks_inside_and_above_the_box():
    view = box_view()
    inside = pd.diagnose_pick(view, top_down(0.15, 0.15, 0.09), 0.05, ROBOTIQ_2F85, {}, TABLE_Z)
    assert inside["tcp_class"] == "inside" and not inside["vgn_keeps"]
    assert inside["closing_region"]["inside"] > 0 and inside["surface_distance_mm"] < VOXEL * 1000
    # where VGN's TCP would sit, 4.6 cm back up the approach: 3.6 cm above the top, within 2
    # dilations of the band in front of it, which VGN keeps
    assert inside["vgn_keeps_base"]
    above = pd.diagnose_pick(view, top_down(0.15, 0.15, 0.25), 0.05, ROBOTIQ_2F85, {}, TABLE_Z)
    assert above["tcp_class"] == "free" and above["surface_distance_mm"] > 100
    assert not above["vgn_keeps"] and not above["vgn_keeps_base"]


def test_first_contact_of_a_top_down_approach_onto_the_box():
    # the fingertips lead: they meet the top when the TCP is FINGER_TIP_Z_M above it
    z_grasp, approach = 0.08, 0.05
    contact = pd.first_contact(top_down(0.15, 0.15, z_grasp), approach, ROBOTIQ_2F85, box_points(), TABLE_Z)
    expected = z_grasp + approach - (TOP_Z + FINGER_TIP_Z_M)
    assert contact["what"] == "box" and "distal" in contact["part"]
    assert contact["approach_m"] == pytest.approx(expected, abs=1e-3)
    assert contact["short_m"] == pytest.approx(approach - expected, abs=1e-3)


def test_first_contact_with_the_table_and_none():
    far = (0.15, -0.20)  # well away from the box
    z = 0.052
    contact = pd.first_contact(top_down(*far, z), 0.05, ROBOTIQ_2F85, box_points(), TABLE_Z)
    assert contact["what"] == "table"
    assert contact["approach_m"] == pytest.approx(z + 0.05 - (TABLE_Z + FINGER_TIP_Z_M), abs=1e-6)
    assert pd.first_contact(top_down(*far, 0.12), 0.05, ROBOTIQ_2F85, box_points(), TABLE_Z) is None
    # already touching at the pre-grasp: contact at 0
    touching = pd.first_contact(top_down(0.15, 0.15, 0.05), 0.05, ROBOTIQ_2F85, box_points(), TABLE_Z)
    assert touching["approach_m"] == 0.0 and touching["short_m"] == pytest.approx(0.05)


def test_same_pick_within_2_cm_and_30_degrees_either_way_round():
    A = top_down(0.15, 0.15, 0.10)
    half_turn = A.copy()
    half_turn[:3, :3] = A[:3, :3] @ np.diag([-1.0, -1.0, 1.0])
    assert pd.same_pick(A, half_turn)
    moved = A.copy()
    moved[0, 3] += 0.025
    assert not pd.same_pick(A, moved)
    c, s = np.cos(np.radians(40)), np.sin(np.radians(40))
    tilted = A.copy()
    tilted[:3, :3] = A[:3, :3] @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    assert not pd.same_pick(A, tilted)


def box_hulls(hand):
    """A HandGeometry's boxes as convex hulls (trimesh), keyed by part."""
    hulls = {}
    for part, (lo, hi) in zip(hand.parts, hand.open_boxes_tcp):
        hull = trimesh.creation.box(extents=hi - lo)
        hull.apply_translation((lo + hi) / 2)
        hulls[part] = hull
    return hulls


def test_first_contact_with_hulls_agrees_with_the_boxes():
    """The same geometry as hulls or as boxes: the same first contact, straight down and
    tilted 35 deg about the closing axis; and none where the box test finds none."""
    hulls, points = box_hulls(ROBOTIQ_2F85), box_points()
    c, s = np.cos(np.radians(35)), np.sin(np.radians(35))
    tilted = top_down(0.17, 0.15, 0.09)
    tilted[:3, :3] = tilted[:3, :3] @ np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    for X in (top_down(0.15, 0.15, 0.08), top_down(0.19, 0.13, 0.09), tilted):
        boxes = pd.first_contact(X, 0.05, ROBOTIQ_2F85, points, table_z_m=-1.0)
        with_hulls = pd.first_contact_hulls(X, 0.05, hulls, points)
        assert boxes is not None and with_hulls["what"] == "box" and with_hulls["part"] == boxes["part"]
        assert with_hulls["approach_m"] == pytest.approx(boxes["approach_m"], abs=2e-4)
        assert with_hulls["short_m"] == pytest.approx(0.05 - with_hulls["approach_m"], abs=2e-4)
        # the point met lies on its box's surface at the contact (given in the TCP frame at the grasp)
        q = np.array(with_hulls["point_tcp_m"]) + (0.05 - with_hulls["approach_m"]) * np.array([0, 0, 1.0])
        lo, hi = ROBOTIQ_2F85.open_boxes_tcp[ROBOTIQ_2F85.parts.index(with_hulls["part"])]
        assert np.max(np.abs(q - (lo + hi) / 2) - (hi - lo) / 2) == pytest.approx(0, abs=2e-4)
    assert pd.first_contact_hulls(top_down(0.15, -0.20, 0.30), 0.05, hulls, points) is None


def test_a_point_enters_a_moving_hull_over_one_interval():
    """A 2 cm cube 2-4 cm ahead of the TCP, moving 5 cm along z to the grasp pose: the point
    at its centre there is met when its far face arrives, after 4 cm (1 cm short); a point
    it holds at the pre-grasp at 0; one beside its path never."""
    cube = trimesh.creation.box(extents=(0.02, 0.02, 0.02))
    cube.apply_translation((0, 0, 0.03))
    s = pd.entry_along_approach([[0, 0, 0.03], [0, 0, -0.015], [0.02, 0, 0.03]], cube, 0.05)
    assert s[0] == pytest.approx(0.04) and s[1] == 0.0 and s[2] == np.inf
