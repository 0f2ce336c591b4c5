"""The clutter-removal benchmark (sim_bridge/benchmark/, issue 8): the round's
rules on a scripted cell, the statistics, the object pool, missing models, and one
small run in Drake (outputs, determinism, resume)."""
import dataclasses
import json
import math
import types

import numpy as np
import pytest
import trimesh

from gravgrasp_detector.perception import model_file, tsdf
from sim_bridge.benchmark import clutter_benchmark as cb
from sim_bridge.benchmark import clearing, protocol, report, sim_cell
from sim_bridge.benchmark import rounds as bench_rounds
from sim_bridge.benchmark import run_files
from sim_bridge.benchmark.methods import gravgrasp as gravgrasp_method
from sim_bridge.physics.objects import ObjectError
from made_models import save_test_model

pytestmark = pytest.mark.drake


# -- the round's rules on a scripted cell ---------------------------------------------

def grasp(score):
    return types.SimpleNamespace(pose=np.eye(4), score_n=score, validness=0.9)


class ScriptedCell:
    """objects_on_table shrinks by one per success; outcomes come from a script; every
    view detects `scores` (ranked as given)."""

    def __init__(self, n_objects, outcomes, scores=(3.0,), infeasible_ranks=()):
        self.left = [f"o{i}" for i in range(n_objects)]
        self.outcomes = list(outcomes)
        self.scores = scores
        self.infeasible_ranks = set(infeasible_ranks)
        self.executed = []

    def objects_on_table(self):
        return list(self.left)

    def detect(self):
        return (np.zeros((4, 4, 4)), 0.0075, np.zeros(3)), [grasp(s) for s in self.scores]

    def execute(self, g, tsdf):
        if g.score_n in self.infeasible_ranks:
            raise clearing.Refused("out of reach")
        self.executed.append(g.score_n)
        ok = self.outcomes.pop(0)
        lifted = [self.left.pop(0)] if ok else []
        return {"outcome": "success" if ok else "dropped", "reason": "scripted", "lifted": lifted}

    def remove_fallen(self):
        return []


def test_round_ends_when_the_table_is_clear():
    cell = ScriptedCell(3, [True, True, True])
    r = clearing.clear_table(cell, 3)
    assert r["end"] == "table_clear" and len(r["attempts"]) == 3
    assert all(a["success"] for a in r["attempts"])


def test_round_ends_after_two_consecutive_failures_only():
    cell = ScriptedCell(5, [False, True, False, False, True])
    r = clearing.clear_table(cell, 5)
    assert r["end"] == "consecutive_failures"
    assert [a["success"] for a in r["attempts"]] == [False, True, False, False]  # one failure did not end it


def test_round_ends_when_nothing_is_detected_or_feasible():
    r = clearing.clear_table(ScriptedCell(2, [], scores=()), 2)
    assert r["end"] == "no_grasp_detected" and r["attempts"] == []
    r = clearing.clear_table(ScriptedCell(2, [], scores=(5.0, 4.0), infeasible_ranks={5.0, 4.0}), 2)
    assert r["end"] == "no_feasible_grasp" and r["attempts"] == []
    assert r["refused"] == {"grasps": 2, "first": ["out of reach", "out of reach"]}  # why, in the round file


def test_the_best_feasible_grasp_is_executed():
    cell = ScriptedCell(1, [True], scores=(5.0, 4.0, 3.0), infeasible_ranks={5.0})
    r = clearing.clear_table(cell, 1)
    assert cell.executed == [4.0]
    assert r["attempts"][0]["rank"] == 1 and r["attempts"][0]["skipped_infeasible"] == 1


def test_attempt_limit_bounds_a_round():
    class NeverClears(ScriptedCell):
        def execute(self, g, tsdf):  # alternates, never 2 failures in a row, object stays
            self.executed.append(g.score_n)
            ok = len(self.executed) % 2 == 0
            return {"outcome": "success" if ok else "dropped", "reason": "scripted", "lifted": []}

    r = clearing.clear_table(NeverClears(1, [], scores=(1.0,)), 1, attempts_per_object=3)
    assert r["end"] == "attempt_limit" and len(r["attempts"]) == 3


def test_a_fault_ends_the_round_without_an_attempt():
    class Faulty(ScriptedCell):
        def execute(self, g, tsdf):
            if self.executed:
                raise clearing.Fault("ARM_FAULT: protective stop")
            return super().execute(g, tsdf)

    r = clearing.clear_table(Faulty(3, [False]), 3)
    assert r["end"] == "executor_fault" and r["fault"] == "ARM_FAULT: protective stop"
    assert len(r["attempts"]) == 1


# -- statistics -----------------------------------------------------------------------

