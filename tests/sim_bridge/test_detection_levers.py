"""The detection levers as benchmark methods (sim_bridge.studies.detection_levers): each
runs its base method's model file under its own ranking or selection."""
import dataclasses
import json

import numpy as np
import pytest
import torch

from gravgrasp_detector.perception import detection, model_file, networks, tsdf
from sim_bridge.benchmark import methods, protocol
from sim_bridge.benchmark import rounds as bench_rounds
from sim_bridge.benchmark.methods import vgn
from sim_bridge.studies import detection_levers

from made_models import save_test_model

pytestmark = pytest.mark.drake


def test_a_ranking_variant_runs_its_base_methods_model_under_its_own_ranking(tmp_path):
    save_test_model(tmp_path / "gravgrasp.pt", validness_bias=0.0)
    other = save_test_model(tmp_path / "elsewhere.pt", validness_bias=0.0)
    assert bench_rounds.resolve_methods(["ours_expected"], tmp_path) == {
        "ours_expected": str((tmp_path / "gravgrasp.pt").resolve())}
    # --model ours=PATH moves the variant with it (the v4 chain benchmarks out/training_v4 models)
    assert bench_rounds.resolve_methods(["ours", "ours_expected"], tmp_path, {"ours": str(other)}) == {
        "ours": str(other.resolve()), "ours_expected": str(other.resolve())}
    grid = np.zeros((40, 40, 40), np.float32)
    grid[10:30, 10:30, 6:12] = 0.3
    grid[10:30, 10:30, 12] = 0.5
    p = protocol.Protocol(validness_threshold=0.0)
    by_score = methods.METHODS["ours"].make(str(other), p).detect((grid, 0.0075, np.zeros(3)))
    by_expected = methods.METHODS["ours_expected"].make(str(other), p).detect((grid, 0.0075, np.zeros(3)))
    keys = [g.validness * g.score_n for g in by_expected]
    assert keys == sorted(keys, reverse=True) and [g.score_n for g in by_score] == sorted(
        (g.score_n for g in by_score), reverse=True)
    assert [g.rank_key for g in by_expected] == pytest.approx(keys)  # the key is its own field, score_n stays N
    assert all(g.rank_key == g.score_n for g in by_score)
    assert [g.voxel_index for g in by_expected] != [g.voxel_index for g in by_score]


def test_a_selection_variant_takes_only_sure_grasps_of_its_base_methods_model(tmp_path):
    save_test_model(tmp_path / "gravgrasp.pt")
    assert bench_rounds.resolve_methods(["ours_sure"], tmp_path) == {
        "ours_sure": str((tmp_path / "gravgrasp.pt").resolve())}
    grid = np.zeros((40, 40, 40), np.float32)
    grid[10:30, 10:30, 6:12] = 0.3
    grid[10:30, 10:30, 12] = 0.5
    p = protocol.Protocol(validness_threshold=0.0)
    # The test model's validness is the same everywhere: sigmoid(bias), 0.88 and 0.92 here.
    for bias, sure_expected in ((2.0, False), (2.5, True)):
        path = save_test_model(tmp_path / f"{bias}.pt", validness_bias=bias)
        every = methods.METHODS["ours"].make(str(path), p).detect((grid, 0.0075, np.zeros(3)))
        sure = methods.METHODS["ours_sure"].make(str(path), p).detect((grid, 0.0075, np.zeros(3)))
        assert every and all(g.rank_key == g.score_n for g in every)
        voxels = [tuple(g.voxel_index) for g in sure]
        assert voxels == ([tuple(g.voxel_index) for g in every] if sure_expected else [])
        # Ours-Precision's sure variant: the same floor on the precision-only model's file
        precision_sure = methods.METHODS["ours_precision_sure"].make(str(path), p).detect((grid, 0.0075, np.zeros(3)))
        assert [tuple(g.voxel_index) for g in precision_sure] == voxels
    save_test_model(tmp_path / "gravgrasp_precision_only.pt")
    assert bench_rounds.resolve_methods(["ours_precision_sure"], tmp_path) == {
        "ours_precision_sure": str((tmp_path / "gravgrasp_precision_only.pt").resolve())}



