"""sim_bridge/doc/levers.md's table is what `python -m sim_bridge.analysis.lever_table`
prints from the committed runs; a lever's cells come from its run's paired comparison and
its attempts lost before the lift."""

import json
import re
from pathlib import Path

import pytest

from sim_bridge.analysis import lever_table

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("tag, lines", [("lever-table", lever_table.table_lines),
                                        ("decisive-table", lever_table.decisive_lines)])
def test_the_doc_holds_what_the_command_prints(tag, lines):
    text = (ROOT / "sim_bridge/doc/levers.md").read_text()
    m = re.search(rf"<!-- {tag}: [^>]*-->\n(.*?)\n<!-- /{tag} -->", text, re.S)
    assert m, f"levers.md has no <!-- {tag} --> block"
    assert m.group(1).split("\n") == lines(ROOT), (f"levers.md's {tag} differs: run "
                                                    "`python -m sim_bridge.analysis.lever_table --write`")


def test_write_rewrites_only_the_generated_blocks(tmp_path, monkeypatch):
    doc = tmp_path / lever_table.DOC
    doc.parent.mkdir(parents=True)
    doc.write_text("intro\n<!-- lever-table: cmd -->\nold\n<!-- /lever-table -->\nmiddle\n"
                   "<!-- decisive-table: cmd -->\nold\n<!-- /decisive-table -->\nend\n")
    monkeypatch.setattr(lever_table, "BLOCKS", (("lever-table", lambda root: ["| a |", "| b |"]),
                                                ("decisive-table", lambda root: ["old"])))
    assert lever_table.write_doc(tmp_path) == ["lever-table"]
    assert doc.read_text() == ("intro\n<!-- lever-table: cmd -->\n| a |\n| b |\n<!-- /lever-table -->\nmiddle\n"
                               "<!-- decisive-table: cmd -->\nold\n<!-- /decisive-table -->\nend\n")
    assert lever_table.write_doc(tmp_path) == []
    doc.write_text("no blocks\n")
    with pytest.raises(ValueError, match="has no <!-- lever-table"):
        lever_table.write_doc(tmp_path)


def write_run(run, diffs, attempts):
    """A run as `benchmark --report` leaves it: comparisons.json (paired per scene) and
    attempts.json. diffs: {(method, kg): (diff, p)}; attempts: [(method, kg, outcome)]."""
    run.mkdir(parents=True)
    run.joinpath("comparisons.json").write_text(json.dumps([
        {"method": m, "mass_kg": kg, "diff": d, "p_value": p, "paired": {"scenes": 16, "diff": d, "p_value": p}}
        for (m, kg), (d, p) in diffs.items()]))
    rounds = [{"method": m, "mass_kg": kg, "scene_id": "packed_000", "end": "table_clear", "n_objects": 5,
               "fell_off": [], "successes": sum(o == "success" for mm, kk, o in attempts if (mm, kk) == (m, kg)), "attempts": 1}
              for m, kg in dict.fromkeys((m, kg) for m, kg, _ in attempts)]
    run.joinpath("attempts.json").write_text(json.dumps({"rounds": rounds, "attempts": [
        {"method": m, "mass_kg": kg, "scene_id": "packed_000", "outcome": o, "reason": ""} for m, kg, o in attempts]}))


def test_a_lever_meets_the_targets_its_paired_figures_and_losses_meet(tmp_path):
    run = tmp_path / "run"
    write_run(run, {("ours_x", 0.1): (-0.02, 0.8), ("ours_x", 1.5): (0.16, 0.04)},
              [("ours_x", 0.1, "no_object"), ("ours_x", 1.5, "jammed_on_approach"), ("ours_x", 1.5, "success"),
               ("binary", 0.1, "no_object"), ("binary", 1.5, "success")])
    rounds = json.loads((run / "attempts.json").read_text())
    rounds["rounds"].append({"method": "binary", "mass_kg": 1.5, "scene_id": "pile_000", "end": "no_feasible_grasp",
                             "n_objects": 5, "fell_off": [], "successes": 0, "attempts": 0})  # a scene ours_x has not run yet: not counted
    (run / "attempts.json").write_text(json.dumps(rounds))
    m = lever_table.measure(run, "ours_x")
    assert m["diff"][1.5] == (0.16, 0.04, 16) and m["losses"] == (2, 1)
    assert m["cr"] == {0.1: (0.0, 0.0), 1.5: (0.2, 0.2)}  # 1 of 5 objects each, over packed_000 only
    assert lever_table._cr_cell(m) == "0 / 0 % · 20 / 20 %"
    assert lever_table.targets_met(m) == "0.1 kg, 1.5 kg"  # 2 lost against 1: over 1.5 x
    m["diff"][1.5] = (0.16, 0.06, 16)
    m["losses"] = (3, 2)
    assert lever_table.targets_met(m) == "0.1 kg, before the lift"  # p 0.06 misses the 1.5 kg target
    assert lever_table.measure(tmp_path / "absent", "ours_x") is None
    assert lever_table.measure(run, "ours_y") is None  # a method its run did not compare


