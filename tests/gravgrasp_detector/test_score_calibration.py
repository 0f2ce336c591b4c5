"""Score calibration (`ros2 run gravgrasp_detector calibration`): predicted against
simulated score at the labelled voxels, per mode, on the held-out scenes."""
import json

import numpy as np
import pytest
import torch

from gravgrasp_detector.perception import model_file, networks, tsdf
from gravgrasp_detector.tools import score_calibration
from gravgrasp_detector.training import scenes as training_scenes

from box_scenes import write_scenes


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    return write_scenes(tmp_path_factory.mktemp("scenes"), 6, seed=11)


class Oracle(torch.nn.Module):
    """Predicts f(simulated score) at each labelled voxel of one scene, 0 elsewhere, and
    validness logit +10 at the labelled voxels, -10 elsewhere."""

    def __init__(self, scene, f):
        super().__init__()
        dense = torch.zeros(scene["tsdf"].shape)
        i, j, k = torch.from_numpy(scene["index"]).T
        dense[i, j, k] = torch.from_numpy(f(scene["score"]))
        self.dense = dense
        self.logit = torch.full(dense.shape, -10.0)
        self.logit[i, j, k] = 10.0
        self.resolution = dense.shape[0]

    def forward(self, x):
        assert x.shape == (1, 1, *self.dense.shape)
        return {"score_n": self.dense[None], "validness_logit": self.logit[None]}


def pairs_of(model, path):
    return score_calibration.summarise(score_calibration.network_at_labels(model, [path])[0])


def test_pairs_are_taken_at_the_labelled_voxels_per_mode(scenes):
    path = sorted(scenes.glob("*.npz"))[0]
    scene = training_scenes.load_scene(path)
    counts = {name: int((scene["mode"] == m).sum()) for m, name in enumerate(scene["mode_names"])}
    exact = pairs_of(Oracle(scene, lambda s: s), path)
    assert {name: row["n"] for name, row in exact.items() if name != "all"} == \
        {name: n for name, n in counts.items() if n}
    assert exact["all"]["n"] == len(scene["score"])
    for row in exact.values():
        assert row["mae_n"] == pytest.approx(0.0, abs=1e-5)
    assert exact["all"]["spearman"] == pytest.approx(1.0)
    high = pairs_of(Oracle(scene, lambda s: s + 5.0), path)
    assert high["all"]["mae_n"] == pytest.approx(5.0, abs=1e-4) and high["all"]["spearman"] == pytest.approx(1.0)
    assert high["all"]["mean_predicted_n"] == pytest.approx(high["all"]["mean_simulated_n"] + 5.0, abs=1e-3)
    flipped = pairs_of(Oracle(scene, lambda s: 60.0 - s), path)
    assert flipped["all"]["spearman"] == pytest.approx(-1.0)


def test_validness_of_an_oracle_is_exact_and_a_constant_is_not(scenes):
    path = sorted(scenes.glob("*.npz"))[0]
    scene = training_scenes.load_scene(path)
    oracle = Oracle(scene, lambda s: s)
    _, (probability, labelled) = score_calibration.network_at_labels(oracle, [path])
    assert labelled.sum() == len(scene["index"])  # every label lies near an observed surface
    assert len(labelled) > 10 * labelled.sum()  # and many candidate voxels hold none
    v = score_calibration.validness_summary(probability, labelled)
    assert v["precision"] == 1.0 and v["recall"] == 1.0 and v["auroc"] == 1.0
    top = v["reliability"][-1]
    assert top["voxels"] == labelled.sum() and top["fraction_valid"] == 1.0
    assert v["reliability"][0]["fraction_valid"] == 0.0
    oracle.logit.fill_(0.0)  # 0.5 everywhere: everything passes the threshold, nothing ranks
    _, (probability, labelled) = score_calibration.network_at_labels(oracle, [path])
    v = score_calibration.validness_summary(probability, labelled)
    assert v["recall"] == 1.0 and v["precision"] == pytest.approx(labelled.mean()) and v["auroc"] == 0.5