def test_binary_scored_takes_binarys_sure_grasps_ranked_by_ours_score(tmp_path):
    """binary_scored: Binary's model places (its validness floor 0.9, its poses), Ours'
    model beside it ranks by its score, which the grasps carry; without Ours' file beside
    Binary's it is missing, and a score model without a score is refused."""
    grid = np.zeros((40, 40, 40), np.float32)
    grid[10:30, 10:30, 6:12] = 0.3
    grid[10:30, 10:30, 12] = 0.5
    view = (grid, 0.0075, np.zeros(3))
    p = protocol.Protocol(validness_threshold=0.0, max_grasps=1000)
    method = methods.METHODS["binary_scored"]
    assert method.file_of == "binary" and method.hand == "2f85"
    binary = save_test_model(tmp_path / "gravgrasp_binary.pt", target="binary")
    notes = []
    assert bench_rounds.resolve_methods(["binary_scored"], tmp_path, note=notes.append) == {}
    assert "gravgrasp.pt not found beside gravgrasp_binary.pt: get it from models/" in notes[0]
    torch.manual_seed(3)
    ours = networks.GraspNet(score_scale_n=30.0)  # scores unlike the binary model's own head
    model_file.save_model(tmp_path / "gravgrasp.pt", ours, tsdf.TSDFVolume(resolution=40),
                          training_data={"target": "gravity-score"})
    assert bench_rounds.resolve_methods(["binary_scored"], tmp_path) == {"binary_scored": str(binary.resolve())}
    detector = method.make(str(binary), p)
    assert detector.target == "gravity-score"
    scored = detector.detect(view)
    placed = methods.METHODS["binary"].make(str(binary), dataclasses.replace(p, validness_threshold=0.9)).detect(view)
    assert scored and len(scored) <= len(placed)
    assert all(g.validness >= 0.9 and np.isfinite(g.score_n) for g in scored)
    assert [g.score_n for g in scored] == sorted((g.score_n for g in scored), reverse=True)
    pose_at = {tuple(g.voxel_index): g.pose for g in placed}
    assert all(np.allclose(g.pose, pose_at[tuple(g.voxel_index)]) for g in scored if tuple(g.voxel_index) in pose_at)
    save_test_model(tmp_path / "gravgrasp.pt", target="binary")
    with pytest.raises(model_file.ModelFileError, match="no gravity-rejection score"):
        method.make(str(binary), p)


def test_the_masked_variant_takes_only_grasps_vgns_mask_keeps_of_its_base_methods_model(tmp_path):
    path = save_test_model(tmp_path / "gravgrasp.pt")
    assert bench_rounds.resolve_methods(["ours_masked"], tmp_path) == {"ours_masked": str(path.resolve())}
    assert methods.METHODS["ours_masked"].file_of == "ours" and methods.METHODS["ours_masked"].hand == "2f85"
    grid = np.zeros((40, 40, 40), np.float32)
    grid[10:30, 10:30, 6:12] = 0.3  # observed inside
    grid[10:30, 10:30, 12] = 0.5  # the surface
    grid[10:30, 10:30, 13:16] = 0.7  # observed free space in front of it
    p = protocol.Protocol(validness_threshold=0.0, max_grasps=1000)
    every = methods.METHODS["ours"].make(str(path), p).detect((grid, 0.0075, np.zeros(3)))
    masked = methods.METHODS["ours_masked"].make(str(path), p).detect((grid, 0.0075, np.zeros(3)))
    band = vgn.free_space_band(grid).numpy()

    def kept(g):  # VGN's mask where VGN's TCP would sit on the grasp's approach
        point = g.pose[:3, 3] + vgn.FINGER_BASE_Z_M * g.pose[:3, 2]
        return bool(band[tuple(np.floor(point / 0.0075).astype(int))])
    assert masked and all(kept(g) for g in masked)
    assert any(not kept(g) for g in every)  # the paper's selection takes grasps the mask drops

