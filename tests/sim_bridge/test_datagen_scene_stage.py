"""Scene stage on hand-made grasp tables (the object stage's output format): real
Drake settling, real ray-cast depth and TSDF; labels checked against Eq. 1, the
voxel grid and the collision model; deterministic and resumable per scene."""

import numpy as np
import pytest
import trimesh

from gravgrasp_detector.execution.executor import ExecutionLimits
from sim_bridge.studies import fingertip_check_study
from sim_bridge.datagen.antipodal_sampling import sample_grasp_candidates
from sim_bridge.datagen.object_grasps import MODE_NAMES, load_table
from sim_bridge.datagen.object_sources import object_from_table
from sim_bridge.datagen.scene_dataset import (NEGATIVE_COLLIDES, NEGATIVE_FAILED, negative_voxels,
                                              requested_object_count, run_scene_stage)
from sim_bridge.datagen.voxel_labels import RESOLUTION
from sim_bridge.physics import hand_collision
from sim_bridge.physics.hand_model import FingerKinematics
from sim_bridge.physics.gravity_projection import gravity_rejection_score
from sim_bridge.physics.scenes import TABLE_HEIGHT_M, VOLUME_SIZE_M

from run_shared import shared_dir
from test_datagen_objects import write_urdf
from test_object_symmetry import surface_distance

pytestmark = pytest.mark.drake
FINGER_JOINTS = ("left_coupler", "left_driver", "left_follower", "left_spring_link",
                 "right_coupler", "right_driver", "right_follower", "right_spring_link")


def make_grasp_data(root):
    """Hand-made grasp tables of a box, a cylinder and a cube (300 candidates each)."""
    meshes = root / "meshes"
    meshes.mkdir(parents=True)
    shapes = {"box": trimesh.creation.box((0.05, 0.06, 0.08)),
              "cyl": trimesh.creation.cylinder(radius=0.025, height=0.10, sections=32),
              "cube": trimesh.creation.box((0.045, 0.045, 0.045))}
    objects = root / "objects" / "objects"
    objects.mkdir(parents=True)
    for k, (name, mesh) in enumerate(shapes.items()):
        write_urdf(meshes, name, mesh, 0.2)
        X = sample_grasp_candidates(mesh, 300, seed=k)
        n = len(X)
        rng = np.random.default_rng(k)
        scores = rng.uniform(1, 60, (n, 6)).astype(np.float32)
        grasped = rng.uniform(size=n) < 0.9
        mode = np.where(grasped, rng.integers(0, 2, n), 2).astype(np.uint8)
        # the hand settles ~5 mm deeper than it was driven (as power grasps do): labels
        # must carry the commanded pose, which clears the object
        settled = X.copy()
        settled[:, :3, 3] += 0.005 * X[:, :3, 2]
        # fingers closed in parallel (as on a precision grasp, driver at 0.6 rad): their
        # pad tips reach ~17 mm past the TCP, 13 mm further than the open hand's
        q = np.where(grasped, 0.6, 0.0)[:, None]
        angles = np.hstack([0 * q, q, -0.96 * q, q] * 2).astype(np.float32)
        np.savez(objects / f"{name}.npz", name=np.asarray(name), source_kind=np.asarray("mesh"),
                 source=np.asarray(f"{name}.urdf"), X_object_tcp_candidate=X.astype(np.float32),
                 X_object_tcp=settled.astype(np.float32),
                 scores_n=np.where(grasped[:, None], scores, 0), mode=mode, grasped=grasped,
                 mode_names=np.asarray(MODE_NAMES), finger_joint_names=np.asarray(FINGER_JOINTS),
                 finger_joint_angles=angles)


def run(grasp_data, out, n):
    return run_scene_stage(out, grasp_data / "objects", [grasp_data / "meshes"], n, seed=5, workers=2,
                           max_objects=3, max_views=3, progress=False)


