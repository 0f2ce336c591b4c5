"""Training pipeline: losses, augmentation consistency, metrics, resume and determinism.

Scenes are made here from a real TSDF fusion (tsdf.TSDFVolume) of an analytic box
ray-cast with numpy, labelled with top-down grasps over the box; small enough that
a few epochs take seconds, structured enough that learning is measurable.
"""
import json

import numpy as np
import pytest
import torch

from gravgrasp_detector import model_file, rotation, training, training_loop, training_losses, training_scenes, tsdf
from gravgrasp_detector.training_config import TrainConfig


def _box_depth(intr, T_task_camera, box_min, box_max, table_z=0.05):
    """Ray-cast depth [m] of an axis-aligned box on a table plane (numpy)."""
    u, v = np.meshgrid(np.arange(intr.width), np.arange(intr.height))
    rays_c = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u, float)], -1)
    R, t = T_task_camera[:3, :3], T_task_camera[:3, 3]
    d = rays_c @ R.T
    depth_along = np.full(u.shape, np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        s_table = (table_z - t[2]) / d[..., 2]
        depth_along = np.where(s_table > 0, s_table, np.inf)
        t0 = (box_min - t) / d
        t1 = (box_max - t) / d
        near = np.nanmax(np.minimum(t0, t1), -1)
        far = np.nanmin(np.maximum(t0, t1), -1)
        hit = (near <= far) & (near > 0)
        depth_along = np.where(hit & (near < depth_along), near, depth_along)
    depth_along[~np.isfinite(depth_along)] = 0.0
    return depth_along.astype(np.float32)  # rays_c has unit z: parameter == depth


def _look_at(eye, target):
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(z, [0, 0, 1.0]); x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4); T[:3, :3] = np.stack([x, y, z], 1); T[:3, 3] = eye
    return T


def make_scene(path, rng):
    size = rng.uniform(0.04, 0.07, size=2)
    height = rng.uniform(0.05, 0.12)
    centre = rng.uniform(0.11, 0.19, size=2)
    box_min = np.array([*(centre - size / 2), 0.05]); box_max = np.array([*(centre + size / 2), 0.05 + height])
    volume = tsdf.TSDFVolume()
    intr = tsdf.CameraIntrinsics(160, 120, 140.0, 140.0, 80.0, 60.0)
    for yaw in rng.uniform(0, 2 * np.pi, size=2):
        eye = np.array([0.15 + 0.5 * np.cos(yaw), 0.15 + 0.5 * np.sin(yaw), 0.55])
        T = _look_at(eye, np.array([0.15, 0.15, 0.05]))
        volume.integrate(_box_depth(intr, T, box_min, box_max), intr, T)
    # Top-down grasps across the box's narrow side: TCP 2 cm below the top face.
    vs = volume.voxel_size_m
    xs = np.arange(box_min[0] + 0.01, box_max[0] - 0.01, vs)
    ys = np.arange(box_min[1] + 0.01, box_max[1] - 0.01, vs)
    p = np.array([(x, y, box_max[2] - 0.02) for x in xs for y in ys])
    index = np.floor(p / vs).astype(np.int64)
    e_z = np.tile([0, 0, -1.0], (len(p), 1))
    e_x = np.tile([1.0, 0, 0] if size[1] < size[0] else [0, 1.0, 0], (len(p), 1))
    score = 40.0 - 200.0 * np.linalg.norm(p[:, :2] - centre, axis=1)  # best at the centre
    np.savez_compressed(path, tsdf=volume.grid(), label_index=index, label_score=score.astype(np.float32),
                        label_e_x=e_x.astype(np.float32), label_e_z=e_z.astype(np.float32),
                        # the best-held grasps (centre) as power, the rest precision
                        label_mode=np.where(score > 35, 0, 1).astype(np.uint8),
                        mode_names=np.asarray(("power", "precision", "none")))


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    root = tmp_path_factory.mktemp("scenes")
    rng = np.random.default_rng(7)
    for n in range(10):
        make_scene(root / f"scene_{n:03d}.npz", rng)
    return root


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


def test_auroc_matches_hand_computed_values():
    assert training_losses.auroc([0.1, 0.4, 0.35, 0.8], [0, 0, 1, 1]) == pytest.approx(0.75)
    assert training_losses.auroc([1, 2, 3], [0, 1, 1]) == 1.0


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
    assert meta["network"]["rotation_representation"] == "ex-ez"


@pytest.mark.slow
def test_variants_train_and_record_their_target(scenes, tmp_path):
    for extra in ({"rotation": "quat"}, {"target": "binary", "nominal_mass_kg": 3.5},
                  {"subset": "precision-only"}):
        out = tmp_path / "-".join(map(str, extra.values()))
        training_loop.train(TrainConfig(data=str(scenes), out=str(out), epochs=1, batch_size=5, threads=1, **extra),
                       progress=False)
        _, meta = model_file.load_model(out / "model.pt")
        for key, value in extra.items():
            if key in ("target", "subset", "nominal_mass_kg"):
                assert meta["training_data"][key] == value
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
