"""Training pipeline: losses, augmentation consistency, metrics, resume and determinism.

Scenes: tests/support/box_scenes.py (a real TSDF fusion of an analytic box, labelled
with top-down grasps over it).
"""
import json

import numpy as np
import pytest
import torch

from gravgrasp_detector.perception import model_file, networks, rotation
from gravgrasp_detector.tools import bench_train
from gravgrasp_detector.training import cli as training
from gravgrasp_detector.training import loop as training_loop
from gravgrasp_detector.training import losses as training_losses
from gravgrasp_detector.training import scenes as training_scenes
from gravgrasp_detector.training.config import TrainConfig

from box_scenes import write_scenes


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    return write_scenes(tmp_path_factory.mktemp("scenes"), 10, seed=7)


def test_quarter_turn_keeps_labels_on_the_same_geometry(scenes):
    scene = training_scenes.load_scene(sorted(scenes.glob("*.npz"))[0])
    grid = scene["tsdf"]
    for k in range(4):
        g, idx, ex, ez = training_scenes.rotate_about_gravity(grid, scene["index"], scene["e_x"], scene["e_z"], k)
        i, j, l = idx.T
        np.testing.assert_array_equal(g[i, j, l], grid[tuple(scene["index"].T)])
        # The approach stays vertical; e_x turns by k*90 deg about z.
        np.testing.assert_allclose(ez, scene["e_z"], atol=1e-6)
        angle = np.degrees(np.arctan2(ex[0, 1], ex[0, 0]) - np.arctan2(scene["e_x"][0, 1], scene["e_x"][0, 0]))
        assert np.isclose((angle - 90 * k + 180) % 360 - 180, 0, atol=1e-4)


def test_rotation_loss_is_zero_for_the_180_degree_twin():
    R = rotation.from_quat(torch.randn(16, 4))
    for rep in rotation.CHANNELS:
        twin_channels = rotation.encode(rep, rotation.symmetric_twin(R))
        assert training_losses.rotation_loss(rep, twin_channels, R) < 1e-8
        assert training_losses.rotation_loss(rep, rotation.encode(rep, R), R) < 1e-8
    other = rotation.from_quat(torch.randn(16, 4))
    assert training_losses.rotation_loss("ex-ez", rotation.encode("ex-ez", other), R) > 0.1


def test_validness_loss_weights_negatives_unlabelled_and_positives_as_configured():
    torch.manual_seed(0)
    logits = torch.randn(2, 6, 6, 6)
    at = (torch.tensor([0, 0, 1, 1]), torch.tensor([1, 2, 3, 4]), torch.tensor([1, 2, 3, 4]), torch.tensor([0, 1, 2, 3]))
    target = torch.tensor([1.0, 1.0, 0.0, 1.0])  # three positives, one explicit negative
    cfg = TrainConfig(data="", out="")
    # The defaults are v1's loss: every non-positive voxel weighs 1, positives the ratio.
    dense = torch.zeros_like(logits)
    dense[at] = target
    v1 = torch.nn.functional.binary_cross_entropy_with_logits(
        logits, dense, pos_weight=torch.tensor((logits.numel() - 3) / 3))
    assert training_losses.validness_loss(logits, at, target, cfg) == pytest.approx(float(v1), rel=1e-5)
    # Unlabelled voxels at weight 0 no longer count; the explicit negative still does.
    cfg = TrainConfig(data="", out="", unlabelled_weight=0.0, negative_weight=2.0)
    base = training_losses.validness_loss(logits, at, target, cfg)
    moved = logits.clone()
    moved[0, 5, 5, 5] += 10.0  # an unlabelled voxel
    assert training_losses.validness_loss(moved, at, target, cfg) == pytest.approx(float(base))
    moved[1, 3, 3, 2] += 10.0  # the negative, now confidently valid: worse
    assert training_losses.validness_loss(moved, at, target, cfg) > base + 1e-3
    # Balanced positives: the summed negative weight (one negative x 2) over 3 positives,
    # never below 1 (positives are not weighed down).
    expected = -(1.0 * torch.nn.functional.logsigmoid(logits[at][target > 0.5]).sum()
                 + 2 * torch.nn.functional.logsigmoid(-logits[at][target < 0.5]).sum()) / logits.numel()
    assert float(base) == pytest.approx(float(expected), rel=1e-5)