def make_stage_run(root):
    make_grasp_data(root / "data")
    s = run(root / "data", root / "scenes", 3)
    assert s["done"] == 3 and s["error"] == 0, s["errors"]


@pytest.fixture(scope="module")
def stage_run(tmp_path_factory):
    """The grasp tables and a 3-scene stage run on them, made once per pytest run
    (run_shared): test_scene_recipes reads them too. Tests only read them."""
    return shared_dir(tmp_path_factory, "scene_stage_run", make_stage_run)


@pytest.fixture(scope="module")
def grasp_data(stage_run):
    return stage_run / "data"


@pytest.fixture(scope="module")
def scenes(stage_run):
    return stage_run / "scenes"


def test_scene_files_hold_tsdf_and_labels_that_match_eq1(grasp_data, scenes):
    total, copies, mirrored, dropped = 0, 0, 0, 0
    fingers = FingerKinematics()
    symmetries = {p.stem: np.load(p)["transforms"] for p in (grasp_data / "objects" / "symmetry").glob("*.npz")}
    for name, S in symmetries.items():  # every copy moves the surface onto itself
        m = trimesh.load(grasp_data / "meshes" / f"{name}.obj")
        pts = m.sample(500, seed=1)
        assert len(S) > 1 and np.allclose(S[0], np.eye(4))
        for X in S:
            assert surface_distance(m, pts @ X[:3, :3].T + X[:3, 3]).max() < 0.002
    for p in sorted((scenes / "scenes").glob("*.npz")):
        z = dict(np.load(p))
        assert z["tsdf"].shape == (RESOLUTION,) * 3 and z["tsdf"].dtype == np.float32
        assert 0 <= z["tsdf"].min() and z["tsdf"].max() <= 1 and (z["tsdf"] > 0).sum() > 1000
        assert 1 <= len(z["T_task_camera"]) <= 3 and str(z["arrangement"]) in ("packed", "pile")
        K = len(z["label_score"])
        total += K
        copies += int((z["label_symmetry"] > 0).sum())
        assert K <= z["n_grasps_collision_free"] <= z["n_grasps_projected"]
        assert len(np.unique(z["label_index"], axis=0)) == K  # one label per voxel
        tables = [load_table(grasp_data / "objects" / "objects" / f"{n}.npz") for n in z["object_names"]]
        X_obj = z["X_task_object"].astype(np.float64)
        others = []
        for k in range(len(tables)):  # the object model the scene stage loads (URDF)
            m = object_from_table(tables[k], [grasp_data / "meshes"]).collision_mesh()
            others.append(hand_collision.surface_points(m) @ X_obj[k, :3, :3].T + X_obj[k, :3, 3])
        for i in range(K):
            k, row = z["label_object"][i], z["label_grasp"][i]
            t = tables[k]
            assert t["grasped"][row] and z["label_mode"][i] == t["mode"][row] != 2
            assert str(z["label_pose"]) == "commanded"
            # a simulated grasp, or its copy at a symmetry of the object (object_symmetry;
            # at a reflection the hand is mirrored too, and its +x and -x scores exchange)
            S = symmetries[str(z["object_names"][k])][z["label_symmetry"][i]]
            is_mirror = np.linalg.det(S[:3, :3]) < 0
            mirrored += int(is_mirror)
            M = np.diag([-1.0, 1, 1, 1]) if is_mirror else np.eye(4)
            X = X_obj[k] @ S @ t["X_object_tcp_candidate"][row].astype(np.float64) @ M
            assert np.linalg.det(X[:3, :3]) == pytest.approx(1.0)
            scores = t["scores_n"][row][[1, 0, 2, 3, 4, 5]] if is_mirror else t["scores_n"][row]
            # the label sits in the voxel of the grasp's TCP, with its axes
            np.testing.assert_array_equal(z["label_index"][i], np.floor(X[:3, 3] / (VOLUME_SIZE_M / RESOLUTION)))
            np.testing.assert_allclose(z["label_e_x"][i], X[:3, 0], atol=1e-5)
            np.testing.assert_allclose(z["label_e_z"][i], X[:3, 2], atol=1e-5)
            # f_g is Eq. 1 of this grasp's scores in this scene's pose
            assert z["label_score"][i] == pytest.approx(gravity_rejection_score(scores, X[:3, :3]), rel=1e-5)
            # and the open hand there, with its approach, clears the table and every object
            # (its own too: the commanded pose is where the open hand really goes)
            obst = np.concatenate(others)
            assert not hand_collision.collides(X, obst, table_z_m=TABLE_HEIGHT_M, approach_m=0.05)[0]
            # ... and so does it at the voxel centre, the pose detection publishes, where
            # the closed fingers' pad tips stay above the table too
            X_exec = X.copy()
            X_exec[:3, 3] = (z["label_index"][i] + 0.5) * (VOLUME_SIZE_M / RESOLUTION)
            assert not hand_collision.collides(X_exec, obst, table_z_m=TABLE_HEIGHT_M, approach_m=0.05)[0]
            tips = fingers.pad_tips_tcp(t["finger_joint_names"], t["finger_joint_angles"][row])[0]
            assert (tips @ X_exec[:3, :3].T + X_exec[:3, 3])[:, 2].min() >= TABLE_HEIGHT_M
        dropped += int(z["n_grasps_dropped_executed"])
    assert total > 30 and 0 < copies < total and 0 < mirrored < copies
    assert dropped > 0  # the check at the executed pose is not vacuous here