def test_binarys_drops_after_the_lift_bound_what_holding_better_can_gain(tmp_path):
    run = tmp_path / "run"
    write_run(run, {}, [("binary", 1.5, "dropped_in_shake"), ("binary", 1.5, "no_object"),
                        ("binary", 1.5, "success"), ("binary", 1.5, "dropped"), ("binary", 0.1, "dropped")])
    assert lever_table.binary_drops(run) == (2, 4)  # a close on nothing is placement, not holding
    assert lever_table.binary_drops(tmp_path / "absent") is None


def test_the_decisive_rows_can_leave_out_the_scenes_the_lever_was_chosen_on(tmp_path):
    run = tmp_path / "run"
    write_run(run, {("ours_x", 1.5): (0.5, 0.5)}, [])  # the whole run's comparison: not used with `after`
    attempts = [(m, s, o) for m, s, o in (("ours_x", "packed_000", "no_object"), ("binary", "packed_000", "success"),
                                          ("ours_x", "pile_000", "success"), ("binary", "pile_000", "dropped"),
                                          ("binary", "pile_000", "no_object"))]
    rounds = [{"method": m, "mass_kg": 1.5, "scene_id": s, "end": "table_clear", "n_objects": 5, "fell_off": [],
               "successes": sum(o == "success" for mm, ss, o in attempts if (mm, ss) == (m, s)), "attempts": 1}
              for m, s in dict.fromkeys((m, s) for m, s, _ in attempts)]
    run.joinpath("attempts.json").write_text(json.dumps({"rounds": rounds, "attempts": [
        {"method": m, "mass_kg": 1.5, "scene_id": s, "outcome": o, "reason": ""} for m, s, o in attempts]}))
    m = lever_table.measure(run, "ours_x", after=1)  # packed_000 was the tuning scene
    d, p, scenes = m["diff"][1.5]
    assert (d, scenes) == (1.0, 1) and m["losses"] == (0, 1)  # pile_000 only: 1/1 against 0/2
    assert lever_table.measure(run, "ours_x")["diff"][1.5] == (0.5, 0.5, 16)  # without: the run's own comparison


def test_the_screen_needs_every_direction_on_both_sets_over_32_scenes(tmp_path, monkeypatch, capsys):
    runs = {run: tmp_path / lever_table.RESULTS / run for _, run in lever_table.SCREEN_RUNS}
    good = {("ours_x", 0.1): (-0.02, 0.8), ("ours_x", 1.5): (0.05, 0.4)}
    outcomes = [("ours_x", 0.1, "success"), ("ours_x", 1.5, "jammed_on_approach"), ("binary", 0.1, "success"),
                ("binary", 1.5, "no_object")]
    heldout, procedural = runs.values()
    write_run(heldout, good, outcomes)
    lines, verdict = lever_table.screen("ours_x", tmp_path)
    assert verdict == "incomplete" and "no report of ours_x" in lines[-1]  # procedural not reported yet
    write_run(procedural, good, outcomes)
    assert lever_table.screen("ours_x", tmp_path)[1] == "incomplete"  # both ran 1 scene, not 32
    monkeypatch.setattr(lever_table, "SCREEN_SCENES", 1)
    lines, verdict = lever_table.screen("ours_x", tmp_path)
    assert verdict == "passed" and len(lines) == 6, lines  # 1 lost against 1 meets ≤ 1.5 ×
    assert lines[0] == ("held-out meshes, 0.1 kg: −2.0 pts per scene (p = 0.8, 16 of 1 scenes pair), "
                        "needs ≥ −3 pts: met")  # the fixture's comparison says 16, its rounds 1
    (procedural / "comparisons.json").write_text(json.dumps([  # level at 1.5 kg is not ahead
        {"method": "ours_x", "mass_kg": kg, "paired": {"scenes": 16, "diff": d, "p_value": 1.0}}
        for kg, d in ((0.1, 0.0), (1.5, 0.0))]))
    lines, verdict = lever_table.screen("ours_x", tmp_path)
    assert verdict == "failed" and lines[4].endswith("needs > 0 pts: missed")
    (heldout / "comparisons.json").write_text(json.dumps([  # behind at 0.1 kg on a finished run:
        {"method": "ours_x", "mass_kg": kg, "paired": {"scenes": 1, "diff": d, "p_value": 1.0}}
        for kg, d in ((0.1, -0.05), (1.5, 0.1))]))
    (procedural / "comparisons.json").unlink()  # failed, whatever the other set says
    assert lever_table.screen("ours_x", tmp_path)[1] == "failed"
    monkeypatch.setattr(lever_table, "SCREEN_SCENES", 32)  # ... unless the run is unfinished
    assert lever_table.screen("ours_x", tmp_path)[1] == "incomplete"
    assert lever_table.main(["--screen", "ours_y"]) == 0  # no rounds of it in the committed runs
    assert capsys.readouterr().out.splitlines()[-1] == "screen_ours_y=incomplete"