def test_explicit_negatives_move_with_the_volume_in_augmentation(scenes):
    scene = training_scenes.load_scene(sorted(scenes.glob("*.npz"))[0])
    r = scene["tsdf"].shape[0]
    scene["tsdf"] = (np.arange(r ** 3, dtype=np.float32).reshape((r,) * 3) + 1) / r ** 3  # every voxel its own value
    scene["negative_index"] = np.array([[10, 12, 3], [20, 21, 5], [30, 9, 8]])
    cfg = TrainConfig(data="", out="")
    rng = np.random.default_rng(3)
    for _ in range(6):
        ex = training_scenes.make_example(scene, cfg, rng)
        grid, idx, valid = ex["tsdf"][0].numpy(), ex["index"].numpy(), ex["valid"].numpy()
        values = grid[tuple(idx.T)]
        originals = np.rint(values * r ** 3 - 1).astype(np.int64)
        original_ijk = np.stack(np.unravel_index(originals, (r,) * 3), 1)
        negatives = valid == 0
        assert 1 <= negatives.sum() <= 3
        # each negative row sits on the voxel that came from a listed negative
        listed = {tuple(v) for v in scene["negative_index"]}
        assert all(tuple(v) in listed for v in original_ijk[negatives])
        assert not ex["score"][negatives].any() and ex["valid"][~negatives].all()


def test_auroc_matches_hand_computed_values():
    assert training_losses.auroc([0.1, 0.4, 0.35, 0.8], [0, 0, 1, 1]) == pytest.approx(0.75)
    assert training_losses.auroc([1, 2, 3], [0, 1, 1]) == 1.0
    assert training_losses.auroc([0.7] * 5, [0, 1, 0, 1, 1]) == 0.5  # ties: no ranking at all
    # both positives beat the 0.2 negative and tie the 0.9 one: (2 + 2 x 0.5) / 4
    assert training_losses.auroc([0.2, 0.9, 0.9, 0.9], [0, 0, 1, 1]) == pytest.approx(0.75)


@pytest.mark.parametrize("representation", ["ex-ez", "quat"])
def test_the_training_forward_gives_the_dense_forwards_losses_and_gradients(scenes, representation):
    """training_outputs skips the dense rotation head and runs dec3 and the heads on the
    half grid: the same losses and gradients as the dense forward, in float32 rounding."""
    torch.manual_seed(0)
    config = TrainConfig(data=str(scenes), out="", negative_weight=250.0)
    rng = np.random.default_rng(0)
    batch = [training_scenes.make_example(training_scenes.load_scene(f), config, rng)
             for f in sorted(scenes.glob("*.npz"))[:3]]
    x = torch.stack([ex["tsdf"] for ex in batch])
    model = networks.GraspNet(representation, score_scale_n=20.0)

    def loss_and_grads(outputs):
        model.zero_grad()
        terms = training_losses.losses(model, outputs, batch, config)
        terms["total"].backward()
        return {k: float(v.detach()) for k, v in terms.items()}, [p.grad.clone() for p in model.parameters()]

    dense, dense_grads = loss_and_grads(model(x))
    fast, fast_grads = loss_and_grads(training_losses.training_outputs(model, x, batch))
    assert dense["rotation"] > 0 and dense["score"] > 0
    assert fast == pytest.approx(dense, rel=1e-5)
    for a, b in zip(dense_grads, fast_grads):
        torch.testing.assert_close(b, a, rtol=1e-3, atol=1e-3 * float(a.abs().max()))