def test_explicit_negatives_are_failures_and_colliding_poses_off_the_labels(grasp_data, scenes):
    voxel = VOLUME_SIZE_M / RESOLUTION
    reasons = []
    for p in sorted((scenes / "scenes").glob("*.npz")):
        z = dict(np.load(p))
        neg, lab = z["negative_index"], z["label_index"]
        assert neg.dtype == np.uint8 and neg.shape[1] == 3 and len(z["negative_reason"]) == len(neg)
        assert len(np.unique(neg, axis=0)) == len(neg)  # one entry per voxel
        flat = lambda ijk: set(np.ravel_multi_index(ijk.astype(np.int64).T, (RESOLUTION,) * 3))  # noqa: E731
        assert not flat(neg) & flat(lab)
        reasons += list(z["negative_reason"])
        # every simulated failure's voxel (the commanded pose, as tried) is a negative or a label
        known = flat(neg) | flat(lab)
        for k, name in enumerate(z["object_names"]):
            t = load_table(grasp_data / "objects" / "objects" / f"{name}.npz")
            X = z["X_task_object"][k].astype(np.float64) @ t["X_object_tcp_candidate"][~t["grasped"]].astype(np.float64)
            ijk = np.floor(X[:, :3, 3] / voxel).astype(np.int64)
            inside = ((ijk >= 0) & (ijk < RESOLUTION)).all(1)
            assert flat(ijk[inside]) <= known
    assert set(reasons) == {NEGATIVE_FAILED, NEGATIVE_COLLIDES}


def test_negative_voxels_take_the_first_reason_and_skip_labels():
    def at(*points):
        X = np.repeat(np.eye(4)[None], len(points), 0)
        X[:, :3, 3] = points
        return X
    v = VOLUME_SIZE_M / RESOLUTION
    c = lambda i, j, k: ((i + 0.5) * v, (j + 0.5) * v, (k + 0.5) * v)  # noqa: E731
    out = negative_voxels(np.array([[1, 1, 1]]), at(c(1, 1, 1), c(2, 2, 2), c(5, 5, 5)),
                          at(c(2, 2, 2), c(3, 3, 3), (-0.01, 0.1, 0.1)))
    assert out["index"].tolist() == [[2, 2, 2], [3, 3, 3], [5, 5, 5]]
    assert out["reason"].tolist() == [NEGATIVE_FAILED, NEGATIVE_COLLIDES, NEGATIVE_FAILED]
    empty = negative_voxels(np.zeros((0, 3)), np.zeros((0, 4, 4)), np.zeros((0, 4, 4)))
    assert empty["index"].shape == (0, 3) and empty["reason"].shape == (0,)