def test_the_method_told_the_mass_takes_the_surest_grasps_predicted_to_hold_it(tmp_path):
    """ours_mass keeps the grasps scored >= 1.5 x m g and ranks them by validness; a binary
    model has no score to keep them by (one sentence). make_cell tells it each round's mass
    (test_benchmark_methods)."""
    path = save_test_model(tmp_path / "gravgrasp.pt", validness_bias=0.0)
    method = methods.METHODS["ours_mass"]
    assert method.told_payload and method.file_of == "ours" and not methods.METHODS["ours"].told_payload
    grid = np.zeros((40, 40, 40), np.float32)
    grid[10:30, 10:30, 6:12] = 0.3
    grid[10:30, 10:30, 12] = 0.5
    p = protocol.Protocol(validness_threshold=0.0, max_grasps=1000)
    every = methods.METHODS["ours"].make(str(path), p).detect((grid, 0.0075, np.zeros(3)))
    scores = sorted(g.score_n for g in every)
    mass_kg = scores[len(scores) // 2] / (9.81 * detection.PAYLOAD_SAFETY_FACTOR)  # half the grasps hold it
    told = method.make(str(path), p, payload_kg=mass_kg).detect((grid, 0.0075, np.zeros(3)))
    assert told and all(g.score_n >= detection.payload_min_score_n(mass_kg) for g in told)
    assert [g.rank_key for g in told] == sorted((g.validness for g in told), reverse=True)
    assert len(told) < len(every)
    binary = save_test_model(tmp_path / "binary.pt", target="binary")
    with pytest.raises(ValueError, match="has none"):
        method.make(str(binary), p, payload_kg=1.0)


def test_the_method_told_the_mass_by_calibration_prefers_what_held_it(tmp_path, monkeypatch):
    """ours_told ranks by validness with the grasps scored >= held_payload_score_n(m) (the
    calibration file's line) first
    and the others after them: a mass no grasp is scored for leaves the validness ranking,
    not an empty view as ours_mass's floor would."""
    path = save_test_model(tmp_path / "gravgrasp.pt", validness_bias=0.0)
    method = methods.METHODS["ours_told"]
    assert method.told_payload and method.file_of == "ours"
    grid = np.zeros((40, 40, 40), np.float32)
    grid[10:30, 10:30, 6:12] = 0.3
    grid[10:30, 10:30, 12] = 0.5
    p = protocol.Protocol(validness_threshold=0.0, max_grasps=1000)
    view = (grid, 0.0075, np.zeros(3))
    by_validness = methods.METHODS["ours_mass"].make(str(path), p, payload_kg=0.0).detect(view)  # no floor
    calibration = tmp_path / "executed_hold.json"  # offset 0: the untrained net scores ~7 N
    calibration.write_text(json.dumps({"offset_n": 0.0, "n_per_weight_n": 1.64}))
    monkeypatch.setattr(detection_levers, "EXECUTED_HOLD_FILE", calibration)
    scores = sorted(g.score_n for g in by_validness)
    mass_kg = scores[len(scores) // 2] / (1.64 * 9.81)  # half are scored for it
    told = method.make(str(path), p, payload_kg=mass_kg).detect(view)
    strong = [g.score_n >= detection_levers.held_payload_score_n(mass_kg) for g in told]
    assert any(strong) and strong == sorted(strong, reverse=True)
    assert [g.rank_key for g in told] == pytest.approx(
        sorted((g.validness + s for g, s in zip(told, strong)), reverse=True), abs=1e-6)
    # (a weaker grasp next to a preferred one loses the non-maximum suppression to it)
    heavy = method.make(str(path), p, payload_kg=1e4).detect(view)
    assert [g.voxel_index for g in heavy] == [g.voxel_index for g in by_validness]


VS = 0.0075


def test_a_preferred_score_orders_but_never_empties():
    """preferring(n) (ours_told's rank_key, n: held_payload_score_n): ranked by validness,
    the grasps scored at least that first, then the others; above every score it leaves the
    validness ranking as it was, where min_score_n would leave nothing."""
    torch.manual_seed(0)
    net = networks.GraspNet().eval()
    grid = np.zeros((40, 40, 40), np.float32)
    grid[:, :, 3:7], grid[:, :, 7:11] = 0.3, 0.7  # a table
    options = detection.DetectionOptions(validness_threshold=0.0, max_grasps=1000, rank_by="validness")
    plain = detection.detect_grasps(net, grid, VS, options=options)

    def prefer(n):
        with torch.inference_mode():
            half, score_n, validness = detection.network_outputs(net, torch.from_numpy(grid), "fp32")
            return detection.select_grasps(torch.from_numpy(grid), score_n, validness, detection.rotations_at(net, half),
                                           net.rotation_representation, VS, options=options,
                                           rank_key=detection_levers.preferring(n)(score_n, validness))
    prefer_n = float(np.median([g.score_n for g in plain]))
    preferred = prefer(prefer_n)
    strong = [g.score_n >= prefer_n for g in preferred]
    assert any(strong) and not all(strong)
    assert strong == sorted(strong, reverse=True)  # every preferred grasp before every other
    for group in (True, False):
        v = [g.validness for g, s in zip(preferred, strong) if s == group]
        assert v == sorted(v, reverse=True)
    assert all(g.rank_key == pytest.approx(g.validness + s) for g, s in zip(preferred, strong))
    assert [g.voxel_index for g in prefer(1e6)] == [g.voxel_index for g in plain]
    assert not detection.detect_grasps(net, grid, VS, options=dataclasses.replace(options, min_score_n=1e6))
