"""The label-time clearance lever (sim_bridge.studies.label_clearance_lever): labels whose
open hand the executor's clearance check refuses in the scene's observed TSDF become
explicit negatives, in scene files written for training.

Scenes: a hand-made 40^3 grid, unobserved (free) but for one observed wall, with one
top-down label whose open finger comes down through the wall and one in the open; and box_scenes' fused TSDFs of a box
(tests/support/box_scenes.py) for the agreement with the executor on many poses.
"""
import numpy as np

from gravgrasp_detector.execution.executor import ExecutionLimits, plan_poses, scene_collision
from gravgrasp_detector.perception import tsdf
from gravgrasp_detector.training import scenes as training_scenes
from gravgrasp_detector.training.config import TrainConfig
from sim_bridge.studies import label_clearance_lever as label_clearance

from box_scenes import write_scenes

R = tsdf.RESOLUTION
VOXEL_M = tsdf.SIZE_M / R
BESIDE_WALL, IN_THE_OPEN = (10, 10, 20), (30, 30, 20)


def wall_scene(path):
    """A scene file: an observed wall (occupied voxels, TSDF 0.3; 2 voxels thick, 120 mm
    tall) 45-53 mm beside the first label's TCP along its closing direction, where the
    open finger descends; nothing near the second label. Unobserved elsewhere (free)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    grid = np.zeros((R, R, R), np.float32)
    grid[6:15, 16:18, 14:30] = 0.3
    grid[6:15, 15, 14:30] = 0.5  # the face the camera saw: surface, not occupied
    np.savez(path, tsdf=grid, label_index=np.array([BESIDE_WALL, IN_THE_OPEN], np.uint8),
             label_score=np.array([30.0, 20.0], np.float32),
             label_e_x=np.array([[1.0, 0, 0], [0, 1.0, 0]], np.float32),
             label_e_z=np.array([[0, 0, -1.0], [0, 0, -1.0]], np.float32),
             label_mode=np.array([0, 1], np.uint8), mode_names=np.asarray(("power", "precision", "none")),
             negative_index=np.array([[2, 2, 2]], np.uint8), negative_reason=np.array([1], np.uint8))
    return path


def executor_refuses(scene):
    """The executor's own verdict per label: its planned poses, its scene_collision."""
    limits = ExecutionLimits()
    grid = (scene["tsdf"], VOXEL_M, np.zeros(3))
    poses = label_clearance.label_poses(scene["index"], scene["e_x"], scene["e_z"], VOXEL_M)
    return np.array([scene_collision(plan_poses(X, limits.pregrasp_distance_m, limits.lift_height_m), grid, limits)
                     != "" for X in poses])


def test_a_label_whose_finger_descends_through_a_seen_wall_becomes_a_negative_the_other_stays(tmp_path):
    path = wall_scene(tmp_path / "scenes" / "wall.npz")
    stored = training_scenes.load_scene(path)
    np.testing.assert_array_equal(label_clearance.refused_labels(stored), [True, False])

    assert label_clearance.write_scenes(tmp_path / "scenes", tmp_path / "out") == (1, 1)
    on = training_scenes.load_scene(tmp_path / "out" / "wall.npz")
    np.testing.assert_array_equal(on["index"], [IN_THE_OPEN])
    np.testing.assert_array_equal(on["score"], [20.0])
    np.testing.assert_array_equal(on["mode"], [1])
    np.testing.assert_array_equal(on["negative_index"], [[2, 2, 2], BESIDE_WALL])
    np.testing.assert_array_equal(on["negative_reason"], [1, label_clearance.NEGATIVE_REFUSED])
    np.testing.assert_array_equal(on["tsdf"], stored["tsdf"])
    # in the training example: the refused voxel is a validness 0, the other still a 1
    example = training_scenes.make_example(on, TrainConfig(data="", out=""))
    valid = {tuple(i): v for i, v in zip(example["index"].tolist(), example["valid"].tolist())}
    assert valid[BESIDE_WALL] == 0.0 and valid[IN_THE_OPEN] == 1.0
    # a second run keeps what the first wrote (an interrupted run resumes)
    assert label_clearance.write_scenes(tmp_path / "scenes", tmp_path / "out") == (0, 0)