def test_a_scene_is_reproducible_from_its_seed_and_a_resumed_run_fills_gaps(grasp_data, scenes, tmp_path):
    # regenerate only scene 1 in a new directory: scenes 0 and 2 copied, 1 missing
    (tmp_path / "scenes").mkdir()
    for i in (0, 2):
        (tmp_path / "scenes" / f"{i:06d}.npz").write_bytes((scenes / "scenes" / f"{i:06d}.npz").read_bytes())
    (tmp_path / "scenes" / ".000001.npz.1234.tmp").write_bytes(b"partial write of a killed run")
    s = run(grasp_data, tmp_path, 3)
    assert s["done"] == 3
    assert not list((tmp_path / "scenes").glob("*.tmp"))
    a, b = np.load(scenes / "scenes" / "000001.npz"), np.load(tmp_path / "scenes" / "000001.npz")
    assert sorted(a.files) == sorted(b.files)
    for key in a.files:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def test_a_drop_that_blows_up_numerically_is_redrawn(grasp_data, monkeypatch):
    from sim_bridge.datagen import scene_dataset
    real, calls = scene_dataset.arrange, []

    def arrange_once_nan(*args, **kwargs):
        calls.append(1)
        if len(calls) == 1:
            raise RuntimeError("SceneGraph encountered a non-finite value (e.g., NaN or infinity) on a pose input port.")
        return real(*args, **kwargs)
    monkeypatch.setattr(scene_dataset, "arrange", arrange_once_nan)
    objects_dir = grasp_data / "objects" / "objects"
    task = scene_dataset.SceneTask(0, 5, str(objects_dir), tuple(scene_dataset.usable_tables(objects_dir)),
                                   (str(grasp_data / "meshes"),), max_objects=3, max_views=1)
    status, scene = scene_dataset.run_scene(task)
    assert status == "ok" and len(calls) == 2 and len(scene["object_names"]) >= 1, scene
    def arrange_fails(*args, **kwargs):
        raise RuntimeError("other")
    monkeypatch.setattr(scene_dataset, "arrange", arrange_fails)
    assert scene_dataset.run_scene(task) == ("error", "scene 0: RuntimeError: other")


def first_scene(grasp_data, out, **options):
    """Scene 0 of the module's seed, made again with other options."""
    s = run_scene_stage(out, grasp_data / "objects", [grasp_data / "meshes"], 1, seed=5, workers=1,
                        max_objects=3, max_views=3, progress=False, **options)
    assert s["done"] == 1 and s["error"] == 0
    return np.load(out / "scenes" / "000000.npz")


def test_mirror_copies_can_be_left_out(grasp_data, scenes, tmp_path):
    rotations = first_scene(grasp_data, tmp_path, mirrors=False)
    both = np.load(scenes / "scenes" / "000000.npz")
    np.testing.assert_array_equal(rotations["tsdf"], both["tsdf"])
    assert not bool(rotations["mirrors"]) and bool(both["mirrors"])
    assert int(rotations["n_labels_without_copies"]) < len(rotations["label_score"]) < len(both["label_score"])


def test_without_symmetry_a_scene_has_just_the_simulated_grasps_labels(grasp_data, scenes, tmp_path):
    plain = first_scene(grasp_data, tmp_path, symmetry=False)
    copied = np.load(scenes / "scenes" / "000000.npz")
    # the same scene (seeded), labelled from the simulated grasps only
    np.testing.assert_array_equal(plain["tsdf"], copied["tsdf"])
    assert not plain["label_symmetry"].any()
    assert len(plain["label_score"]) == int(copied["n_labels_without_copies"]) == int(plain["n_labels_without_copies"])
    assert len(copied["label_score"]) > len(plain["label_score"])


