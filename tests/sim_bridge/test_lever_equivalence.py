"""The detection levers left the detector for the study that registers them
(sim_bridge.studies.detection_levers) and the benchmark's own clear_hand
(benchmark.methods.hand_clearing): every project method still picks the same grasps on a
fixed TSDF as when the levers were DetectionOptions fields.

tests/data/lever_equivalence/: tsdf.npz, a rendered tabletop (a box, a cylinder, a small
box; two views) and golden_grasps.json, each method's grasps on it (voxel, score,
validness, rank key, pose) with the shipped models, with and without the protocol's
clear_hand, written by the registry before the move."""

import dataclasses
import json
import math
import pathlib

import numpy as np
import pytest

from sim_bridge.benchmark import methods
from sim_bridge.benchmark.protocol import Protocol
from sim_bridge.studies import detection_levers

DATA = pathlib.Path(__file__).resolve().parents[1] / "data" / "lever_equivalence"
MODELS = pathlib.Path(__file__).resolve().parents[2] / "models"
GOLDEN = json.loads((DATA / "golden_grasps.json").read_text())


def cases():
    for key in GOLDEN:
        name, clear, payload = key.split("|")
        yield pytest.param(name, clear == "clear_hand=True", None if payload == "payload=None" else float(
            payload.split("=")[1]), GOLDEN[key], id=key)


def test_the_registry_holds_the_shipped_models_and_baselines_and_the_study_its_levers():
    shipped = {"ours", "ours_precision", "binary", "ours_ey_ez", "ours_quat", "vgn", "vgn_2f85", "vn_edge"}
    levers = {m.name for m in detection_levers.LEVERS}
    assert levers == {"ours_expected", "ours_sure", "ours_precision_sure", "ours_masked", "ours_mass", "ours_told",
                      "binary_scored"}
    assert shipped | levers <= set(methods.METHODS)  # the study registered its levers on import
    assert {methods.PROVIDERS[n] for n in levers} == {"sim_bridge.studies.detection_levers"}
    assert not shipped & set(methods.PROVIDERS)
    registry = (pathlib.Path(methods.__file__)).read_text()
    assert not [n for n in levers if f'"{n}"' in registry]


@pytest.mark.parametrize("name, clear_hand, payload_kg, golden", cases())
def test_a_method_picks_the_grasps_it_picked_when_levers_were_detection_options(name, clear_hand, payload_kg, golden):
    d = np.load(DATA / "tsdf.npz")
    method = methods.METHODS[name]
    protocol = dataclasses.replace(Protocol(), clear_hand=clear_hand)
    told = {"payload_kg": payload_kg} if payload_kg is not None else {}
    grasps = method.make(str(method.locate(MODELS)), protocol, **told).detect(
        (d["grid"], float(d["voxel_size_m"]), np.zeros(3)))
    assert [list(g.voxel_index) for g in grasps] == [g["voxel_index"] for g in golden]
    for g, want in zip(grasps, golden):
        assert (math.isnan(g.score_n) and want["score_n"] is None) or g.score_n == pytest.approx(want["score_n"], abs=1e-4)
        assert g.validness == pytest.approx(want["validness"], abs=1e-5)
        assert g.rank_key == pytest.approx(want["rank_key"], abs=1e-4)
        np.testing.assert_allclose(g.pose, want["pose"], atol=1e-6)


def test_the_calibrated_preference_reads_the_committed_calibration_file():
    line = json.loads((MODELS / "calibration" / "gravgrasp_executed_hold.json").read_text())
    assert detection_levers.held_payload_score_n(1.5) == pytest.approx(
        line["offset_n"] + line["n_per_weight_n"] * 1.5 * 9.81)
    with pytest.raises(ValueError, match="mass >= 0"):
        detection_levers.held_payload_score_n(-1.0)