def test_a_scene_with_nothing_refused_is_written_as_stored(tmp_path):
    (tmp_path / "scenes").mkdir()
    scenes = write_scenes(tmp_path / "scenes", 1, seed=3)
    [path] = sorted(scenes.glob("*.npz"))
    keep = ~label_clearance.refused_labels(training_scenes.load_scene(path))
    with np.load(path) as z:  # the same scene with only the labels the executor accepts
        arrays = {k: z[k] for k in z.files}
    for key in ("label_index", "label_score", "label_e_x", "label_e_z", "label_mode"):
        arrays[key] = arrays[key][keep]
    (tmp_path / "kept").mkdir()
    np.savez(tmp_path / "kept" / path.name, **arrays)
    assert label_clearance.write_scenes(tmp_path / "kept", tmp_path / "out") == (1, 0)
    with np.load(tmp_path / "kept" / path.name) as a, np.load(tmp_path / "out" / path.name) as b:
        assert sorted(a.files) == sorted(b.files)
        for key in a.files:
            np.testing.assert_array_equal(a[key], b[key])


def test_no_scene_files_is_one_clear_error(tmp_path, capsys):
    assert label_clearance.main([str(tmp_path)]) == 2
    assert "no scene files (*.npz) under" in capsys.readouterr().err


def test_the_verdict_is_the_executors_own_on_the_same_poses(tmp_path):
    rng = np.random.default_rng(5)
    verdicts = []
    for path in sorted(write_scenes(tmp_path, 3, seed=11).glob("*.npz")) + [wall_scene(tmp_path / "wall.npz")]:
        scene = training_scenes.load_scene(path)
        # the scene's labels, and as many random voxels and approaches within 40 deg of down
        n = 150
        tilt, yaw = np.radians(rng.uniform(0, 40, n)), rng.uniform(0, 2 * np.pi, n)
        e_z = np.stack([np.sin(tilt) * np.cos(yaw), np.sin(tilt) * np.sin(yaw), -np.cos(tilt)], 1)
        e_x = np.cross(e_z, rng.normal(size=(n, 3)))
        e_x /= np.linalg.norm(e_x, axis=1, keepdims=True)
        scene["index"] = np.concatenate([scene["index"], rng.integers(4, R - 4, size=(n, 3))])
        scene["e_x"], scene["e_z"] = np.concatenate([scene["e_x"], e_x]), np.concatenate([scene["e_z"], e_z])
        ours = label_clearance.refused_labels(scene)
        np.testing.assert_array_equal(ours, executor_refuses(scene))
        verdicts.append(ours)
    verdicts = np.concatenate(verdicts)
    assert 0.1 < verdicts.mean() < 0.9, "the poses should test both verdicts"


def test_the_check_on_the_stored_scene_is_the_check_on_the_rotated_one(tmp_path):
    """The lever checks the scene as stored, before training augments it: the same labels
    are refused whichever quarter turn the volume takes afterwards."""
    scene = training_scenes.load_scene(sorted(write_scenes(tmp_path, 1, seed=7).glob("*.npz"))[0])
    refused = label_clearance.refused_labels(scene)
    assert 0 < refused.sum() < len(refused)
    for k in range(1, 4):
        grid, index, e_x, e_z = training_scenes.rotate_about_gravity(scene["tsdf"], scene["index"], scene["e_x"],
                                                                     scene["e_z"], k)
        turned = dict(scene, tsdf=grid, index=index, e_x=e_x, e_z=e_z)
        np.testing.assert_array_equal(label_clearance.refused_labels(turned), refused)