def test_without_the_execution_check_labels_are_checked_only_where_simulated(grasp_data, scenes, tmp_path):
    unchecked = first_scene(grasp_data, tmp_path, execution_check=False)
    checked = np.load(scenes / "scenes" / "000000.npz")
    np.testing.assert_array_equal(unchecked["tsdf"], checked["tsdf"])
    assert bool(checked["execution_check"]) and not bool(unchecked["execution_check"])
    assert int(unchecked["n_grasps_dropped_executed"]) == 0 < int(checked["n_grasps_dropped_executed"])
    # n_grasps_collision_free counts what passed every check; the checked scene also drops
    # grasps outside the executor's cone before any other check (clear of the scene or not)
    assert int(unchecked["n_grasps_outside_cone"]) == 0 < int(checked["n_grasps_outside_cone"])
    passed, dropped, outside = (int(checked[k]) for k in ("n_grasps_collision_free", "n_grasps_dropped_executed",
                                                           "n_grasps_outside_cone"))
    assert passed + dropped <= int(unchecked["n_grasps_collision_free"]) <= passed + dropped + outside
    assert len(checked["label_score"]) < len(unchecked["label_score"])
    # the fixture's free sampler approaches from anywhere: only checked labels all keep to the cone
    def degrees_from_down(z):
        e_z = z["label_e_z"] / np.linalg.norm(z["label_e_z"], axis=1, keepdims=True)
        return np.degrees(np.arccos(np.clip(-e_z[:, 2], -1, 1)))
    assert degrees_from_down(checked).max() <= ExecutionLimits.approach_cone_deg + 1e-3
    assert degrees_from_down(unchecked).max() > ExecutionLimits.approach_cone_deg


def test_object_counts_follow_vgns_poisson_capped_or_are_uniform():
    rng = np.random.default_rng(0)
    poisson = np.bincount([requested_object_count(rng, "poisson", 5) for _ in range(4000)], minlength=6)[1:] / 4000
    # Poisson(4) + 1 capped at 5: P(1..5) = 1.8, 7.3, 14.7, 19.5, 56.7 %
    np.testing.assert_allclose(poisson, [0.018, 0.073, 0.147, 0.195, 0.567], atol=0.02)
    uniform = np.bincount([requested_object_count(rng, "uniform", 5) for _ in range(4000)], minlength=6)[1:] / 4000
    np.testing.assert_allclose(uniform, 0.2, atol=0.02)
    with pytest.raises(ValueError, match="object_count 'many'"):
        requested_object_count(rng, "many", 5)


def test_fingertip_check_study_compares_every_label(grasp_data, scenes, capsys):
    result = fingertip_check_study.compare(scenes, grasp_data / "objects")
    labels = sum(len(np.load(p)["label_score"]) for p in (scenes / "scenes").glob("*.npz"))
    assert sum(d["n"] for d in result.values()) == labels > 0
    # the fixture's fingers all stop at the same driver angle: the estimate's error is the
    # estimate (an opening seen in the TSDF) minus one fixed tip depth, within the stroke
    fk_tip_mm = 1000 * FingerKinematics().pad_tips_tcp(FINGER_JOINTS, [[0.0, 0.6, -0.576, 0.6] * 2])[0][:, 2].max()
    for d in result.values():
        assert 0 <= d["refused"] <= d["n"]
        estimate_mm = np.asarray(d["error_mm"]) + fk_tip_mm
        assert estimate_mm.min() >= 4.3 and estimate_mm.max() <= 18.0
    fingertip_check_study.main(["--scenes", str(scenes), "--objects", str(grasp_data / "objects")])
    assert capsys.readouterr().out.strip().splitlines()[-1].startswith("power_refused_fraction=")