def test_wilson_interval():
    lo, hi = report.wilson_interval(5, 10)
    assert lo == pytest.approx(0.2366, abs=1e-4) and hi == pytest.approx(0.7634, abs=1e-4)
    lo, hi = report.wilson_interval(0, 10)
    assert lo == 0.0 and hi == pytest.approx(0.2775, abs=1e-4)
    lo, hi = report.wilson_interval(10, 10)
    assert hi == 1.0 and lo == pytest.approx(0.7225, abs=1e-4)
    assert all(math.isnan(v) for v in report.wilson_interval(0, 0))


def test_two_proportion_test_matches_newcombe_and_the_chi_square_test():
    # Newcombe (1998), Stat. Med. 17:873, Table II, method 10: (a) and (b).
    c = report.two_proportion_test(56, 70, 48, 80)
    assert c["diff"] == pytest.approx(0.2) and c["ci95"] == pytest.approx((0.0524, 0.3339), abs=1e-4)
    assert report.two_proportion_test(9, 10, 3, 10)["ci95"] == pytest.approx((0.1705, 0.8090), abs=1e-4)
    # The pooled z test is Pearson's chi-square on the 2x2 table (no continuity correction).
    chi2 = (80 * (30 * 20 - 10 * 20) ** 2) / (40 * 40 * 50 * 30)
    assert report.two_proportion_test(30, 40, 20, 40)["p_value"] == pytest.approx(math.erfc(math.sqrt(chi2 / 2)))
    assert report.two_proportion_test(11, 24, 22, 37)["p_value"] > 0.05  # issue 16's 1.5 kg: no difference shown
    same = report.two_proportion_test(0, 10, 0, 10)
    assert same["p_value"] == 1.0 and same["diff"] == 0.0
    assert math.isnan(report.two_proportion_test(3, 5, 0, 0)["p_value"])


def test_every_method_is_compared_to_binary_at_the_weights_both_ran():
    def row(method, kg, s, a):
        return {"method": method, "mass_kg": kg, "successes": s, "attempts": a}
    rows = [row("ours", 0.1, 9, 10), row("ours", 1.5, 8, 10), row("binary", 1.5, 3, 10), row("ours_quat", 0.5, 1, 2)]
    comparisons = report.compare_to(rows)
    assert [(c["method"], c["mass_kg"]) for c in comparisons] == [("ours", 1.5)]
    assert comparisons[0]["diff"] == pytest.approx(0.5) and comparisons[0]["p_value"] < 0.05
    md = "\n".join(report.comparison_lines(comparisons))
    assert "| ours | 1.5 | 0 | — | — | — | +50.0 pts |" in md  # no scene rounds given: no paired figure
    paired = [{"method": "ours", "mass_kg": 1.5, "scenes": 4, "diff": 0.375, "ci95": (0.1, 0.6), "p_value": 0.125}]
    md = "\n".join(report.comparison_lines(report.with_paired(comparisons, paired)))
    assert "| ours | 1.5 | 4 | +37.5 pts | +10.0 to +60.0 | 0.125 | +50.0 pts |" in md
    assert "No comparison" in report.comparison_lines([])[0]


def test_modes_of_lifted_objects_are_tabulated_with_how_many_then_held():
    def attempt(mode, success):
        return {"mode": mode, "success": success, "outcome": "success" if success else "dropped_in_shake"}
    rounds = [{"method": "ours", "mass_kg": 1.5, "attempts": [attempt("power", True), attempt("power", False),
                                                                attempt("precision", False), attempt("", False)]},
              {"method": "ours", "mass_kg": 1.5, "attempts": [attempt("power", True)]},
              {"method": "ours", "mass_kg": 0.5, "attempts": [attempt("", False)]}]
    lines = report.mode_lines(rounds, {"ours": [0.1, 0.5, 1.5]})
    assert "| ours | 1.5 | 2 / 3 | 0 / 1 |" in lines and "| ours | 0.5 | 0 / 0 | 0 / 0 |" in lines
    assert not any(line.startswith("| ours | 0.1 |") for line in lines)  # no rounds there: no row


def test_a_motion_stopped_by_contact_is_told_apart_by_where_and_round_ends_are_per_method():
    def attempt(outcome, reason):
        return {"outcome": outcome, "reason": reason, "success": outcome == "success"}
    contact = ("stopped by contact after 0.004 of 0.150 m: the force on the hand rose from 0 to 61 N, by more than "
               "the 60 N limit")
    jam = attempt("unreachable", f"arm could not reach the grasp pose: {contact}")
    jam_pre = attempt("unreachable", f"arm could not reach the pregrasp pose: {contact}")
    blocked = attempt("unreachable", f"arm could not reach the lift pose: {contact}")
    out_of_box = attempt("unreachable", "lift TCP position [0.1, 0.1, 0.9] m is outside the workspace box")
    stuck_miss = attempt("unreachable", "the grasp missed the object: empty; backing out failed: arm could not "
                                        f"reach the pre-grasp (backing out) pose: {contact}; disarmed")
    assert [report.outcome_class(a) for a in (jam, jam_pre, blocked, out_of_box, stuck_miss,
                                              attempt("success", "held"))] == [
        "jammed_on_approach", "jammed_on_approach", "lift_blocked", "unreachable", "no_object", "success"]
    rounds = [{"method": "ours", "mass_kg": 1.5, "end": "no_feasible_grasp", "attempts": [jam, blocked]},
              {"method": "ours", "mass_kg": 1.5, "end": "table_clear", "attempts": [attempt("success", "held")]},
              {"method": "binary", "mass_kg": 1.5, "end": "table_clear", "attempts": [jam_pre]}]
    plan = {"ours": [1.5], "binary": [1.5]}
    outcomes = report.outcome_lines(rounds, plan)
    assert "| method | weight [kg] | success | jammed_on_approach | lift_blocked |" in outcomes
    assert "| ours | 1.5 | 1 | 1 | 1 |" in outcomes and "| binary | 1.5 | 0 | 1 | 0 |" in outcomes
    ends = report.end_lines(rounds, plan)
    assert "| method | weight [kg] | no_feasible_grasp | table_clear |" in ends
    assert "| ours | 1.5 | 1 | 1 |" in ends and "| binary | 1.5 | 0 | 1 |" in ends


