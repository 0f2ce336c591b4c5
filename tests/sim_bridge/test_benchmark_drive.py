"""The benchmark's drive (protocol.Protocol.drive): the 2F-85's transmission in the cell is
recorded with a run and its rounds, a resume keeps it, and rounds of two drives are never
pooled in one report."""
import json

import pytest

from sim_bridge.benchmark import run_files
from sim_bridge.benchmark.protocol import Protocol, drive_of, drive_of_run
from sim_bridge.benchmark.report import write_outputs
from sim_bridge.benchmark.rounds import run_benchmark


def _config(tmp_path, **protocol):
    """A config.json as run_benchmark writes it (a back-drivable run has no drive key)."""
    import dataclasses
    p = {k: v for k, v in dataclasses.asdict(Protocol(**protocol)).items()
         if k not in ("clear_hand", "close_on_contact_within_m") and not (k == "drive" and v == "backdrivable")}
    (tmp_path / "config.json").write_text(json.dumps({"seed": 0, "meshes": None, "procedural_seed": 7,
                                                      "objects_per_scene": 5, "protocol": p}))


def test_a_run_keeps_its_drive_and_old_runs_read_as_backdrivable(tmp_path):
    assert drive_of_run(tmp_path) is None
    _config(tmp_path)
    assert drive_of_run(tmp_path) == "backdrivable"
    _config(tmp_path, drive="self_locking")
    assert drive_of_run(tmp_path) == "self_locking"
    assert drive_of({}) == "backdrivable"


def test_a_locked_run_refuses_to_resume_backdrivable(tmp_path):
    _config(tmp_path, drive="self_locking")
    model = tmp_path / "m.pt"
    model.write_bytes(b"x")
    run_benchmark(tmp_path, {"ours": str(model)}, [0.1], 2, protocol=Protocol(drive="self_locking"),
                  report_only=True, procedural_seed=7)
    with pytest.raises(ValueError, match="another configuration"):
        run_benchmark(tmp_path, {"ours": str(model)}, [0.1], 2, protocol=Protocol(), report_only=True,
                      procedural_seed=7)


def test_the_report_never_pools_rounds_of_two_drives(tmp_path):
    run_files.rounds_file(tmp_path).put({"model_sha256": "abc", "method": "ours", "mass_kg": 0.1,
                                         "scene_id": "packed_000", "attempts": []})  # before the drive was recorded
    with pytest.raises(ValueError, match="1 rounds .* backdrivable drive .* self_locking: .* never pooled"):
        write_outputs(tmp_path, {"ours": [0.1]}, {"ours": "abc"}, ["packed_000"], [], Protocol(drive="self_locking"), None)


def test_a_run_of_other_models_keeps_their_directory(tmp_path, capsys):
    """A run of models trained on other labels (e.g. models/v6, under the shipped methods'
    names) records where they are: a resume or --report without --models-dir finds them,
    another directory is refused, and the shipped models' runs record nothing (as before)."""
    from sim_bridge.benchmark import clutter_benchmark
    from sim_bridge.benchmark.rounds import models_dir_of_run
    shipped, other = tmp_path / "shipped", tmp_path / "v6"
    for d in (shipped, other):
        d.mkdir()
        (d / "gravgrasp.pt").write_bytes(d.name.encode())
    run = tmp_path / "run"
    run.mkdir()
    _config(run, drive="self_locking")
    config = json.loads((run / "config.json").read_text())
    (run / "config.json").write_text(json.dumps({**config, "models_dir": str(other)}))
    assert models_dir_of_run(run) == str(other) and models_dir_of_run(tmp_path / "none") is None
    args = ["--out", str(run), "--scenes", "2", "--weights", "0.1", "--methods", "ours", "--report",
            "--procedural-seed", "7", "--no-progress"]
    assert clutter_benchmark.main(args) == 0  # found in the run's own directory
    assert clutter_benchmark.main(args + ["--models-dir", str(other) + "/"]) == 0  # the same, however written
    assert clutter_benchmark.main(args + ["--models-dir", str(shipped)]) == 2
    err = capsys.readouterr().err
    assert f"ran the model files of {other}/, not {shipped}/: pass --models-dir {other}" in err
    plain = tmp_path / "plain"
    plain.mkdir()
    _config(plain, drive="self_locking")
    assert models_dir_of_run(plain) == "models"
