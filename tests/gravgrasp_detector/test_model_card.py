"""Model cards (gravgrasp_detector/tools/model_card.py) from a tiny real training run.

Six synthetic scenes (tests/support/box_scenes.make_scene: a fused TSDF of a box with top-down
labels) laid out as `datagen scenes` does (DATA/scenes/*.npz + manifest.json naming the
grasp tables), three small grasp tables, two epochs of `training_loop.train`.
"""
import functools
import json
import shutil

import numpy as np
import pytest

from gravgrasp_detector.perception import model_file
from gravgrasp_detector.tools import model_card
from gravgrasp_detector.training import loop as training_loop
from gravgrasp_detector.training.config import TrainConfig
from box_scenes import make_scene

pytestmark = pytest.mark.slow  # the fixture trains a model

_DATA_SUMMARY_ONCE = functools.cache(model_card.data_summary)  # per (data dir, tables dir), for this module


@pytest.fixture(autouse=True)
def data_report_once_per_inputs(monkeypatch):
    """The card's dataset summary is sim_bridge's data_report in a subprocess (~5 CPU-s,
    most of a card's time): it runs once for each tables + scenes pair this module asks
    about, and later cards reuse its answer. Every test still renders real cards."""
    monkeypatch.setattr(model_card, "data_summary", _DATA_SUMMARY_ONCE)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    root = tmp_path_factory.mktemp("card")
    tables = root / "tables" / "objects"
    tables.mkdir(parents=True)
    for n in range(3):  # 3 held grasps per object: power, precision, power; one missed
        np.savez(tables / f"obj{n}.npz", mode_names=np.array(["power", "precision", "none"]),
                 mode=np.array([0, 1, 0, 2], np.uint8), grasped=np.array([1, 1, 1, 0], bool),
                 scores_n=np.full((4, 6), 10.0), wall_time_s=np.ones(4))
    scenes = root / "data" / "scenes"
    scenes.mkdir(parents=True)
    rng = np.random.default_rng(7)
    for n in range(6):
        make_scene(scenes / f"{n:06d}.npz", rng)
        z = dict(np.load(scenes / f"{n:06d}.npz"))
        np.savez_compressed(scenes / f"{n:06d}.npz", **z, arrangement=np.asarray("packed"))  # datagen writes it
    (scenes / "manifest.json").write_text(json.dumps({"objects_dir": str(tables)}))
    out = root / "run"
    training_loop.train(TrainConfig(data=str(root / "data"), out=str(out), epochs=2, threads=1), progress=False)
    models = root / "models"
    models.mkdir()
    shutil.copy(out / "model.pt", models / "gravgrasp.pt")
    return root, out, models / "gravgrasp.pt"


def _card(run, *extra):
    root, out, model = run
    argv = [str(out), "--model", str(model), "--qualitative", str(root / "qualitative"), *extra]
    assert model_card.main(argv) == 0
    return (model.parent / "gravgrasp.md").read_text()


def test_card_has_metrics_data_command_and_machine(run):
    root, out, model = run
    history = json.loads((out / "history.json").read_text())
    card = _card(run)
    rows = {line.split("|")[1].strip(): line for line in card.splitlines() if line.startswith("| ")}
    final = history[-1]
    assert f"| {final['val_score_mae_n']:.3g} (epoch 2) |" in rows["score MAE [N] (valid voxels)"]
    assert f"| {final['val_rotation_error_deg']:.3g} (epoch 2) |" in rows["rotation error [deg] (valid voxels, 180° twin)"]
    best_auroc = max(history, key=lambda h: h["val_validness_auroc"])
    assert rows["validness AUROC"].endswith(f"| {best_auroc['val_validness_auroc']:.3g} ({best_auroc['epoch']}) |")
    # data: from data_report over the manifest's tables (3 objects, 9 held, 6 power) and the scene files
    assert "3 objects, 9 held grasps, power fraction 0.667" in card
    assert "scenes: 6 (packed 6)" in card
    recorded = model_file.load_model(model)[1]["training_data"]
    assert f"command (as `train` recorded it): `{recorded['command']}`" in card
    assert recorded["machine"]["cpu"] in card and "torch threads 1" in card
    first, second = history[0]["wall_s"], history[1]["wall_s"] - history[0]["wall_s"]
    slow = 1 if first >= second else 2
    assert f"median {(first + second) / 2:.1f} s, slowest {max(first, second):.1f} s (epoch {slow})" in card
    assert f"`{model_file.file_sha256(model)}`" in card
    assert "_Not run yet: no PNGs" in card and model_card.HUMAN_PLACEHOLDER in card
    assert "recipes restore" not in card  # named only when --recipes says where they are
    with_recipes = _card(run, "--recipes", "models/scene_recipes_v9")
    restore = f"`python -m sim_bridge.datagen recipes restore models/scene_recipes_v9 {recorded['data']} "
    assert f"{restore}--objects {root / 'tables'} --meshes ../shared/meshes/vgn_train` rebuilds" in with_recipes
    # recipes packed from scenes of other tables: the card's scenes are those relabelled
    other = root / "recipes_of_other_tables"
    other.mkdir(exist_ok=True)
    (other / "manifest.json").write_text(json.dumps({"objects_dir": "/x/grasp_tables_v1/objects"}))
    assert "vgn_train --relabel` rebuilds" in _card(run, "--recipes", str(other))
    # the curve is copied beside the card (a clone has no out/) and linked there
    copy = model.parent / "gravgrasp_training_curve.png"
    assert copy.read_bytes() == (out / "training_curve.png").read_bytes()
    assert "(gravgrasp_training_curve.png)" in card


