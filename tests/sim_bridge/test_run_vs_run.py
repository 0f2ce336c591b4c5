"""run_vs_run: one method in two runs of the same scenes, paired per scene."""

import json

from sim_bridge.analysis import run_vs_run
from sim_bridge.benchmark import run_files


def write_run(run, rounds, scenes=("packed_000", "pile_000")):
    """A run directory as the benchmark's --report leaves it: scenes.jsonl and attempts.json.
    rounds: [(method, kg, scene_id, [outcome...], end)]."""
    run_files.scenes_file(run).put(*({"scene_id": sid, "objects": [sid]} for sid in scenes))
    attempts, records = [], []
    for method, kg, sid, outcomes, end in rounds:
        records.append({"method": method, "mass_kg": kg, "scene_id": sid, "end": end, "n_objects": 5, "fell_off": [],
                        "successes": outcomes.count("success"), "attempts": len(outcomes)})
        attempts += [{"method": method, "mass_kg": kg, "scene_id": sid, "outcome": o, "success": o == "success",
                      "reason": ""} for o in outcomes]
    (run / "attempts.json").write_text(json.dumps({"schema_version": 2, "attempts": attempts, "rounds": records}))


def test_a_method_is_paired_per_scene_across_the_runs_with_its_losses_before_the_lift(tmp_path, capsys):
    write_run(tmp_path / "base", [("ours", 0.1, "packed_000", ["success", "jammed_on_approach"], "table_clear"),
                                  ("ours", 0.1, "pile_000", ["no_object", "no_object"], "consecutive_failures"),
                                  ("binary", 0.1, "packed_000", ["success"], "table_clear")])
    write_run(tmp_path / "guarded", [("ours", 0.1, "packed_000", ["success", "success"], "table_clear"),
                                     ("ours", 0.1, "pile_000", ["success", "no_object"], "no_feasible_grasp")])
    assert run_vs_run.main([str(tmp_path / "base"), str(tmp_path / "guarded")]) == 0
    out = capsys.readouterr().out
    # ours: per scene 0.5 -> 1.0 and 0.0 -> 0.5, +50 points; lost before the lift 3 -> 2 (a miss, a refusing end)
    assert "| ours | 0.1 | 2 | 25.0 % | 75.0 % | +50.0 pts |" in out and "| 3 → 2 |" in out
    assert "diff_ours_0.1=+0.500" in out and "p_paired_ours_0.1=0.500" in out
    assert "binary" not in out  # binary did not run in the lever run


def test_runs_of_other_scenes_are_refused_with_one_message(tmp_path, capsys):
    write_run(tmp_path / "base", [("ours", 0.1, "packed_000", ["success"], "table_clear")])
    write_run(tmp_path / "other", [("ours", 0.1, "packed_000", ["success"], "table_clear")])
    run_files.scenes_file(tmp_path / "other").put({"scene_id": "packed_000", "objects": ["else"]})
    assert run_vs_run.main([str(tmp_path / "base"), str(tmp_path / "other")]) == 2
    assert "scene packed_000 differs" in capsys.readouterr().err
    write_run(tmp_path / "elsewhere", [], scenes=("pile_009",))
    assert run_vs_run.main([str(tmp_path / "base"), str(tmp_path / "elsewhere")]) == 2
    assert "share no scene" in capsys.readouterr().err


def test_a_run_without_its_report_is_one_clear_error(tmp_path, capsys):
    write_run(tmp_path / "base", [("ours", 0.1, "packed_000", ["success"], "table_clear")])
    write_run(tmp_path / "lever", [("ours", 0.1, "packed_000", ["success"], "table_clear")])
    (tmp_path / "lever" / "attempts.json").unlink()
    assert run_vs_run.main([str(tmp_path / "base"), str(tmp_path / "lever")]) == 2
    assert "run the benchmark's --report" in capsys.readouterr().err
