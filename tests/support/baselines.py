"""Skip marks for tests that need the paper's baselines' files (shared/baselines: the Panda
hand, VGN's weights). CI has them beside the clone; a clone without them skips, saying where."""
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