def test_qualitative_pngs_are_linked_and_human_notes_survive(run):
    root, out, model = run
    qdir = root / "qualitative"
    qdir.mkdir(exist_ok=True)
    for name in model_card.SLICE_PNGS[:3]:
        (qdir / name).write_bytes(b"png")
    card = _card(run)
    assert "(../qualitative/slice_z080mm.png)" in card  # relative to models/
    assert "depth.png) (missing)" in card
    notes = "Score peaks around the cylinder at z = 0.08 m; the box's 100 mm side is rejected."
    path = model.parent / "gravgrasp.md"
    path.write_text(card.replace(model_card.HUMAN_PLACEHOLDER, notes))
    again = _card(run)
    assert notes in again and model_card.HUMAN_PLACEHOLDER not in again


def test_bad_inputs_are_one_line(run, tmp_path, capsys):
    root, out, model = run
    other = tmp_path / "other.pt"
    other.write_bytes(model.read_bytes() + b"\0")
    assert model_card.main([str(out), "--model", str(other)]) == 2
    assert model_card.main([str(tmp_path), "--model", str(model)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2
    assert "is not the model of" in err[0]
    assert "history.json is missing" in err[1]


def test_calibration_reports_stand_side_by_side_and_a_bad_one_is_one_line(run, tmp_path, capsys):
    def report(model, precision, mae, label, negative):
        picks = {"1": {"label": label, "negative": negative, "neither": 100 - label - negative}}
        return {"model": model, "data": "out/scenes_v6", "scenes": 100, "split": "val",
                "validness": {"precision": precision, "recall": 0.9, "threshold": 0.5, "auroc": 0.98},
                "modes": {"all": {"mae_n": mae, "spearman": 0.6}, "power": {"mae_n": 2 * mae, "spearman": 0.5}},
                "top_picks": {"score": picks, "expected_score": picks, "validness": picks}}
    new, old = tmp_path / "v6.json", tmp_path / "v4.json"
    v6 = report("models/v6/gravgrasp.pt", 0.21, 11.5, 61, 20)
    v6["validness"]["precision_at_recall"] = {"0.8": 0.31, "0.9": 0.2, "0.95": 0.125}
    new.write_text(json.dumps(v6))
    old.write_text(json.dumps(report("models/gravgrasp.pt", 0.15, 12.8, 44, 34)))
    card = _card(run, "--calibration", str(new), "--calibration", str(old))
    rows = {line.split("|")[1].strip(): line for line in card.splitlines() if line.startswith("| ")}
    assert "`models/v6/gravgrasp.pt` on `out/scenes_v6`" in card and "`models/gravgrasp.pt` on" in card
    assert rows["validness precision / recall (at its threshold)"].count("/ 0.900 (0.5)") == 2
    assert "| 0.210 / 0.900 (0.5) | 0.150 / 0.900 (0.5) |" in rows["validness precision / recall (at its threshold)"]
    # at equal recall: the older report (made before the key) reads as a dash
    assert "| 0.310 / 0.200 / 0.125 | — |" in rows["validness precision at equal recall 0.8 / 0.9 / 0.95"]
    assert "| 11.50 | 12.80 |" in rows["score MAE [N], all"] and "| 23.00 | 25.60 |" in rows["score MAE [N], power"]
    assert "| — | — |" in rows["score MAE [N], precision"]  # not in the reports: a dash, not an error
    assert "| 0.61 / 0.61 / 0.61 | 0.44 / 0.44 / 0.44 |" in rows[
        "first pick on a held label, by score / validness × score / validness"]
    assert "## Calibration" not in _card(run)  # only with --calibration
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"validness": {}}))
    root, out, model = run
    assert model_card.main([str(out), "--model", str(model), "--calibration", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a score_calibration report" in err[0] and "calibration.json" in err[0]
