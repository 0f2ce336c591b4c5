"""Where the paper's baselines' files are (VGN's and VN-EdgeGraspNet's weights, the Panda
hand they were made for). They are other people's data under their own licences: the
project loads them by path and never copies them into its tree.

The directory is, first found: the one passed in (a command's --baselines DIR), the
GRAVGRASP_BASELINES environment variable, or ../shared/baselines next to the project
root (GRAVGRASP_ROOT, set by ros_ws/env.sh; else the working directory)."""

from __future__ import annotations

import os
import pathlib

# file under the baselines directory -> where a user gets it
SOURCES = {
    "panda_hand": "github.com/HaojHuang/Edge-Grasp-Network, data_robot/urdfs/panda/ (VGN's Panda hand: "
                  "hand.urdf and meshes/)",
    "vgn": "github.com/ethz-asl/vgn, assets/models/vgn_conv.pth",
    "vn_edge_grasp": "github.com/HaojHuang/Edge-Grasp-Network, vn_edge_pretrained_para/checkpoints/",
}


class BaselineFileMissing(FileNotFoundError):
    """A file of the baselines is not where it was looked for."""


def baselines_dir(override: str | os.PathLike | None = None) -> pathlib.Path:
    """The baselines directory (see the module's docstring); not checked here."""
    if override:
        return pathlib.Path(override).expanduser()
    if os.environ.get("GRAVGRASP_BASELINES"):
        return pathlib.Path(os.environ["GRAVGRASP_BASELINES"]).expanduser()
    root = pathlib.Path(os.environ.get("GRAVGRASP_ROOT") or os.getcwd())
    return (root / ".." / "shared" / "baselines").resolve()


def baseline_file(relative_path: str, directory: str | os.PathLike | None = None) -> pathlib.Path:
    """The path of `relative_path` ("panda_hand/hand.urdf") under the baselines directory;
    BaselineFileMissing, saying where to get it, if it is not there."""
    path = baselines_dir(directory) / relative_path
    if not path.is_file():
        top = pathlib.PurePosixPath(relative_path).parts[0]
        source = SOURCES.get(top, "the baseline's original repository")
        raise BaselineFileMissing(
            f"baseline file {path} not found: get {relative_path} from {source} into {baselines_dir(directory)}, "
            "or point to the directory that has it (--baselines DIR or GRAVGRASP_BASELINES)")
    return path
