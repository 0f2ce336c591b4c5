"""sim_bridge's sub-packages import downwards only (sim_bridge/sim_bridge/__init__.py):
physics at the bottom, then datagen and world side by side, benchmark, ros and analysis,
studies on top. Only ros talks to ROS; nothing imports studies, and only studies import
analysis. The benchmark holds the pipeline alone; studies are not installed executables.
Read from the source with `ast`, so an import inside a function counts."""

import ast
import pathlib
import sys

import pytest
from import_graph import layering_violations, module_imports, sub_package  # tests/support

PACKAGE_DIR = pathlib.Path(__file__).resolve().parents[2] / "sim_bridge" / "sim_bridge"
PLUMBING = {"parallel"}  # shared modules at the top; they import no sub-package
ALLOWED = {  # sub-package -> the sub-packages it may import (besides itself and PLUMBING)
    "physics": set(),
    "datagen": {"physics"},
    "world": {"physics"},
    "benchmark": {"physics", "datagen", "world"},
    "ros": {"physics", "world", "benchmark"},
    "analysis": {"physics", "datagen", "world", "benchmark"},  # only studies import analysis
    "studies": {"physics", "datagen", "world", "benchmark", "analysis"},  # and no sub-package imports studies
}
# the benchmark's modules: the pipeline that runs and reports rounds (analysis of the
# rounds lives in analysis/, the lever variants in studies/)
BENCHMARK_PIPELINE = {"clutter_benchmark", "rounds", "protocol", "sim_cell", "clearing", "report", "paired",
                      "failed_rounds", "machine", "results_table", "paper_claims", "baselines_figure", "bench_round",
                      "qualitative", "run_files"}
ROS_MODULES = ("rclpy", "sensor_msgs", "geometry_msgs", "std_msgs", "gravgrasp_msgs", "builtin_interfaces")


def _modules():
    return sorted(p for p in PACKAGE_DIR.rglob("*.py"))


def _imports(path: pathlib.Path):
    return module_imports(path, PACKAGE_DIR.parent)


def _sub_package(path: pathlib.Path):
    return sub_package(path, PACKAGE_DIR)


def test_every_module_sits_in_a_known_sub_package_or_is_plumbing():
    stray = [p.name for p in PACKAGE_DIR.glob("*.py") if p.stem not in PLUMBING | {"__init__"}]
    assert not stray, f"flat modules in sim_bridge/sim_bridge (move them into a sub-package): {stray}"
    subs = {p.name for p in PACKAGE_DIR.iterdir() if p.is_dir() and p.name != "__pycache__"}
    assert subs == set(ALLOWED), subs


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(PACKAGE_DIR)))
def test_imports_point_down(path):
    wrong = layering_violations(path, PACKAGE_DIR, ALLOWED, PLUMBING, ROS_MODULES)
    own = _sub_package(path)
    wrong += [f"line {line}: {module} (use the names sim_bridge.world exports, not its modules)"
              for module, line in _imports(path)
              if module.startswith("sim_bridge.world.") and own not in ("world", None)]
    assert not wrong, "\n".join(wrong)


def test_nothing_imports_the_studies():
    """The pipeline runs without the studies: no sub-package may import them, and no module
    of the other packages does either."""
    assert not [sub for sub, allowed in ALLOWED.items() if "studies" in allowed]
    wrong = [f"{p}:{line}: {module}" for p in _modules() if _sub_package(p) != "studies"
             for module, line in _imports(p) if module.startswith("sim_bridge.studies")]
    for package in ("gravgrasp_detector", "robotiq_driver"):  # absolute imports only reach sim_bridge
        for p in (PACKAGE_DIR.parents[1] / package / package).rglob("*.py"):
            for node in ast.walk(ast.parse(p.read_text(), str(p))):
                names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                         else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
                wrong += [f"{p}:{node.lineno}: {n}" for n in names if n.startswith("sim_bridge.studies")]
    assert not wrong, "\n".join(wrong)


def test_the_check_sees_an_import_of_a_study(tmp_path, monkeypatch):
    fake = tmp_path / "sim_bridge"
    (fake / "benchmark").mkdir(parents=True)
    bad = fake / "benchmark" / "bad.py"
    bad.write_text("from ..studies.refusal_study import main\n")
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE_DIR", fake)
    with pytest.raises(AssertionError, match="benchmark may import"):
        test_imports_point_down(bad)


def test_the_check_sees_a_bad_import(tmp_path, monkeypatch):
    """The check itself: an upward import in physics is caught."""
    fake = tmp_path / "sim_bridge"
    (fake / "physics").mkdir(parents=True)
    bad = fake / "physics" / "bad.py"
    bad.write_text("def f():\n    from ..world.sim_world import SimWorld\n")
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE_DIR", fake)
    with pytest.raises(AssertionError, match="physics may import nothing"):
        test_imports_point_down(bad)


def test_only_the_studies_import_the_analysis_tools():
    wrong = [f"{p}:{line}: {module}" for p in _modules() if _sub_package(p) not in ("analysis", "studies")
             for module, line in _imports(p) if module.startswith("sim_bridge.analysis")]
    assert not wrong, "\n".join(wrong)
    assert [sub for sub, allowed in ALLOWED.items() if "analysis" in allowed] == ["studies"]


def test_the_benchmark_holds_the_pipeline_and_its_methods_only():
    modules = {p.stem for p in (PACKAGE_DIR / "benchmark").glob("*.py")} - {"__init__"}
    assert modules == BENCHMARK_PIPELINE, f"analysis belongs in sim_bridge/analysis: {sorted(modules - BENCHMARK_PIPELINE)}"
    registry = (PACKAGE_DIR / "benchmark" / "methods" / "__init__.py").read_text()
    for variant in ("ours_sure", "ours_expected", "ours_masked", "ours_told", "ours_mass", "binary_scored"):
        assert f'"{variant}"' not in registry, f"{variant} is a study's variant: register it from the study"


def test_no_study_or_analysis_tool_is_an_installed_executable():
    """They run as `python -m sim_bridge.studies.<name>` / `sim_bridge.analysis.<name>`."""
    setup = (PACKAGE_DIR.parent / "setup.py").read_text()
    installed = [line for line in setup.splitlines() if "= sim_bridge." in line]
    assert installed and not [line for line in installed if "sim_bridge.studies." in line or "sim_bridge.analysis." in line]