def test_losses_before_the_lift_are_counted_per_weight_and_over_the_weights_binary_ran():
    contact = "stopped by contact after 0.004 of 0.150 m"
    miss = {"outcome": "no_object", "success": False, "reason": "the grasp missed the object: empty"}
    jam = {"outcome": "unreachable", "success": False, "stopped_by_contact": True,
           "reason": f"arm could not reach the grasp pose: {contact}"}
    blocked = {**jam, "reason": f"arm could not reach the lift pose: {contact}"}
    dropped = {"outcome": "dropped", "success": False, "reason": "the object slipped out during the lift"}
    rounds = [{"method": "ours", "mass_kg": 0.1, "end": "no_feasible_grasp", "attempts": [miss, jam, blocked]},
              {"method": "ours", "mass_kg": 1.5, "end": "consecutive_failures", "attempts": [dropped, dropped]},
              {"method": "ours", "mass_kg": 1.5, "end": "no_feasible_grasp", "attempts": [miss]},
              {"method": "binary", "mass_kg": 0.1, "end": "table_clear", "attempts": [jam]},
              {"method": "binary", "mass_kg": 1.5, "end": "table_clear", "attempts": [dropped]}]
    losses = report.before_lift_losses(rounds)
    assert losses[("ours", 0.1)] == {"closed_on_nothing": 1, "contact_stops": 2, "rounds_all_refused": 1, "total": 4}
    assert losses[("ours", 1.5)]["total"] == 2 and losses[("binary", 1.5)]["total"] == 0  # a drop is after the lift
    lines = report.before_lift_lines(rounds, {"ours": [0.1, 1.5], "binary": [0.1, 1.5]})
    assert "| ours | 0.1 | 1 | 2 | 1 | 4 | 4.0 |" in lines
    assert "| ours | 1.5 | 1 | 0 | 1 | 2 | ∞ |" in lines  # binary lost none there
    assert "| ours | all (0.1, 1.5) | 2 | 2 | 2 | 6 | 6.0 |" in lines
    assert "| binary | 0.1 | 0 | 1 | 0 | 1 | — |" in lines and not any("| binary | all" in line for line in lines)


def test_guarded_closes_are_tabulated_by_how_they_ended():
    short = "; closed 5.0 mm short of the grasp pose, backed off where the arm's contact stop halted the approach"
    rounds = [{"method": "ours", "mass_kg": 1.5, "attempts": [
        {"outcome": "success", "success": True, "reason": f"lifted 0.15 m and held{short}"},
        {"outcome": "dropped", "success": False, "reason": f"the object slipped out during the lift{short}"},
        {"outcome": "no_object", "success": False, "reason": f"the grasp missed the object: empty{short}"},
        {"outcome": "success", "success": True, "reason": "lifted 0.15 m and held"}]}]
    lines = report.guarded_lines(rounds, {"ours": [1.5], "binary": [1.5]}, 0.01)
    assert "at most 10 mm short" in lines[0]
    assert "| method | weight [kg] | success | dropped | no_object |" in lines
    assert "| ours | 1.5 | 1 | 1 | 1 |" in lines and not any(line.startswith("| binary") for line in lines)


def test_success_rates():
    assert clearing.success_rates(2, 4, 5) == (0.5, 0.4)
    assert all(math.isnan(v) for v in clearing.success_rates(0, 0, 0))
    assert clearing.success_rates(0, 0, 3, empty=0.0) == (0.0, 0.0)


# -- objects and models ---------------------------------------------------------------