@pytest.mark.slow  # trains three times (minutes)
def test_training_learns_and_resumes_deterministically(scenes, tmp_path):
    # One thread: `make test` runs two test files at once on two cores, and two OpenMP
    # threads waiting on a busy core made this test 3-4x slower there.
    common = dict(data=str(scenes), batch_size=4, learning_rate=3e-3, seed=3, threads=1)
    full = training_loop.train(TrainConfig(out=str(tmp_path / "a"), epochs=4, **common), progress=False)
    history = json.loads((tmp_path / "a" / "history.json").read_text())
    assert len(history) == 4
    assert history[-1]["train_total"] < history[0]["train_total"]
    # Held-out scenes: score and rotation errors fall as it learns.
    assert history[-1]["val_score_mae_n"] < 0.7 * history[0]["val_score_mae_n"], history
    assert history[-1]["val_rotation_error_deg"] < 0.7 * history[0]["val_rotation_error_deg"], history
    assert (tmp_path / "a" / "training_curve.png").stat().st_size > 5000

    # Interrupted after 2 epochs, resumed to 4: the same weights as the straight run.
    training_loop.train(TrainConfig(out=str(tmp_path / "b"), epochs=2, **common), progress=False)
    resumed = training_loop.train(TrainConfig(out=str(tmp_path / "b"), epochs=4, **common), progress=False)
    assert resumed["val_loss_total"] == pytest.approx(full["val_loss_total"], rel=1e-5)

    model, meta = model_file.load_model(tmp_path / "a" / "model.pt")
    assert meta["training_data"]["scenes_train"] + meta["training_data"]["scenes_val"] == 10
    # Run again when finished: the model file is kept byte for byte (benchmark rounds
    # record its sha256), and the answer is the last epoch's.
    written = (tmp_path / "a" / "model.pt").read_bytes()
    again = training_loop.train(TrainConfig(out=str(tmp_path / "a"), epochs=4, **common), progress=False)
    assert (tmp_path / "a" / "model.pt").read_bytes() == written and again == history[-1]
    assert meta["network"]["rotation_representation"] == "ex-ez"


@pytest.mark.slow
def test_variants_train_and_record_their_target(scenes, tmp_path):
    for extra in ({"rotation": "quat"}, {"target": "binary", "nominal_mass_kg": 3.5},
                  {"subset": "precision-only"}, {"unlabelled_weight": 0.05, "negative_weight": 2.0}):
        out = tmp_path / "-".join(map(str, extra.values()))
        training_loop.train(TrainConfig(data=str(scenes), out=str(out), epochs=1, batch_size=5, threads=1, **extra),
                       progress=False)
        _, meta = model_file.load_model(out / "model.pt")
        for key, value in extra.items():
            if key in ("target", "subset", "nominal_mass_kg"):
                assert meta["training_data"][key] == value
            elif key.endswith("_weight"):
                assert meta["training_data"]["config"][key] == value
                assert meta["training_data"]["negatives_train"] > 0
                assert 0 <= meta["training_data"]["validation"]["val_validness_negatives_rejected"] <= 1
            else:
                assert meta["network"]["rotation_representation"] == value


def test_missing_data_is_one_clear_error(tmp_path, capsys):
    assert training.main(["--data", str(tmp_path), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "found 0 scene files" in err and "datagen scenes" in err


def test_precision_only_keeps_the_grasps_named_precision_in_the_scene_file(scenes):
    scene = training_scenes.load_scene(sorted(scenes.rglob("*.npz"))[0])
    config = TrainConfig(data="", out="", subset="precision-only")
    _, score, *_ = training_scenes.select_labels(scene, config)
    precision = scene["mode"] == 1  # make_scene: mode_names[1] == "precision" (score <= 35)
    assert len(score) == precision.sum() > 0
    assert (score <= 35).all()
    # A file that orders its names differently is read by name, not by number.
    swapped = dict(scene, mode_names=("precision", "power", "none"))
    _, score_swapped, *_ = training_scenes.select_labels(swapped, config)
    assert (score_swapped > 35).all() and len(score_swapped) == (~precision).sum()


def test_training_step_benchmark_prints_its_figure_last(capsys):
    bench_train.main(["--batch-size", "2", "--steps", "1", "--threads", "1"])
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[-1].startswith("train_step_s=") and float(lines[-1].split("=")[1]) > 0
    assert any(line.startswith("train_step_dense_s=") for line in lines)
