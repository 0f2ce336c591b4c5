"""A run's records in one JSON-lines file (benchmark.run_files): sorted by key, one record a
line; the per-record files of older runs are read beside it and win (a job on older code
may still write them); `convert` packs a run's folders into the two files, losing nothing."""

import json

from sim_bridge.benchmark import run_files


def round_record(method, kg, scene, successes=1):
    return {"method": method, "mass_kg": kg, "scene_id": scene, "successes": successes, "model_sha256": "abc"}


def write_old_round(run, record):
    path = run / "rounds" / record["method"] / f"{record['mass_kg']:g}" / f"{record['scene_id']}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record, indent=1))
    return path


def test_records_are_one_line_each_sorted_by_method_weight_and_scene(tmp_path):
    rounds = run_files.rounds_file(tmp_path)
    rounds.put(round_record("ours", 1.5, "pile_000"))
    rounds.put(round_record("binary", 4.0, "packed_000"), round_record("ours", 0.1, "pile_000"))
    rounds.put(round_record("ours", 1.5, "pile_000", successes=3))  # a rerun replaces its round
    lines = (tmp_path / "rounds.jsonl").read_text().splitlines()
    assert [(r["method"], r["mass_kg"]) for r in map(json.loads, lines)] == [("binary", 4.0), ("ours", 0.1), ("ours", 1.5)]
    again = run_files.rounds_file(tmp_path)
    assert len(again) == 3 and again.get("ours", 1.5, "pile_000")["successes"] == 3
    assert again.get("ours", "1.5", "pile_000") is again.get("ours", 1.5, "pile_000")  # a weight as given on a command line
    assert again.get("ours", 0.5, "pile_000") is None
    assert not (tmp_path / "rounds").exists()


def test_old_per_round_files_are_read_and_win_until_a_new_record_replaces_them(tmp_path):
    run_files.rounds_file(tmp_path).put(round_record("ours", 0.1, "packed_000", successes=1),
                                        round_record("ours", 0.1, "pile_000", successes=1))
    old = write_old_round(tmp_path, round_record("ours", 0.1, "packed_000", successes=2))
    write_old_round(tmp_path, round_record("binary", 0.1, "packed_000", successes=4))
    (old.parent / ".packed_000.json.123.tmp").write_text("{")  # a killed writer's temporary: not a record
    rounds = run_files.rounds_file(tmp_path)
    assert len(rounds) == 3 and rounds.get("ours", 0.1, "packed_000")["successes"] == 2
    rounds.put(round_record("ours", 0.1, "packed_000", successes=5))
    assert not old.exists() and run_files.rounds_file(tmp_path).get("ours", 0.1, "packed_000")["successes"] == 5


def test_convert_packs_a_run_and_keeps_every_record(tmp_path, capsys):
    (tmp_path / "config.json").write_text("{}")
    records = [round_record(m, kg, s, successes=i) for i, (m, kg, s) in enumerate(
        [("ours", 0.1, "packed_000"), ("ours", 1.5, "pile_000"), ("binary", 0.5, "packed_000")])]
    for r in records:
        write_old_round(tmp_path, r)
    (tmp_path / "scenes").mkdir()
    for sid in ("pile_000", "packed_000"):
        (tmp_path / "scenes" / f"{sid}.json").write_text(json.dumps({"scene_id": sid, "seed": 1}))
    assert run_files.main(["convert", str(tmp_path)]) == 0
    assert "packed 3 round files into rounds.jsonl, 2 scene files into scenes.jsonl" in capsys.readouterr().out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["config.json", "rounds.jsonl", "scenes.jsonl"]
    rounds = run_files.rounds_file(tmp_path)
    assert [rounds.get(r["method"], r["mass_kg"], r["scene_id"]) for r in records] == records
    assert [s["scene_id"] for s in run_files.scenes_file(tmp_path).records()] == ["packed_000", "pile_000"]
    assert run_files.main(["convert", str(tmp_path / "rounds.jsonl")]) == 2
    assert "holds no benchmark run" in capsys.readouterr().err
