"""The benchmark's clear_hand (benchmark.methods.hand_clearing): a from_candidates step
of the detection that publishes the grasps the open hand can reach."""
import numpy as np
import torch

from gravgrasp_detector.execution import executor as grasp_execution
from gravgrasp_detector.perception import detection, hand_clearance
from sim_bridge.benchmark.methods import hand_clearing

from tabletop_grid import R, VS, table_grid  # noqa: F401  (tests/support)


def top_down_channels(index):
    """Rotation channels (ex-ez) for a top-down grasp: approach -z, fingers close along y."""
    return torch.tensor([1.0, 0.0, 0.0, 0.0, 0.0, -1.0]).repeat(len(index), 1)


def test_clear_hand_publishes_the_neighbour_the_open_hand_can_reach():
    # A lid 6 cm above the table top: the housing of a top-down grasp at k=8 meets it,
    # one voxel higher it clears it. By the paper's steps the deeper grasp (9 N) suppresses
    # its neighbour (8.5 N) in NMS and is the only one published, which the executor then
    # refuses; the benchmark's clear_hand (a from_candidates step) publishes the neighbour instead.
    grid = table_grid().clone()
    grid[14:27, 14:27, 16] = 0.3
    score, validness = torch.zeros(R, R, R), torch.ones(R, R, R)
    score[20, 20, 8], score[20, 20, 9] = 9.0, 8.5

    def run(grid, clear_hand=False):
        options = detection.DetectionOptions(min_surface_voxels=0)
        steps = (lambda g, candidate, ranked, poses_at: hand_clearing.clear_hand(
            g, candidate, ranked, poses_at, VS, options.nms_radius_voxels)) if clear_hand else None
        return detection.select_grasps(grid, score, validness, top_down_channels, "ex-ez", VS, (0.1, 0.0, 0.0), options,
                                       from_candidates=steps)

    assert [g.voxel_index for g in run(grid)] == [(20, 20, 8)]
    (clear,) = run(grid, clear_hand=True)
    assert clear.voxel_index == (20, 20, 9) and clear.score_n == 8.5
    # the executor's own check agrees (task frame: the grid's origin at x = 0.1 m)
    tsdf = (grid.numpy(), VS, np.array([0.1, 0.0, 0.0]))
    assert not hand_clearance.first_collision(grasp_execution.plan_poses(clear.pose, 0.05, 0.1), tsdf)
    X_deep = grasp_execution.plan_poses(run(grid)[0].pose, 0.05, 0.1)
    assert "housing" in hand_clearance.first_collision(X_deep, tsdf)
    # a lid one voxel higher blocks both: nothing is published rather than a grasp the hand cannot reach
    low = table_grid().clone()
    low[14:27, 14:27, 17] = 0.3
    assert run(low, clear_hand=True) == []
