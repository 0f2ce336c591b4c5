"""Deployment publishes no grasp with nothing between the fingers: the shipped model on
a rendered table-top scene, and on the same scene seen as a real depth sensor sees it
(noise growing with range, speckle dropouts and a large hole)."""
import pathlib

import numpy as np
import pytest
import trimesh

from gravgrasp_detector.perception import detection
from gravgrasp_detector.perception.model_file import load_model
from gravgrasp_detector.perception.tsdf import CameraIntrinsics, TSDFVolume
from robotiq_driver.hand_geometry import FINGER_TIP_Z_M, MAX_STROKE_M, PAD_WIDTH_M, PALM_FACE_Z_M
from sim_bridge.physics.depth_rendering import DepthRenderer, look_at

MODEL = pathlib.Path(__file__).resolve().parents[2] / "models" / "gravgrasp.pt"
SIZE = 0.30
TABLE_Z = 0.05


def scene_depth(sensor_like, seed=0):
    table = trimesh.creation.box((1.0, 1.0, 0.05))
    table.apply_translation([SIZE / 2, SIZE / 2, TABLE_Z - 0.025])
    box = trimesh.creation.box((0.05, 0.07, 0.09))
    box.apply_translation([0.10, 0.15, TABLE_Z + 0.045])
    cyl = trimesh.creation.cylinder(radius=0.03, height=0.11, sections=48)
    cyl.apply_translation([0.20, 0.16, TABLE_Z + 0.055])
    K = CameraIntrinsics(640, 480, 540.0, 540.0, 319.5, 239.5)
    T = look_at([SIZE / 2, -0.25, 0.55], [SIZE / 2, SIZE / 2, TABLE_Z])
    depth = DepthRenderer([table, box, cyl]).render(K, T)
    if sensor_like:
        rng = np.random.default_rng(seed)
        # D435-like: depth noise ~ 1 mm at 0.5 m growing with range squared, 5 % speckle
        # dropouts, and a 60 x 80 px hole (a glare or an IR shadow)
        depth = depth + rng.normal(0, 0.004 * depth**2, depth.shape) * (depth > 0)
        depth[rng.uniform(size=depth.shape) < 0.05] = 0.0
        depth[200:260, 300:380] = 0.0
    return depth.astype(np.float32), K, T


def closing_region_surface(grid, pose, voxel_size_m):
    """Brute force, independent of detection.py: observed on/behind-surface voxel centres
    between the pads of the open hand at `pose` (grid frame)."""
    n = 0
    for ijk in np.argwhere((grid > 0) & (grid <= 0.5)):
        q = pose[:3, :3].T @ ((ijk + 0.5) * voxel_size_m - pose[:3, 3])
        n += (abs(q[0]) <= PAD_WIDTH_M / 2 and abs(q[1]) <= MAX_STROKE_M / 2
              and PALM_FACE_Z_M <= q[2] <= FINGER_TIP_Z_M)
    return n


@pytest.mark.skipif(not MODEL.exists(), reason="no shipped model")
@pytest.mark.parametrize("sensor_like", [False, True], ids=["rendered", "sensor-like"])
def test_every_published_grasp_has_observed_surface_between_the_fingers(sensor_like):
    model, _ = load_model(MODEL)
    depth, K, T = scene_depth(sensor_like)
    tsdf = TSDFVolume(size_m=SIZE, resolution=model.resolution)
    tsdf.integrate(depth, K, T)
    grid = tsdf.grid()
    vs = SIZE / model.resolution
    grasps = detection.detect_grasps(model, grid, vs, options=detection.DetectionOptions(max_grasps=30))
    no_veto = detection.DetectionOptions(max_grasps=120, min_surface_voxels=0)
    unfiltered = detection.detect_grasps(model, grid, vs, options=no_veto)
    assert grasps, "the model found no grasp on two graspable objects"
    for g in grasps:
        assert closing_region_surface(grid, g.pose, vs) >= 1, f"grasp at voxel {g.voxel_index} holds nothing"
    vetoed = [g for g in unfiltered if closing_region_surface(grid, g.pose, vs) == 0]
    print(f"{'sensor-like' if sensor_like else 'rendered'}: {len(grasps)} published, "
          f"{len(vetoed)} of {len(unfiltered)} unfiltered candidates had nothing between the fingers")
    # what the veto removes never reaches the published list
    assert not {g.voxel_index for g in vetoed} & {g.voxel_index for g in grasps}
