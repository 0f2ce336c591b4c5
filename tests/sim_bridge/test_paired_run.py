"""Pairing new methods with committed rounds (sim_bridge.analysis.paired_run): it copies
the run's config, excluded objects, scenes and the named methods' rounds and nothing else;
the benchmark then takes the copy as its own run (--report pools the copied rounds); it
refuses, copying nothing, rounds of another model than the current one; a rerun is a
no-op, and a directory holding another run is refused, not overwritten. The source is a
two-scene cut of the committed procedural_v4 run."""

import json
import shutil
from pathlib import Path

import pytest

from sim_bridge.benchmark import clutter_benchmark as cb
from sim_bridge.analysis import paired_run
from sim_bridge.benchmark import failed_rounds, run_files

REPO = Path(__file__).resolve().parents[2]
COMMITTED = REPO / "sim_bridge/results/procedural_v4"
MODELS = REPO / "models"
SCENES = ("packed_000", "pile_000")


@pytest.fixture
def source(tmp_path):
    """config.json, excluded_objects.json, two scenes and their 0.1 kg rounds of ours,
    binary and ours_expected, as committed."""
    src = tmp_path / "procedural_cut"
    src.mkdir()
    for f in ("config.json", "excluded_objects.json"):
        shutil.copyfile(COMMITTED / f, src / f)
    committed_rounds, committed_scenes = run_files.rounds_file(COMMITTED), run_files.scenes_file(COMMITTED)
    run_files.scenes_file(src).put(*(committed_scenes.get(s) for s in SCENES))
    run_files.rounds_file(src).put(*(committed_rounds.get(m, 0.1, s)
                                     for m in ("ours", "binary", "ours_expected") for s in SCENES))
    return src


def tree(root: Path) -> dict:
    """{file: bytes} of the run's files, {(method, kg, scene) or scene: record} of its records."""
    files = {p.name: p.read_bytes() for p in root.glob("*.json")}
    rounds = {(r["method"], r["mass_kg"], r["scene_id"]): r for r in run_files.rounds_file(root).records()}
    return {**files, **rounds, **{s["scene_id"]: s for s in run_files.scenes_file(root).records()}}


def test_it_copies_the_run_and_the_named_methods_rounds_and_nothing_else(source, tmp_path):
    out = tmp_path / "paired"
    counts = paired_run.prepare(source, out, ["ours", "binary"], MODELS)
    copied = tree(out)
    expected = {k: v for k, v in tree(source).items() if "ours_expected" not in k}
    assert copied == expected and counts == {"copied": len(expected), "kept": 0}
    assert ("ours", 0.1, "pile_000") in copied and "packed_000" in copied


def test_the_benchmark_takes_the_copy_as_its_own_run(source, tmp_path):
    """--report with the source run's options: the copied config.json is the one the
    benchmark builds (else it refuses the directory) and the copied rounds are counted
    (their model's sha256 is the current model's, so a run would not redo them)."""
    out = tmp_path / "paired"
    paired_run.prepare(source, out, ["ours", "binary"], MODELS)
    assert cb.main(["--out", str(out), "--report", "--scenes", "2", "--weights", "0.1", "--methods", "ours,binary",
                    "--models-dir", str(MODELS), "--no-progress"]) == 0
    rows = json.loads((out / "results.json").read_text())
    assert {(r["method"], r["rounds"]) for r in rows} == {("ours", 2), ("binary", 2)}
    (comparison,) = json.loads((out / "comparisons.json").read_text())
    assert comparison["method"] == "ours" and comparison["paired"]["scenes"] == 2


def test_rounds_of_another_model_are_refused_in_one_sentence_and_nothing_is_copied(source, tmp_path, capsys):
    models = tmp_path / "models"
    models.mkdir()
    (models / "gravgrasp.pt").write_bytes(b"a retrained model")
    shutil.copyfile(MODELS / "gravgrasp_binary.pt", models / "gravgrasp_binary.pt")
    out = tmp_path / "paired"
    with pytest.raises(paired_run.PairedRunError) as e:
        paired_run.prepare(source, out, ["binary", "ours"], models)
    message = str(e.value)
    assert "the rounds of ours were run with another model" in message and str(models / "gravgrasp.pt") in message
    assert "\n" not in message and not out.exists()
    # the command: one line on stderr, exit 2
    assert paired_run.main(["--source", str(source), "--out", str(out), "--methods", "ours",
                            "--models-dir", str(models)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("paired_run: ") and not out.exists()
    # the rounds of a model that is still the same are fine
    assert paired_run.prepare(source, out, ["binary"], models)["copied"] == 2 + 2 + 2


def test_a_rerun_keeps_everything_even_after_the_benchmark_has_run_there(source, tmp_path):
    out = tmp_path / "paired"
    first = paired_run.prepare(source, out, ["ours", "binary"], MODELS)
    # what a run adds: the hands and machines in config.json, its execution settings, new rounds
    config = json.loads((out / "config.json").read_text())
    config["protocol"].update({"approach_fast_speed_mps": 0.0, "freeze_resting_objects": False})
    (out / "config.json").write_text(json.dumps({**config, "hands": {"vgn": "panda"}, "machines": ["x"]}))
    run_files.rounds_file(out).put({"method": "vgn", "mass_kg": 0.1, "scene_id": "packed_000"})
    before = tree(out)
    assert paired_run.prepare(source, out, ["ours", "binary"], MODELS) == {"copied": 0, "kept": first["copied"]}
    assert tree(out) == before


def test_a_directory_holding_another_run_is_refused_not_overwritten(source, tmp_path):
    out = tmp_path / "paired"
    paired_run.prepare(source, out, ["ours"], MODELS)
    record = run_files.rounds_file(out).get("ours", 0.1, "packed_000")
    run_files.rounds_file(out).put({**record, "successes": record["successes"] + 1})
    config = json.loads((source / "config.json").read_text())
    (source / "config.json").write_text(json.dumps({**config, "seed": 7}))
    with pytest.raises(paired_run.PairedRunError, match="differs from its source.*2 such files or records.*another run"):
        paired_run.prepare(source, out, ["ours"], MODELS)
    assert run_files.rounds_file(out).get("ours", 0.1, "packed_000")["successes"] == record["successes"] + 1


def test_missing_rounds_are_a_note_and_failed_rounds_come_along(source, tmp_path):
    sha = run_files.rounds_file(source).get("ours", 0.1, "packed_000")["model_sha256"]
    failed_rounds.save(source, {failed_rounds.key("ours", 0.1, "pile_001"):
                                failed_rounds.record("ours", 0.1, "pile_001", sha, "RuntimeError: x", "m")})
    notes, out = [], tmp_path / "paired"
    paired_run.prepare(source, out, ["ours", "ours_precision"], MODELS, note=notes.append)
    assert len(notes) == 1 and "no rounds of ours_precision" in notes[0]
    assert list(failed_rounds.load(out)) == [("ours", 0.1, "pile_001")]


def test_a_source_without_a_run_is_one_sentence(tmp_path):
    with pytest.raises(paired_run.PairedRunError, match="holds no benchmark run"):
        paired_run.prepare(tmp_path / "nothing", tmp_path / "out", ["ours"], MODELS)
