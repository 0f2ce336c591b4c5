"""VGN's mask (benchmark.methods.vgn.free_space_band) as a selection lever on the project's
detection (studies.detection_levers.VGN_MASKS, a restriction of the candidates): the band
it keeps, and the candidates it lets through at the voxel ("tcp") and where VGN's TCP would
sit on the approach ("finger_base")."""
import numpy as np
import pytest
import torch
from scipy import ndimage

from gravgrasp_detector.perception import detection
from sim_bridge.benchmark.methods.vgn import FINGER_BASE_Z_M, free_space_band
from sim_bridge.studies.detection_levers import VGN_MASKS

VS = 0.0075
R = 40
INSIDE_K, FREE_K = range(3, 7), range(7, 11)  # observed behind / in front of a table top


def table_grid():
    """A table top between k = 6 and 7: observed inside (0.3) below, observed free space
    (0.7, the band in front of the surface) above, 0 (unobserved, or far) elsewhere."""
    grid = np.zeros((R, R, R), np.float32)
    grid[:, :, INSIDE_K.start:INSIDE_K.stop] = 0.3
    grid[:, :, FREE_K.start:FREE_K.stop] = 0.7
    return torch.from_numpy(grid)


def test_the_band_is_free_space_and_two_steps_beyond_never_inside():
    band = free_space_band(table_grid())
    kept_k = np.flatnonzero(band[20, 20].numpy()).tolist()
    assert kept_k == [7, 8, 9, 10, 11, 12]  # free space + 2 dilations up, none into k = 3..6
    assert band.dtype == torch.bool and bool(band[:, :, 7:13].all())


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_band_is_vgns_masked_binary_dilation(seed):
    # VGN's own call (detection.py's `process`) on a random grid of the grid's values,
    # near-zero included (1e-3 is where VGN's "inside" starts)
    values = np.array([0.0, 1e-4, 2e-3, 0.3, 0.5, 0.7, 0.95], np.float32)
    grid = np.random.default_rng(seed).choice(values, size=(R, R, R), p=[0.5, 0.05, 0.05, 0.15, 0.05, 0.1, 0.1])
    inside = (grid > 1e-3) & (grid < 0.5)
    expected = ndimage.binary_dilation(grid > 0.5, iterations=2, mask=~inside)
    np.testing.assert_array_equal(free_space_band(grid).numpy(), expected)
    np.testing.assert_array_equal(free_space_band(torch.from_numpy(grid)).numpy(), expected)


def top_down_channels(index):
    """ex-ez rotation channels of a top-down grasp (approach -z) at every voxel."""
    return torch.tensor([1.0, 0.0, 0.0, 0.0, 0.0, -1.0]).repeat(len(index), 1)


# candidates: a strong one inside the table top, one on the free-space band, one far above
INSIDE, BAND, FAR = (10, 10, 4), (20, 20, 8), (30, 30, 15)


def masked(mask):
    """select_grasps' from_candidates step restricting the candidates to VGN_MASKS[mask] ("off": none)."""
    if mask == "off":
        return None
    return lambda grid, candidate, ranked, poses_at: ranked(candidate & VGN_MASKS[mask](grid, candidate, poses_at, VS))


def select(mask):
    score, validness = torch.zeros(R, R, R), torch.ones(R, R, R)
    for index, value in ((INSIDE, 9.0), (BAND, 5.0), (FAR, 7.0)):
        score[index] = value
    options = detection.DetectionOptions(min_surface_voxels=0, surface_distance_voxels=10)
    grasps = detection.select_grasps(table_grid(), score, validness, top_down_channels, "ex-ez", VS, (0, 0, 0),
                                     options, from_candidates=masked(mask))
    return [g.voxel_index for g in grasps]


def test_off_keeps_every_candidate_as_the_paper_does():
    assert select("off") == [INSIDE, FAR, BAND]


def test_at_the_tcp_only_the_candidate_on_the_band_is_kept():
    assert select("tcp") == [BAND]


def test_at_the_finger_base_the_mask_is_tested_up_the_approach():
    # a top-down grasp's finger base is FINGER_BASE_Z_M (-4.6 cm: 6.1 voxels) up the
    # approach from its TCP: above the inside candidate (k 4 -> 10) it is on the band, above
    # the band one (k 8 -> 14) and the far one (k 15 -> 21) beyond it
    assert [int(((k + 0.5) * VS - FINGER_BASE_Z_M) / VS) for k in (4, 8, 15)] == [10, 14, 21]
    assert select("finger_base") == [INSIDE]


def tilted_channels(index):
    """ex-ez channels whose approach tilts from straight down by 0-80 deg about x, by
    voxel: the finger base lands on the band for some candidates and not for others."""
    tilt = torch.deg2rad(20.0 * (index.sum(dim=1) % 5).double()).float()
    zeros, ones = torch.zeros_like(tilt), torch.ones_like(tilt)
    return torch.stack((ones, zeros, zeros, zeros, torch.sin(tilt), -torch.cos(tilt)), dim=1)


def test_finger_base_keeps_what_the_mask_keeps_at_each_candidates_own_approach():
    # smooth, as a network's outputs are; approaches tilted by voxel
    rng = np.random.default_rng(0)
    score = torch.from_numpy(ndimage.gaussian_filter(rng.random((R, R, R)), 3).astype(np.float32)) * 100
    validness = torch.from_numpy(rng.random((R, R, R)).astype(np.float32))
    options = detection.DetectionOptions(max_grasps=5)
    grid = table_grid()
    grasps = detection.select_grasps(grid, score, validness, tilted_channels, "ex-ez", VS, (0, 0, 0), options,
                                     from_candidates=masked("finger_base"))
    band = free_space_band(grid).numpy()
    bases = np.floor(np.array([g.pose[:3, 3] + FINGER_BASE_Z_M * g.pose[:3, 2] for g in grasps]) / VS).astype(int)
    assert len(grasps) == 5 and band[tuple(bases.T)].all()
    off = detection.select_grasps(grid, score, validness, tilted_channels, "ex-ez", VS, (0, 0, 0), options)
    assert [g.voxel_index for g in off] != [g.voxel_index for g in grasps]  # it took some of the paper's picks
