"""Skip marks for tests that need the paper's baselines' files (shared/baselines: the Panda
hand, VGN's and VN-EdgeGraspNet's weights). CI has them beside the clone; a clone without them
skips, saying where."""
import pytest

from sim_bridge.physics import panda_hand
from sim_bridge.physics.baseline_files import BaselineFileMissing, baseline_file, baselines_dir


def _have(relative_path: str) -> bool:
    try:
        baseline_file(relative_path)
        return True
    except BaselineFileMissing:
        return False


needs_panda = pytest.mark.skipif(not _have(panda_hand.URDF), reason=f"no panda_hand/ under {baselines_dir()}")

# VN-EdgeGraspNet's four published checkpoints (vn_edge_grasp/<part>-ckpt-105.pt)
VN_EDGE_FILES = tuple(f"vn_edge_grasp/{part}-ckpt-105.pt"
                      for part in ("local_emd_model", "global_emd_model", "classifier_model", "std"))
needs_vn_edge = pytest.mark.skipif(not all(map(_have, VN_EDGE_FILES)),
                                   reason=f"no vn_edge_grasp/ checkpoints under {baselines_dir()}")
