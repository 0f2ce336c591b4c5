"""A synthetic TSDF of a bare table, shared by the detection and hand-clearing tests."""
import numpy as np
import torch

VS = 0.0075  # voxel size [m]
R = 40  # voxels per side


def table_grid():
    """A table surface between k=6 and k=7: behind-surface band below, free band above."""
    grid = np.zeros((R, R, R), np.float32)
    grid[:, :, 3:7] = 0.3
    grid[:, :, 7:11] = 0.7
    return torch.from_numpy(grid)
