"""A round Drake cannot simulate is recorded once (benchmark.failed_rounds): a rerun does
not run it again, the report lists it by scene, --retry-failed runs it again. The round
itself is scripted here (no Drake)."""
import json

import pytest

from gravgrasp_detector.perception.model_file import file_sha256
from sim_bridge.benchmark import clutter_benchmark as cb
from sim_bridge.benchmark import rounds as bench_rounds
from sim_bridge.benchmark.protocol import LEGACY_EXECUTION
from sim_bridge.benchmark.rounds import run_benchmark

NON_FINITE = "SceneGraph encountered a non-finite value (e.g., NaN or infinity) on a pose input port."


def finished_round(task) -> dict:
    """A round record with no attempts (what write_outputs reads)."""
    return {"schema_version": 2, "method": task.method, "hand": "2f85", "model_sha256": task.model_sha256,
            "target": "gravity-score", "mass_kg": task.mass_kg, "scene_id": task.scene["scene_id"], "objects": [],
            "n_objects": 0, "left_before_start": [], "settle_s": 0.0, "end": "table_clear", "attempts": [],
            "fell_off": [], "successes": 0, "sim_time_s": 0.0, "cpu_s": 0.0, "machine": "test",
            "execution": dict(LEGACY_EXECUTION)}


@pytest.fixture
def run(tmp_path, monkeypatch):
    """(run(**kw) -> summary rows of a one-scene, one-weight run of `ours` in tmp_path, the
    model's sha256). The scene is on disk already: no object pool is needed."""
    monkeypatch.setattr(bench_rounds, "object_pool", lambda *args, **kwargs: ((), ()))
    model = tmp_path / "m.pt"
    model.write_bytes(b"a model")
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    (scenes / "packed_000.json").write_text(json.dumps({"scene_id": "packed_000", "objects": []}))
    notes = []
    return lambda **kw: run_benchmark(tmp_path, {"ours": str(model)}, [0.1], 1, workers=0, progress=False,
                                      note=notes.append, **kw), file_sha256(model)


def test_a_round_drake_cannot_simulate_is_recorded_once_and_listed_by_scene(tmp_path, monkeypatch, capsys, run):
    run, sha = run
    ran = []

    def fails_in_drake(task):
        ran.append(task.scene["scene_id"])
        raise RuntimeError(NON_FINITE + "\nIt came from the input associated with source id 16 and name 'plant'.")

    monkeypatch.setattr(bench_rounds, "run_round", fails_in_drake)
    argv = ["--out", str(tmp_path), "--methods", "ours", "--models-dir", str(tmp_path / "none"),
            "--model", f"ours={tmp_path / 'm.pt'}", "--scenes", "1", "--weights", "0.1", "--workers", "0",
            "--no-progress", "--execution", "v4", "--drive", "backdrivable"]  # as run() below: Protocol()'s settings
    assert cb.main(argv) == 1 and ran == ["packed_000"]  # a round is missing
    assert "1 rounds Drake could not simulate, listed in results.md" in capsys.readouterr().out
    (record,) = json.loads((tmp_path / "failed_rounds.json").read_text())
    assert record["error"] == "RuntimeError: " + NON_FINITE
    assert (record["method"], record["mass_kg"], record["scene_id"], record["model_sha256"]) == ("ours", 0.1, "packed_000", sha)
    md = (tmp_path / "results.md").read_text()
    assert "Rounds Drake could not simulate (1;" in md and f"- packed_000: ours 0.1 kg: RuntimeError: {NON_FINITE}" in md

    run()  # a rerun does not run it again
    assert ran == ["packed_000"]
    assert "- packed_000: ours 0.1 kg" in (tmp_path / "results.md").read_text()

    monkeypatch.setattr(bench_rounds, "run_round", finished_round)  # after a fix
    assert run(retry_failed=True)[0]["rounds"] == 1
    assert json.loads((tmp_path / "failed_rounds.json").read_text()) == []
    assert "could not simulate" not in (tmp_path / "results.md").read_text()


def test_other_errors_are_not_recorded_and_are_retried(tmp_path, monkeypatch, run):
    run, _ = run
    ran = []

    def bad_model(task):
        ran.append(task.scene["scene_id"])
        raise ValueError("the model does not fit the volume")

    monkeypatch.setattr(bench_rounds, "run_round", bad_model)
    run()
    run()
    assert ran == ["packed_000", "packed_000"] and not (tmp_path / "failed_rounds.json").exists()
