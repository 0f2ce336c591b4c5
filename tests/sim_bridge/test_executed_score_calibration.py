"""The executed-score calibration (studies/executed_score_calibration.py) on round files
whose outcomes are drawn from a known P(held | placed, score, weight): the fit recovers the
score a grasp needs; copies of a round count once; other models' rounds do not count."""
import hashlib
import json
import math

import numpy as np
import pytest

from sim_bridge.benchmark import run_files
from sim_bridge.studies import executed_score_calibration as esc

TRUE_W = (-1.0, 0.08, -0.12)  # intercept, per N of score, per N of weight


def write_rounds(folder, sha, n_rounds=400, seed=0):
    rng = np.random.default_rng(seed)
    records = []
    for i in range(n_rounds):
        mass = (0.1, 0.5, 1.5, 4.0)[i % 4]
        attempts = []
        for _ in range(5):
            s = float(rng.uniform(20, 110))
            v = float(rng.uniform(0.5, 1.0))
            if rng.random() > 0.3 + 0.6 * v:  # placement depends on validness
                attempts.append({"outcome": "no_object", "reason": "the grasp missed the object", "score_n": s,
                                 "validness": v, "rank_key": s})
                continue
            p = 1 / (1 + math.exp(-(TRUE_W[0] + TRUE_W[1] * s + TRUE_W[2] * mass * 9.81)))
            held = rng.random() < p
            attempts.append({"outcome": "success" if held else "dropped", "reason": "", "score_n": s,
                             "validness": v, "rank_key": s})
        records.append({"scene_id": f"scene_{i:03d}", "method": "ours", "mass_kg": mass, "model_sha256": sha,
                        "target": "gravity-score", "attempts": attempts})
    run_files.rounds_file(folder).put(*records)


@pytest.fixture
def model(tmp_path):
    path = tmp_path / "model.pt"
    path.write_bytes(b"weights")
    return path, hashlib.sha256(b"weights").hexdigest()


def test_the_fit_recovers_the_score_a_grasp_needs(tmp_path, model, capsys):
    path, sha = model
    write_rounds(tmp_path / "a", sha)
    out = tmp_path / "cal.json"
    assert esc.main(["--model", str(path), "--results", str(tmp_path / "a"), "--out", str(out),
                     "--bootstrap-draws", "100"]) == 0
    result = json.loads(out.read_text())
    true_needed = esc.score_needed_n(TRUE_W, 0.8, 1.5)  # (1.386 + 1 + 1.766) / 0.08 = 51.9 N
    assert result["score_needed_n"]["0.8"]["1.5"] == pytest.approx(true_needed, abs=5.0)
    assert result["score_per_weight_n"] == pytest.approx(1.5, abs=0.4)
    fitted = result["score_needed_n"]["0.8"]["1.5"]
    assert result["interval"]["low_n"] < fitted < result["interval"]["high_n"]
    assert result["interval"]["high_n"] - result["interval"]["low_n"] < 10.0  # 2,000 attempts pin it to a few N
    placed = {lo: frac for lo, hi, n, frac, ci in result["placed_by_validness"]}
    assert placed[0.0] < placed[0.95]  # placement rises with validness, as drawn
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert last.startswith("score_for_hold_0.8_at_1.5kg_n=")
    assert float(last.split("=")[1]) == pytest.approx(result["score_needed_n"]["0.8"]["1.5"], abs=0.05)


def test_copies_count_once_and_other_models_not_at_all(tmp_path, model):
    path, sha = model
    write_rounds(tmp_path / "a", sha, n_rounds=40)
    write_rounds(tmp_path / "copy", sha, n_rounds=40)  # the same rounds, as analysis.paired_run copies them
    write_rounds(tmp_path / "other", "0" * 64, n_rounds=40, seed=1)
    once = esc.load_attempts([tmp_path / "a"], sha)
    assert len(once) == 200
    assert esc.load_attempts([tmp_path / "a", tmp_path / "copy", tmp_path / "other"], sha) == once


def test_bad_inputs_get_one_sentence(tmp_path, model, capsys):
    path, sha = model
    out = str(tmp_path / "x.json")
    assert esc.main(["--model", str(tmp_path / "none.pt"), "--results", str(tmp_path), "--out", out]) == 2
    assert "no model file" in capsys.readouterr().err
    assert esc.main(["--model", str(path), "--results", str(tmp_path / "missing"), "--out", out]) == 2
    assert "has no rounds" in capsys.readouterr().err
    write_rounds(tmp_path / "b", "0" * 64, n_rounds=8)  # no round of this model
    assert esc.main(["--model", str(path), "--results", str(tmp_path / "b"), "--out", out]) == 2
    assert "0 placed attempts" in capsys.readouterr().err
    assert esc.main(["--model", str(path), "--results", str(tmp_path / "b"), "--out", out, "--hold", "1"]) == 2
    assert "between 0 and 1" in capsys.readouterr().err


def test_the_calibration_file_is_the_committed_study():
    """detection_levers.held_payload_score_n (ours_told's preference, from
    models/calibration/gravgrasp_executed_hold.json) says what the committed study measured:
    rerunning the study without updating the calibration file fails here."""
    import pathlib

    from sim_bridge.studies import detection_levers
    result = json.loads((pathlib.Path(__file__).parents[2] / "sim_bridge/results/executed_score_calibration.json")
                        .read_text())
    assert result["interval"]["hold_p"] == 0.8
    for m, needed in result["score_needed_n"]["0.8"].items():
        assert detection_levers.held_payload_score_n(float(m)) == pytest.approx(needed, abs=0.3)