def test_oversized_objects_are_excluded_and_reported(tmp_path):
    trimesh.creation.box((0.10, 0.12, 0.10)).export(tmp_path / "big_cube.obj")       # 100 mm at its narrowest
    trimesh.creation.box((0.09, 0.20, 0.03)).export(tmp_path / "flat_board.obj")     # 30 mm thick: fits
    for i in range(5):
        trimesh.creation.cylinder(radius=0.02 + 0.002 * i, height=0.1).export(tmp_path / f"can{i}.obj")
    usable, excluded = protocol.object_pool(str(tmp_path))
    assert [e["name"] for e in excluded] == ["big_cube"]
    assert excluded[0]["min_width_mm"] == pytest.approx(100.0, abs=0.5)
    assert sorted(s.name for s in usable) == ["can0", "can1", "can2", "can3", "can4", "flat_board"]


def test_only_keeps_the_listed_meshes_and_an_unknown_name_is_one_error(tmp_path, capsys):
    for i in range(7):
        trimesh.creation.cylinder(radius=0.02 + 0.002 * i, height=0.1).export(tmp_path / f"can{i}.obj")
    usable, _ = protocol.object_pool(str(tmp_path), only=("can1", "can2", "can3", "can4", "can6"))
    assert sorted(s.name for s in usable) == ["can1", "can2", "can3", "can4", "can6"]
    with pytest.raises(ObjectError, match="not in"):
        protocol.object_pool(str(tmp_path), only=("can1", "mug"))
    listed = tmp_path / "list.txt"
    listed.write_text("# held out\ncan1\nmug\n")
    save_test_model(tmp_path / "m.pt")
    argv = ["--only", str(listed), "--model", f"x={tmp_path}/m.pt", "--methods", "", "--out", str(tmp_path / "o"),
            "--workers", "0"]
    assert cb.main(argv) == 2
    assert "give the mesh directory" in capsys.readouterr().err
    assert cb.main(argv + ["--meshes", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "mug" in err


def test_bad_mesh_dir_is_one_clear_error(tmp_path, capsys):
    code = cb.main(["--meshes", str(tmp_path / "nope"), "--model", f"x={tmp_path}/m.pt", "--methods", "",
                    "--out", str(tmp_path / "o")])
    assert code == 2  # the model is missing too: that message comes first
    assert "no method has its files" in capsys.readouterr().err
    save_test_model(tmp_path / "m.pt")
    code = cb.main(["--meshes", str(tmp_path / "nope"), "--model", f"x={tmp_path}/m.pt", "--methods", "",
                    "--out", str(tmp_path / "o"), "--workers", "0"])
    err = capsys.readouterr().err
    assert code == 2 and "does not exist" in err and "Traceback" not in err


@pytest.mark.parametrize("bad", ["-0.01", "nan"])
def test_a_bad_guard_distance_is_one_clear_error(tmp_path, capsys, bad):
    save_test_model(tmp_path / "m.pt")
    code = cb.main(["--model", f"x={tmp_path}/m.pt", "--methods", "", "--out", str(tmp_path / "o"),
                    "--close-on-contact-within-m", bad])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "--close-on-contact-within-m" in err, err
    assert not (tmp_path / "o").exists()  # nothing started


def test_a_procedural_seed_draws_other_objects_is_recorded_and_a_resume_keeps_it(tmp_path, capsys, monkeypatch):
    """--procedural-seed 2000 (a confirmation run on objects no choice was tuned on): its
    own pool and scenes, in config.json and results.md; that --out refuses another seed."""
    def pool_kinds(seed):  # the objects themselves: names are per index (proc<seed>_i), kinds are not
        usable, excluded = protocol.object_pool(None, procedural_seed=seed)
        return [s.load().name for s in usable], [e["name"] for e in excluded]

    assert pool_kinds(2000) != pool_kinds(protocol.PROCEDURAL_SEED)

    def scripted_round(task):  # a round record without Drake (what write_outputs reads)
        return {"schema_version": 2, "method": task.method, "hand": "2f85", "model_sha256": task.model_sha256,
                "target": "gravity-score", "mass_kg": task.mass_kg, "scene_id": task.scene["scene_id"],
                "objects": [], "n_objects": 0, "left_before_start": [], "settle_s": 0.0, "end": "table_clear",
                "attempts": [], "fell_off": [], "successes": 0, "sim_time_s": 0.0, "cpu_s": 0.0,
                "machine": "test", "execution": dict(protocol.LEGACY_EXECUTION), "drive": task.protocol.drive}

    monkeypatch.setattr(bench_rounds, "run_round", scripted_round)
    save_test_model(tmp_path / "m.pt")
    out = tmp_path / "o"
    argv = ["--out", str(out), "--methods", "", "--model", f"ours={tmp_path / 'm.pt'}", "--scenes", "1",
            "--weights", "0.1", "--workers", "0", "--no-progress", "--execution", "v4"]
    assert cb.main(argv + ["--procedural-seed", "2000"]) == 0
    assert json.loads((out / "config.json").read_text())["procedural_seed"] == 2000
    scene = run_files.scenes_file(out).get("packed_000")
    assert [o["source"]["proc_seed"] for o in scene["objects"]] == [2000] * protocol.OBJECTS_PER_SCENE
    assert "objects: procedural (seed 2000)" in (out / "results.md").read_text()
    capsys.readouterr()
    for other in ([], ["--procedural-seed", "3000"]):  # the default (1000) is another seed too
        assert cb.main(argv + other) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "seed 2000, not" in err and "--procedural-seed 2000" in err, err
    assert cb.main(argv + ["--procedural-seed", "2000", "--report"]) == 0


def test_the_training_seed_and_a_seed_with_meshes_are_one_clear_error_each(tmp_path, capsys):
    out = tmp_path / "o"
    for extra, says in ((["--procedural-seed", "0"], "trained on"),
                        (["--procedural-seed", "2000", "--meshes", str(tmp_path)], "--meshes replaces")):
        code = cb.main(["--out", str(out), "--methods", "", "--model", f"x={tmp_path}/m.pt", *extra])
        err = capsys.readouterr().err.strip()
        assert code == 2 and len(err.splitlines()) == 1 and says in err, err
    assert not out.exists()  # nothing started


def test_missing_model_is_skipped_with_a_note(tmp_path):
    notes = []
    save_test_model(tmp_path / "gravgrasp.pt")
    found = bench_rounds.resolve_methods(["ours", "binary"], tmp_path, note=notes.append)
    assert list(found) == ["ours"]
    assert notes == [f"benchmark: skipping binary: model file {tmp_path / 'gravgrasp_binary.pt'} not found"]
    with pytest.raises(ValueError, match="unknown method"):
        bench_rounds.resolve_methods(["oursx"], tmp_path)


def test_binary_model_ranks_by_validness(tmp_path):
    model, meta = model_file.load_model(save_test_model(tmp_path / "b.pt", validness_bias=0.0, target="binary"))
    assert model_file.training_target(meta) == "binary" and model_file.ranking(meta) == "validness"
    grid = np.zeros((40, 40, 40), np.float32)
    grid[10:30, 10:30, 6:12] = 0.3
    grid[10:30, 10:30, 12] = 0.5
    # a min-score threshold in N must not apply to probabilities
    p = protocol.Protocol(validness_threshold=0.0, min_score_n=1e6)
    detect = gravgrasp_method.make_detect(model, p, gravgrasp_method.detection_options(meta, p))
    grasps = detect((grid, 0.0075, np.zeros(3)))
    assert grasps and all(math.isnan(g.score_n) for g in grasps)  # no score in N, not its probability
    assert [g.rank_key for g in grasps] == sorted((g.rank_key for g in grasps), reverse=True)
    assert all(g.rank_key == g.validness and 0.0 <= g.validness <= 1.0 for g in grasps)


# -- a small run in Drake ---------------------------------------------------------------

def run_argv(out, models):
    return ["--out", str(out), "--methods", "ours,binary", "--models-dir", str(models / "none"),
            "--model", f"ours={models / 'ours.pt'}", "--model", f"blind={models / 'blind.pt'}", "--scenes", "1",
            "--weights", "0.3", "--time-step-s", "0.002", "--workers", "0", "--no-progress",
            # a scene where the test model's best grasps pass the executor's checks (seed
            # 0's packed scene, since footprints pack objects closer, has none: 0 attempts)
            "--seed", "1"]


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    """One small run (ours' round of tens of seconds in Drake, blind's that detects nothing),
    made once for the module: the resume test works on a copy, the replay test reads it.
    -> (models dir, run dir, the lines the run printed)."""
    import contextlib
    import io

    models = tmp_path_factory.mktemp("small_run")
    save_test_model(models / "ours.pt")
    save_test_model(models / "blind.pt", validness_bias=-20.0)
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert cb.main(run_argv(models / "out", models)) == 0
    return models, models / "out", printed.getvalue().strip().splitlines()


def test_run_outputs_determinism_and_resume(small_run, tmp_path, capsys, monkeypatch):
    import shutil

    models, run_dir, text = small_run
    out = tmp_path / "out"
    shutil.copytree(run_dir, out)
    argv = run_argv(out, models)
    assert any("skipping binary" in line for line in text)
    assert text[-2].startswith("SR_ours_0.3=") and text[-1].startswith("SR_blind_0.3=nan")

    attempts = json.loads((out / "attempts.json").read_text())
    rounds = {r["method"]: r for r in attempts["rounds"]}
    assert rounds["blind"]["end"] == "no_grasp_detected" and rounds["blind"]["attempts"] == 0
    ours = rounds["ours"]
    assert ours["end"] in ("table_clear", "consecutive_failures", "no_feasible_grasp", "attempt_limit")
    assert ours["attempts"] >= 1 and ours["n_objects"] + len(ours["left_before_start"]) == protocol.OBJECTS_PER_SCENE
    for a in attempts["attempts"]:
        assert set(a) >= {"method", "mass_kg", "scene_id", "object", "pose", "score_n", "validness", "rank_key",
                          "outcome", "success", "reason", "mode"}
        assert a["mode"] in ("power", "precision") if a["success"] else a["mode"] in ("", "power", "precision")
        assert np.asarray(a["pose"]).shape == (4, 4) and a["mass_kg"] == 0.3
        assert a["score_n"] > 0 and a["rank_key"] == a["score_n"] and 0 <= a["validness"] <= 1  # ranked by N
    results = json.loads((out / "results.json").read_text())
    row = next(r for r in results if r["method"] == "ours")
    assert row["SR"] == pytest.approx(row["successes"] / row["attempts"])
    md = (out / "results.md").read_text()
    assert "| ours | 0.3 | 1/1 |" in md
    from sim_bridge.benchmark.machine import machine_name
    here = machine_name()
    assert json.loads((out / "config.json").read_text())["machines"] == [here]
    assert run_files.rounds_file(out).get("ours", 0.3, "packed_000")["machine"] == here
    assert f"Rounds by machine: {here} (2)" in md  # ours' round and blind's
    # Every attempt appears once in the outcome table.
    md_lines = md.splitlines()
    at = next(i for i, line in enumerate(md_lines) if line.startswith("| method | weight [kg] | success"))
    header = md_lines[at]
    outcome_row = next(line for line in md_lines[at:] if line.startswith("| ours | 0.3 |"))
    counts = dict(zip(header.strip("| ").split(" | ")[2:], map(int, outcome_row.strip("| ").split(" | ")[2:])))
    assert sum(counts.values()) == ours["attempts"] and counts["success"] == row["successes"]
    mode_row = next(line for line in md_lines[at:] if line.startswith("| ours | 0.3 |") and "/" in line)
    held = [int(cell.split(" / ")[0]) for cell in mode_row.strip("| ").split(" | ")[2:]]
    assert sum(held) == row["successes"]  # every success lifted something in one of the two modes
    assert (out / "sr_cr_vs_weight.png").stat().st_size > 1000
    assert json.loads((out / "comparisons.json").read_text()) == [] and "No comparison with binary" in md
    scene = run_files.scenes_file(out).get("packed_000")
    assert [o["source"]["proc_seed"] for o in scene["objects"]] == [protocol.PROCEDURAL_SEED] * protocol.OBJECTS_PER_SCENE

    # Finished rounds are not run again.
    monkeypatch.setattr(bench_rounds, "run_round", lambda task: pytest.fail("a finished round ran again"))
    assert cb.main(argv) == 0
    monkeypatch.undo()
    first = (out / "attempts.json").read_text()
    # A partial run (one round's file lost) resumes to the same results; --report before
    # that runs nothing and reports the rounds there are (none of ours).
    kept = [line for line in (out / "rounds.jsonl").read_text().splitlines()
            if (json.loads(line)["method"], json.loads(line)["mass_kg"]) != ("ours", 0.3)]
    (out / "rounds.jsonl").write_text("".join(line + "\n" for line in kept))
    (out / "attempts.json").unlink()
    monkeypatch.setattr(bench_rounds, "run_round", lambda task: pytest.fail("--report ran a round"))
    capsys.readouterr()
    assert cb.main(argv + ["--report"]) == 0
    monkeypatch.undo()
    md = (out / "results.md").read_text()
    assert "| ours | 0.3 |" not in md and "No rounds (not run, or not yet): ours at 0.3 kg." in md
    assert "an interim report" in capsys.readouterr().out
    assert run_files.rounds_file(out).get("ours", 0.3, "packed_000") is None
    (out / "excluded_objects.json").unlink()  # a run stopped before it listed them
    assert cb.main(argv + ["--report"]) == 0
    assert cb.main(argv[:1] + [str(tmp_path / "nothing")] + argv[2:] + ["--report"]) == 2
    assert "holds no benchmark run" in capsys.readouterr().err
    # A run resumed on another machine type keeps its rounds and lists both machines.
    config = json.loads((out / "config.json").read_text())
    (out / "config.json").write_text(json.dumps({**config, "machines": ["Other CPU, 4 cores"]}))
    assert cb.main(argv) == 0
    assert (out / "attempts.json").read_text() == first
    assert json.loads((out / "config.json").read_text())["machines"] == sorted(["Other CPU, 4 cores", here])
    # Another configuration in the same directory is refused.
    assert cb.main(argv + ["--hold-s", "2"]) == 2
    assert "another configuration" in capsys.readouterr().err


def test_a_good_grasp_is_a_success_after_hold_and_shake_and_its_object_is_removed():
    """The cell on its own: a 34 mm cylinder (procedural test object 1) upright, a
    top-down grasp 2.5 cm below its top -> executor, 1 s hold, shake, removal."""
    from sim_bridge.datagen.object_sources import procedural_sources
    from sim_bridge.world import R_TOP_DOWN

    source = procedural_sources(protocol.PROCEDURAL_POOL, protocol.PROCEDURAL_SEED)[1]
    mesh = source.load().collision_mesh()
    height_m = float(mesh.extents[2])
    assert mesh.extents[0] < 0.05 and 0.08 < height_m < 0.15  # a slim upright cylinder
    X = np.eye(4)
    X[:3, 3] = [0.15, 0.15, 0.051 - mesh.bounds[0][2]]
    scene = {"scene_id": "packed_t", "arrangement": "packed",
             "objects": [{"source": dataclasses.asdict(source), "name": "c", "X_task_object": X.tolist()}]}
    cell = sim_cell.SimCell(scene, 0.5, protocol.Protocol(time_step_s=0.002), tsdf.TSDFVolume(resolution=40),
                            detect=lambda tsdf: [])
    view = cell.observe()
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = R_TOP_DOWN, [0.15, 0.15, 0.05 + height_m - 0.025]
    g = types.SimpleNamespace(pose=pose, score_n=30.0, validness=0.9, rank_key=27.0)
    assert cell.feasible(g, view) == ""
    result = cell.execute(g, view)
    assert result["outcome"] == "success", result
    assert (result["score_n"], result["validness"], result["rank_key"], result["stopped_by_contact"]) == (
        30.0, 0.9, 27.0, False)  # the record's fields (clearing.grasp_fields), apart
    assert len(result["lifted"]) == 1 and result["mode"] in ("power", "precision")
    assert cell.objects_on_table() == [] and cell.world.object_names() == []  # removed
    assert np.allclose(cell.world.tcp_pose()[:3, 3], cell.home[:3, 3], atol=1e-3)  # back home
    assert cell.world.finger_width_m() > 0.08  # open


def test_a_recorded_round_replays_to_the_same_attempts_and_shows_the_closing_region(small_run, tmp_path, capsys):
    """replay_round: the first attempt of a fresh one-round run (the module's) comes out the
    same (pose and outcome), with what the detector saw between the pads; another model file
    or a round that was not run is one error line."""
    from sim_bridge.analysis import replay

    models, out, _ = small_run
    model = models / "ours.pt"
    recorded = run_files.rounds_file(out).get("ours", 0.3, "packed_000")["attempts"]
    assert recorded
    capsys.readouterr()
    argv = ["--results", str(out), "--method", "ours", "--weight", "0.3", "--scene", "packed_000",
            "--model", str(model), "--attempts", "1", "--dump", str(tmp_path / "dump")]
    assert replay.main(argv) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[-1] == "replayed=1 matched=1"
    entry = json.loads(lines[0])
    assert entry["recorded"] == entry["replayed"] == recorded[0]["outcome"] and entry["same_pose"]
    assert entry["observed"]["voxels"] >= 1  # the detector's closing-region check passed it
    lo, hi = np.round(np.asarray(replay.CLOSING_REGION_TCP) * 1000)
    assert np.all(np.asarray(entry["observed"]["min"]) >= lo - 1) and np.all(np.asarray(entry["observed"]["max"]) <= hi + 1)
    if entry["replayed"] == "success":  # what it lifted was between the pads
        assert entry["objects"]
    dumped = np.load(tmp_path / "dump" / "1.npz")
    assert dumped["grid"].shape == (40, 40, 40) and np.allclose(dumped["pose"], recorded[0]["pose"], atol=2e-6)

    other = save_test_model(tmp_path / "other.pt", validness_bias=4.0)
    assert replay.main(argv[:8] + ["--model", str(other)]) == 2
    assert "is not the model this round ran" in capsys.readouterr().err
    assert replay.main(["--results", str(out), "--method", "ours", "--weight", "1.5", "--scene", "packed_000",
                        "--model", str(model)]) == 2
    assert "no round" in capsys.readouterr().err


# execution settings (protocol.EXECUTION_SETTINGS): recorded, resumed, never pooled


def _legacy_config(tmp_path):
    """A config.json as runs up to benchmark v4 wrote it: no execution settings in it."""
    import dataclasses as dc
    from sim_bridge.benchmark.protocol import LEGACY_EXECUTION, PROCEDURAL_SEED, Protocol as P
    protocol = {k: v for k, v in dc.asdict(P()).items()
                if k not in LEGACY_EXECUTION and k not in ("clear_hand", "close_on_contact_within_m", "drive")}
    (tmp_path / "config.json").write_text(json.dumps({"seed": 0, "meshes": None, "procedural_seed": PROCEDURAL_SEED,
                                                      "objects_per_scene": 5, "protocol": protocol}))


def test_a_run_from_before_execution_settings_resumes_as_v4_and_refuses_others(tmp_path):
    from sim_bridge.benchmark.protocol import Protocol as P, with_execution
    from sim_bridge.benchmark.rounds import run_benchmark
    _legacy_config(tmp_path)
    model = tmp_path / "m.pt"
    model.write_bytes(b"x")
    run_benchmark(tmp_path, {"ours": str(model)}, [0.1], 2, protocol=with_execution(P(), "v4"), report_only=True)
    with pytest.raises(ValueError, match="execution settings v4, not fast.*never pooled.*--execution v4"):
        run_benchmark(tmp_path, {"ours": str(model)}, [0.1], 2, protocol=with_execution(P(), "fast"),
                      report_only=True)


def test_a_report_names_the_rounds_it_leaves_out(tmp_path):
    """A report rewrites the run's summaries for the methods and weights it names only: the
    rounds of the others stay on disk, and the report says whose it left out."""
    from sim_bridge.benchmark.protocol import Protocol as P, with_execution
    from sim_bridge.benchmark.rounds import run_benchmark
    _legacy_config(tmp_path)
    model = tmp_path / "m.pt"
    model.write_bytes(b"x")
    run_files.rounds_file(tmp_path).put(*({"method": method, "mass_kg": kg, "scene_id": "packed_000"}
                                          for method, kg in (("binary", 1.5), ("ours", 0.1), ("ours", 4.0))))
    notes = []
    run_benchmark(tmp_path, {"ours": str(model)}, [0.1], 2, protocol=with_execution(P(), "v4"), report_only=True,
                  note=notes.append)
    assert len(notes) == 1 and "binary at 1.5 kg, ours at 4.0 kg (not named" in notes[0]
    notes.clear()
    run_benchmark(tmp_path, {"ours": str(model), "binary": str(model)}, [0.1, 1.5, 4.0], 2,
                  protocol=with_execution(P(), "v4"), report_only=True, note=notes.append)
    assert notes == []
    assert run_files.rounds_file(tmp_path).get("binary", 1.5, "packed_000") is not None


def test_execution_defaults_to_the_settings_of_the_run_being_resumed(tmp_path):
    """--execution left out: a run resumes (or gains a method) under its own settings, so a
    changed DEFAULT_EXECUTION never stops, or silently mixes, an older run."""
    from sim_bridge.benchmark.protocol import EXECUTION_SETTINGS, execution_of_run
    assert execution_of_run(tmp_path) is None  # no run there: the CLI's default applies
    _legacy_config(tmp_path)
    assert execution_of_run(tmp_path) == "v4"  # written before the settings were recorded
    config = json.loads((tmp_path / "config.json").read_text())
    config["protocol"].update(EXECUTION_SETTINGS["freeze_only"])
    (tmp_path / "config.json").write_text(json.dumps(config))
    assert execution_of_run(tmp_path) == "freeze_only"
    config["protocol"]["lift_speed_mps"] = 0.07  # settings with no name: the CLI's default, which then refuses
    (tmp_path / "config.json").write_text(json.dumps(config))
    assert execution_of_run(tmp_path) is None


def test_the_report_refuses_rounds_run_under_other_execution_settings(tmp_path):
    from sim_bridge.benchmark.protocol import EXECUTION_SETTINGS, Protocol as P
    from sim_bridge.benchmark.report import write_outputs
    path = tmp_path / "rounds" / "ours" / "0.1" / "packed_000.json"
    path.parent.mkdir(parents=True)
    path.write_text(json.dumps({"model_sha256": "abc", "method": "ours", "mass_kg": 0.1, "scene_id": "packed_000",
                                "execution": EXECUTION_SETTINGS["fast"], "attempts": []}))
    with pytest.raises(ValueError, match="1 rounds .* ran under execution settings fast .* never pooled"):
        write_outputs(tmp_path, {"ours": [0.1]}, {"ours": "abc"}, ["packed_000"], [], P(), None)


def test_figure_names_carry_the_weight_in_kg_as_people_write_it():
    """`p_paired_ours_vs_binary_1.5=`, `p_paired_ours_vs_ours_precision_4=` (not 4.0): the names
    the decisive comparison is read by; SR last."""
    rows = [{"method": m, "mass_kg": 4.0, "SR": 0.25, "CR": 0.2, "before_lift": {"total": 3}} for m in ("ours", "binary")]
    comparisons = [{"method": "ours", "mass_kg": 4.0, "p_value": 0.2,
                    "paired": {"p_value": 0.04, "scenes_for_10pts": 30.0}},
                   {"method": "ours", "mass_kg": 1.5, "p_value": 0.5, "paired": {"p_value": 0.5}}]
    effect = [{"mass_kg": 4.0, "diff": 0.125, "p_value": 0.031}, {"mass_kg": 0.1, "diff": float("nan")}]
    lines = cb.figure_lines(rows, comparisons, effect)
    assert {"p_paired_ours_vs_binary_4=0.040", "scenes_for_10pts_ours_vs_binary_4=30", "p_paired_ours_vs_binary_1.5=0.500",
            "diff_ours_vs_ours_precision_4=+0.125", "p_paired_ours_vs_ours_precision_4=0.031",
            "before_lift_ours_4=3", "CR_binary_4=0.20"} <= set(lines)
    assert not any("_0.1=" in line for line in lines)  # no effect where either did not run
    assert lines[-2:] == ["SR_ours_4=0.25", "SR_binary_4=0.25"]