def test_precision_at_equal_recall_is_read_where_recall_reaches_it():
    # 4 positives among 8, ranked: + + - + - - + -
    probability = np.array([0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2])
    labelled = np.array([1, 1, 0, 1, 0, 0, 1, 0], bool)
    p = score_calibration.precision_at_recall(probability, labelled, recalls=(0.5, 0.75, 1.0))
    assert p == {"0.5": 1.0, "0.75": 0.75, "1.0": 4 / 7}  # 2 of 2, 3 of 4, 4 of 7 taken
    assert all(np.isnan(v) for v in score_calibration.precision_at_recall(probability, labelled * False).values())


def test_cli_scores_the_held_out_scenes_and_writes_the_figure(scenes, tmp_path, capsys):
    model_path = tmp_path / "model.pt"
    torch.manual_seed(0)
    model_file.save_model(model_path, networks.GraspNet(), tsdf.TSDFVolume(),
                          training_data={"config": {"seed": 3, "validation_fraction": 0.3}})
    files = sorted(str(p) for p in scenes.rglob("*.npz"))
    held_out = training_scenes.split_scenes(files, 0.3, 3)[1]
    assert 0 < len(held_out) < len(files)

    out = tmp_path / "val"
    assert score_calibration.main(["--model", str(model_path), "--data", str(scenes), "--out", str(out)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    report = json.loads((out / "calibration.json").read_text())
    assert report["scenes"] == len(held_out) and report["split"] == "val"
    expected = {}
    for f in held_out:
        scene = training_scenes.load_scene(f)
        for m, name in enumerate(scene["mode_names"]):
            if (scene["mode"] == m).any():
                expected[name] = expected.get(name, 0) + int((scene["mode"] == m).sum())
    expected["all"] = sum(expected.values())
    assert {name: row["n"] for name, row in report["modes"].items()} == expected
    assert lines[-1] == f"score_mae_n={report['modes']['all']['mae_n']:.2f}"
    assert lines[-6].startswith("validness near surfaces:") and report["validness"]["voxels"] > 0
    assert lines[-5].startswith("score ranking: top 1 on a label ") and lines[-4].startswith("expected_score ranking:")
    assert lines[-2].startswith("told the mass (by validness among grasps scored >= 1.5 x m g): top 1 on a label "
                                "holding 0.1 kg ")
    assert set(report["top_picks"]) == {"score", "expected_score", "validness"} | {
        f"told_{m:g}kg" for m in score_calibration.HOLDS_KG}
    assert (out / "calibration.png").stat().st_size > 5000

    assert score_calibration.main(["--model", str(model_path), "--data", str(scenes), "--split", "all",
                                   "--out", str(tmp_path / "all")]) == 0
    everything = json.loads((tmp_path / "all" / "calibration.json").read_text())
    assert everything["scenes"] == len(files) and set(everything["modes"]) == {"power", "precision", "all"}


def test_bad_inputs_are_one_line_each(scenes, tmp_path, capsys):
    assert score_calibration.main(["--model", str(tmp_path / "none.pt"), "--data", str(scenes)]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    model_path = tmp_path / "model.pt"
    model_file.save_model(model_path, networks.GraspNet(), tsdf.TSDFVolume())
    assert score_calibration.main(["--model", str(model_path), "--data", str(tmp_path / "empty")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no scene files" in err[0]
    assert score_calibration.main(["--model", str(model_path), "--data", str(scenes), "--validness-threshold", "1.5"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "outside [0, 1]" in err[0]


def test_top_picks_are_told_apart_by_what_the_scene_knows_of_their_voxel(scenes, tmp_path, monkeypatch):
    import numpy as np

    from gravgrasp_detector.perception.detection import Grasp
    path = sorted(scenes.glob("*.npz"))[0]
    scene = training_scenes.load_scene(path)
    label = tuple(scene["index"][0].tolist())
    negative = next((i, 0, 0) for i in range(40) if (i, 0, 0) not in {tuple(v) for v in scene["index"].tolist()})
    z = dict(np.load(path))
    z["negative_index"] = np.asarray([negative], np.uint8)
    edited = tmp_path / path.name  # not in the shared fixture's folder: other tests glob it
    np.savez(edited, **z)
    order = {"score": [negative, label, (39, 39, 39)], "expected_score": [label, negative, (39, 39, 39)],
             "validness": []}
    monkeypatch.setattr(score_calibration, "pick_grasps", lambda model, grid, vs, ranking, options: [
        Grasp(np.eye(4), 1.0, 1.0, v) for v in order[ranking if ranking in order else options.rank_by]])
    picks = score_calibration.top_picks(None, {}, [edited], 0.0075)
    where = lambda c: {w: c[w] for w in ("label", "negative", "neither")}  # noqa: E731
    assert where(picks["score"][1]) == {"label": 0, "negative": 1, "neither": 0}
    assert where(picks["expected_score"][1]) == {"label": 1, "negative": 0, "neither": 0}
    assert where(picks["score"][5]) == where(picks["expected_score"][5]) == {"label": 1, "negative": 1, "neither": 1}
    # a binary model has one ranking, its validness
    monkeypatch.setattr(score_calibration, "pick_grasps", lambda model, grid, vs, ranking, options: [
        Grasp(np.eye(4), 1.0, 1.0, label)] if options.rank_by == "validness" else [])
    assert list(score_calibration.top_picks(None, {"training_data": {"target": "binary"}}, [edited], 0.0075)) == \
        ["validness"]


def test_a_pick_holds_the_weights_its_closest_label_holds(scenes, tmp_path, monkeypatch):
    """Two labels at one voxel, 10 N and 30 N, turned 90 deg apart: a pick takes the f_g of
    the one its rotation matches (pads swapped counts as the same), so it holds 0.1 and
    0.5 kg but not 1.5 kg (14.7 N) on the first, and up to 2.5 kg (24.5 N) on the second."""
    import numpy as np

    from gravgrasp_detector.perception.detection import Grasp
    path = sorted(scenes.glob("*.npz"))[0]
    z = dict(np.load(path))
    voxel = np.asarray([[20, 20, 10]], z["label_index"].dtype)
    z.update(label_index=np.repeat(voxel, 2, axis=0), label_score=np.asarray([10.0, 30.0], z["label_score"].dtype),
             label_e_x=np.asarray([[1, 0, 0], [0, 1, 0]], z["label_e_x"].dtype),
             label_e_z=np.asarray([[0, 0, -1], [0, 0, -1]], z["label_e_z"].dtype),
             label_mode=np.zeros(2, z["label_mode"].dtype), negative_index=np.zeros((0, 3), np.uint8))
    edited = tmp_path / path.name
    np.savez(edited, **z)

    def pick(e_x):
        pose = np.eye(4)
        pose[:3, 0], pose[:3, 2] = e_x, [0, 0, -1]
        pose[:3, 1] = np.cross(pose[:3, 2], pose[:3, 0])
        return Grasp(pose, 20.0, 0.9, (20, 20, 10))

    for e_x, held in (([1, 0, 0], {"0.1": 1, "0.5": 1, "1.5": 0, "2.5": 0, "4.0": 0}),
                      ([0, -1, 0], {"0.1": 1, "0.5": 1, "1.5": 1, "2.5": 1, "4.0": 0})):
        monkeypatch.setattr(score_calibration, "pick_grasps", lambda model, grid, vs, ranking, options, e_x=e_x: [pick(e_x)])
        picks = score_calibration.top_picks(None, {"training_data": {"target": "binary"}}, [edited], 0.0075)
        assert picks["validness"][1]["label"] == 1 and picks["validness"][1]["holds_kg"] == held
    seen = []
    monkeypatch.setattr(score_calibration, "pick_grasps", lambda model, grid, vs, ranking, options: seen.append(
        options.validness_threshold) or [])
    score_calibration.top_picks(None, {}, [edited], 0.0075, validness_threshold=0.9)
    assert seen == [0.9] * (3 + len(score_calibration.HOLDS_KG))  # each ranking with the threshold asked for
    told = score_calibration.pick_options("told_1.5kg", True, 0.5)
    assert told.rank_by == "validness" and told.min_score_n == pytest.approx(1.5 * 9.81 * 1.5)
    assert [score_calibration.told_mass_kg(score_calibration.told_ranking(m)) for m in (0.1, 4.0)] == [0.1, 4.0]
    assert score_calibration.told_mass_kg("validness") is None
    assert score_calibration.label_score_at(training_scenes.load_scene(edited), Grasp(np.eye(4), 1.0, 1.0, (0, 0, 0))) is None
