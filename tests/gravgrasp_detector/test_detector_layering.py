"""gravgrasp_detector's sub-packages import downwards only (gravgrasp_detector/gravgrasp_detector/
__init__.py): perception and calibration at the bottom, training and execution on perception,
tools on training, ros on top. Only ros talks to ROS. Read from the source with `ast`, so an
import inside a function counts."""

import pathlib
import sys

import pytest
from import_graph import layering_violations  # tests/support

PACKAGE_DIR = pathlib.Path(__file__).resolve().parents[2] / "gravgrasp_detector" / "gravgrasp_detector"
PLUMBING = {"poses", "atomic_files", "problem_log"}  # shared modules at the top; they import no sub-package
ALLOWED = {  # sub-package -> the sub-packages it may import (besides itself and PLUMBING)
    "perception": set(),
    "calibration": set(),
    "training": {"perception"},
    "execution": {"perception"},
    "tools": {"perception", "training"},
    "ros": {"perception", "execution", "calibration"},
}
# rclpy, the ROS message and service packages the project uses, and the ROS runtime's helpers.
ROS_MODULES = ("rclpy", "sensor_msgs", "geometry_msgs", "std_msgs", "std_srvs", "gravgrasp_msgs",
               "builtin_interfaces", "visualization_msgs", "rcl_interfaces", "ament_index_python")


def _modules():
    return sorted(p for p in PACKAGE_DIR.rglob("*.py"))


def test_every_module_sits_in_a_known_sub_package_or_is_plumbing():
    stray = [p.name for p in PACKAGE_DIR.glob("*.py") if p.stem not in PLUMBING | {"__init__"}]
    assert not stray, f"flat modules in gravgrasp_detector/gravgrasp_detector (move them into a sub-package): {stray}"
    subs = {p.name for p in PACKAGE_DIR.iterdir() if p.is_dir() and p.name != "__pycache__"}
    assert subs == set(ALLOWED), subs
    nested = [str(p.relative_to(PACKAGE_DIR)) for p in PACKAGE_DIR.glob("*/*/*.py")]
    assert not nested, f"one level of sub-packages only: {nested}"


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(PACKAGE_DIR)))
def test_imports_point_down(path):
    wrong = layering_violations(path, PACKAGE_DIR, ALLOWED, PLUMBING, ROS_MODULES)
    assert not wrong, "\n".join(wrong)


def test_the_check_sees_a_bad_import(tmp_path, monkeypatch):
    """The check itself: an upward import in perception and a ROS import in execution are
    caught, both inside functions."""
    fake = tmp_path / "gravgrasp_detector"
    (fake / "perception").mkdir(parents=True)
    (fake / "execution").mkdir(parents=True)
    up = fake / "perception" / "bad.py"
    up.write_text("def f():\n    from ..execution.executor import GraspExecutor\n")
    ros = fake / "execution" / "bad.py"
    ros.write_text("def f():\n    import rclpy  # lazy: not here\n")
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE_DIR", fake)
    with pytest.raises(AssertionError, match="perception may import nothing"):
        test_imports_point_down(up)
    with pytest.raises(AssertionError, match="only gravgrasp_detector.ros talks to ROS"):
        test_imports_point_down(ros)
