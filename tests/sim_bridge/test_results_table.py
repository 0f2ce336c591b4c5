"""The results table of README.md and results.md is what `python -m sim_bridge.benchmark.results_table` prints
from the committed results, and those results are the shipped models'."""

import hashlib
import json
import re
from pathlib import Path

import pytest

from sim_bridge.benchmark import results_table, run_files

ROOT = Path(__file__).resolve().parents[2]


def tabled(page: str) -> list:
    text = (ROOT / page).read_text()
    m = re.search(r"<!-- results-table: [^>]*-->\n(.*?)\n<!-- /results-table -->", text, re.S)
    assert m, f"{page} has no <!-- results-table --> block"
    return m.group(1).split("\n")


@pytest.mark.parametrize("page", ["README.md", "sim_bridge/doc/results.md"])
def test_the_pages_table_is_what_the_command_prints(page):
    assert tabled(page) == results_table.table_lines(ROOT), \
        f"{page}'s results table differs: paste `python -m sim_bridge.benchmark.results_table` into it"


def _write_runs(root, rows, comparisons):
    for _, run in results_table.RUNS:
        (root / run).mkdir(parents=True)
        (root / run / "results.json").write_text(json.dumps(rows))
        (root / run / "comparisons.json").write_text(json.dumps(comparisons))


def test_a_cell_holds_sr_interval_and_the_paired_difference_to_binary(tmp_path):
    rows = [{"method": "ours", "mass_kg": 1.5, "SR": 0.5, "SR_ci95": [0.3, 0.7], "successes": 10, "attempts": 20},
            {"method": "binary", "mass_kg": 1.5, "SR": 0.25, "SR_ci95": [0.11, 0.47], "successes": 5, "attempts": 20}]
    # the pooled z test's figures stay in results.md; the cell shows the paired per-scene one
    comparisons = [{"method": "ours", "mass_kg": 1.5, "diff": 0.25, "p_value": 0.0952,
                    "paired": {"scenes": 16, "diff": 0.2813, "ci95": [0.1, 0.4], "p_value": 0.0312}}]
    _write_runs(tmp_path, rows, comparisons)
    lines = results_table.table_lines(tmp_path)
    assert lines[0] == "| objects | method | SR 1.5 kg |"
    assert lines[2] == "| held-out meshes | **Ours** | 50.0 % (10/20; 30–70), +28.1 pts, p = 0.031 |"
    assert lines[3] == "| held-out meshes | Binary | 25.0 % (5/20; 11–47) |"
    assert len(lines) == 6


def test_the_power_grasp_effect_is_the_last_row_of_a_run_that_reported_it(tmp_path):
    """Ours − Ours-Precision per scene (power_grasp_effect.json, `benchmark --report`) under the
    run's methods, a dash where either did not run; no row for a run reported before it."""
    rows = [{"method": m, "mass_kg": w, "SR": 0.5, "SR_ci95": [0.3, 0.7], "successes": 10, "attempts": 20}
            for m in ("ours", "ours_precision") for w in (1.5, 4.0)]
    _write_runs(tmp_path, rows, [])
    effect = [{"method": "ours", "reference": "ours_precision", "mass_kg": 1.5, "diff": float("nan"), "scenes": 0},
              {"method": "ours", "reference": "ours_precision", "mass_kg": 4.0, "diff": 0.1234, "p_value": 0.0312,
               "ci95": [0.02, 0.2], "scenes": 32}]
    (tmp_path / results_table.RUNS[0][1] / "power_grasp_effect.json").write_text(json.dumps(effect))
    lines = results_table.table_lines(tmp_path)
    assert lines[4] == "| held-out meshes | Ours − Ours-Precision, per scene | — | +12.3 pts, p = 0.031 |"
    assert len(lines) == 7 and not any("procedural objects | Ours − " in line for line in lines)


def test_levers_and_weights_never_run_are_left_out_and_fewer_scenes_are_named(tmp_path):
    """Only the shipped models' rows; a weight a method never ran is a dash, not '0/0'; a
    cell on fewer scenes than the run's (0.5 kg on 16 of 32) says so."""
    def row(method, kg, rounds, successes, attempts):
        return {"method": method, "mass_kg": kg, "rounds": rounds, "SR": successes / attempts if attempts else
                float("nan"), "SR_ci95": [0.2, 0.8], "successes": successes, "attempts": attempts}
    rows = [row("ours", 0.1, 32, 30, 40), row("ours", 0.5, 16, 10, 20), row("binary", 0.1, 32, 35, 40),
            row("binary", 0.5, 16, 12, 20), row("ours_precision_sure", 0.1, 32, 36, 40),
            row("ours_precision_sure", 0.5, 0, 0, 0)]
    _write_runs(tmp_path, rows, [])
    lines = results_table.table_lines(tmp_path)
    assert lines[0] == "| objects | method | SR 0.1 kg | SR 0.5 kg |"
    assert lines[2] == "| held-out meshes | **Ours** | 75.0 % (30/40; 20–80) | 50.0 % (10/20; 20–80; 16 scenes) |"
    assert not any("ours_precision_sure" in line for line in lines) and len(lines) == 6


def test_the_tabled_runs_are_the_shipped_models():
    """Every tabled round ran the committed model file its run names: models/ or the run's
    recorded --models-dir (e.g. models/v6, under the same method names)."""
    from sim_bridge.benchmark.rounds import models_dir_of_run
    shipped = {"ours": "gravgrasp.pt", "binary": "gravgrasp_binary.pt", "ours_precision": "gravgrasp_precision_only.pt"}
    for _, run in results_table.RUNS:
        models = ROOT / models_dir_of_run(ROOT / run)
        for method, model in shipped.items():
            sha = hashlib.sha256((models / model).read_bytes()).hexdigest()
            rounds = [r for r in run_files.rounds_file(ROOT / run).records() if r["method"] == method]
            assert rounds and all(r["model_sha256"] == sha for r in rounds), \
                f"{run}'s {method} rounds were not run with the committed {models.relative_to(ROOT)}/{model}"


def test_the_figure_draws_every_shipped_method_and_baseline_on_both_object_sets(tmp_path):
    series = results_table.figure_series()
    assert list(series) == ["held-out meshes", "procedural objects"]
    for lines in series.values():
        assert [name.split(":")[0] for name, _, _ in lines] == [
            "Ours", "Binary", "Ours-Precision", "VGN (Panda)", "VN-EdgeGraspNet (Panda)", "VGN's grasps on the 2F-85"]
        assert [dashed for _, dashed, _ in lines] == [False] * 3 + [True] * 3
        assert [r["mass_kg"] for r in lines[0][2]] == [0.1, 0.5, 1.5, 4.0]
    results_table.plot(tmp_path / "f.png")
    assert (tmp_path / "f.png").read_bytes()[:4] == b"\x89PNG"
