"""Scene recipes: scenes from the real scene stage (Drake settling, ray-cast depth),
packed into recipes, deleted, and rebuilt from the recipes without the physics; the
rebuilt files must be the scene stage's, and `datagen scenes` must resume on them."""

import shutil

import numpy as np
import pytest

from sim_bridge.datagen import data_report, scene_recipes
from sim_bridge.datagen.cli import main as datagen
from sim_bridge.datagen.scene_dataset import run_scene_stage

# the stage run's fixtures, made once per pytest run (run_shared)
from test_datagen_scene_stage import grasp_data, run, scenes, stage_run  # noqa: F401

pytestmark = pytest.mark.drake


@pytest.fixture(scope="module")
def made(grasp_data, scenes, tmp_path_factory):  # noqa: F811
    """4 scenes of the stage: test_datagen_scene_stage's 3 (a scene is reproducible from its
    seed, which that file tests) and one more made by resuming on a copy of them."""
    out = tmp_path_factory.mktemp("recipes_scenes")
    shutil.copytree(scenes, out, dirs_exist_ok=True)
    s = run(grasp_data, out, 4)
    assert s["done"] == 4 and s["error"] == 0, s["errors"]
    return out


def test_restored_scenes_are_the_scene_stage_files_and_the_stage_resumes_on_them(grasp_data, made, tmp_path, capsys):  # noqa: F811
    recipes = tmp_path / "recipes"
    assert datagen(["recipes", "pack", str(made), str(recipes)]) == 0
    assert "recipes: scenes=4 blocks_written=1" in capsys.readouterr().out
    size = sum(f.stat().st_size for f in recipes.glob("recipes_*.npz"))
    scene_size = sum(f.stat().st_size for f in (made / "scenes").glob("*.npz"))
    assert size < scene_size / 20, (size, scene_size)

    out = tmp_path / "rebuilt"
    assert datagen(["recipes", "restore", str(recipes), str(out), "--objects", str(grasp_data / "objects"),
                    "--meshes", str(grasp_data / "meshes"), "--workers", "2", "--no-progress"]) == 0
    assert "restore: scenes=4 restored=4 differing=0 error=0" in capsys.readouterr().out
    n_labels = 0
    for i in range(4):
        with np.load(made / "scenes" / f"{i:06d}.npz") as a, np.load(out / "scenes" / f"{i:06d}.npz") as b:
            assert sorted(a.files) == sorted(b.files)
            for k in a.files:
                if a[k].dtype.kind == "f":
                    np.testing.assert_allclose(b[k], a[k], atol=1e-6, err_msg=k)
                else:
                    assert np.array_equal(a[k], b[k]), k
            n_labels += len(a["label_score"])
    assert n_labels > 0

    # `datagen scenes` takes the rebuilt directory as its own: nothing is redone ...
    before = {f.name: f.stat().st_mtime_ns for f in (out / "scenes").glob("*.npz")}
    s = run(grasp_data, out, 4)
    assert s["done"] == 4 and {f.name: f.stat().st_mtime_ns for f in (out / "scenes").glob("*.npz")} == before
    # ... and restoring again writes nothing either
    assert datagen(["recipes", "restore", str(recipes), str(out), "--objects", str(grasp_data / "objects"),
                    "--meshes", str(grasp_data / "meshes"), "--no-progress"]) == 0
    assert "restored=0" in capsys.readouterr().out


def test_pack_grows_block_by_block_and_never_drops_a_recipe(made, tmp_path, monkeypatch):
    monkeypatch.setattr(scene_recipes, "BLOCK", 2)
    scenes = tmp_path / "scenes"
    shutil.copytree(made, scenes)
    (scenes / "scenes" / "000003.npz").unlink()
    recipes = tmp_path / "recipes"
    assert scene_recipes.pack(scenes, recipes) == {"scenes": 3, "written": 2}
    assert sorted(f.name for f in recipes.glob("recipes_*.npz")) == ["recipes_000000.npz", "recipes_000002.npz"]
    assert scene_recipes.pack(scenes, recipes) == {"scenes": 3, "written": 0}  # nothing new: no block rewritten

    # a lost scene file (out/ on a new machine) does not lose its recipe; a new one is added
    block0 = (recipes / "recipes_000000.npz").read_bytes()
    (scenes / "scenes" / "000000.npz").unlink()
    shutil.copy(made / "scenes" / "000003.npz", scenes / "scenes")
    assert scene_recipes.pack(scenes, recipes) == {"scenes": 4, "written": 1}
    assert (recipes / "recipes_000000.npz").read_bytes() == block0
    assert sorted(scene_recipes.read_block(recipes / "recipes_000002.npz")) == [2, 3]


def test_restore_refuses_other_grasp_tables_and_missing_recipes(grasp_data, made, tmp_path, capsys):  # noqa: F811
    recipes = tmp_path / "recipes"
    scene_recipes.pack(made, recipes)
    fewer = tmp_path / "fewer"
    shutil.copytree(grasp_data / "objects", fewer)
    (fewer / "objects" / "cube.npz").unlink()
    assert datagen(["recipes", "restore", str(recipes), str(tmp_path / "o"), "--objects", str(fewer)]) == 2
    err = capsys.readouterr().err.strip()
    assert "are not the 3 the scenes were made from" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "o").exists()

    assert datagen(["recipes", "restore", str(tmp_path / "nothing"), str(tmp_path / "o")]) == 2
    assert "holds no recipes" in capsys.readouterr().err
    assert datagen(["recipes", "pack", str(tmp_path / "nothing"), str(recipes)]) == 2
    assert "has no manifest.json" in capsys.readouterr().err


def _edit_tables(src, dst, edit):
    shutil.copytree(src, dst)
    for f in sorted((dst / "objects").glob("*.npz")):
        t = dict(np.load(f))
        edit(t)
        np.savez(f, **t)


def test_relabel_gives_the_same_scenes_the_labels_of_other_tables(grasp_data, made, tmp_path, capsys):  # noqa: F811
    recipes = tmp_path / "recipes"
    scene_recipes.pack(made, recipes)

    def fewer_held(t):  # tables changed after the scenes were made: every other held grasp dropped
        t["grasped"] = t["grasped"] & (np.arange(len(t["grasped"])) % 2 == 0)
    other = tmp_path / "other"
    _edit_tables(grasp_data / "objects", other, fewer_held)
    args = ["recipes", "restore", str(recipes), str(tmp_path / "relabelled"), "--objects", str(other),
            "--meshes", str(grasp_data / "meshes"), "--no-progress"]
    assert datagen(args) == 2  # same object pool, other tables: not a silent relabel
    err = capsys.readouterr().err.strip()
    assert "3 grasp tables in" in err and "--relabel" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "relabelled").exists()

    assert datagen(args + ["--relabel"]) == 0
    out = capsys.readouterr().out
    assert "relabelled 4 scenes: labels per scene median" in out and "restored=4" in out
    total = {"before": 0, "after": 0}
    for i in range(4):
        with np.load(made / "scenes" / f"{i:06d}.npz") as a, np.load(tmp_path / "relabelled" / "scenes" / f"{i:06d}.npz") as b:
            np.testing.assert_allclose(b["tsdf"], a["tsdf"], atol=1e-6)  # the same settled scene ...
            assert np.array_equal(b["X_task_object"], a["X_task_object"])
            total["before"] += len(a["label_score"])
            total["after"] += len(b["label_score"])
            assert set(b["label_grasp"] % 2) <= {0}  # ... labelled from the held grasps that are left
    assert 0 < total["after"] < total["before"], total

    # the relabelled directory is the scene stage's own, on the other tables: nothing redone
    relabelled = tmp_path / "relabelled"
    before = {f.name: f.stat().st_mtime_ns for f in (relabelled / "scenes").glob("*.npz")}
    s = run_scene_stage(relabelled, other, [grasp_data / "meshes"], 4, seed=5, workers=1, max_objects=3,
                        max_views=3, progress=False)
    assert s["done"] == 4 and {f.name: f.stat().st_mtime_ns for f in (relabelled / "scenes").glob("*.npz")} == before
    # its recipes restore it exactly with those tables, and old recipes refuse to take it
    assert datagen(["recipes", "pack", str(relabelled), str(recipes)]) == 2
    assert "different tables" in capsys.readouterr().err
    assert datagen(["recipes", "pack", str(relabelled), str(tmp_path / "recipes2")]) == 0
    assert datagen(["recipes", "restore", str(tmp_path / "recipes2"), str(tmp_path / "again"), "--objects",
                    str(other), "--meshes", str(grasp_data / "meshes"), "--no-progress"]) == 0
    assert "restored=4 differing=0 error=0" in capsys.readouterr().out

    def reshaped(t):  # another mesh under the same name: the settled poses no longer apply
        t["shape_sha256"] = np.asarray("f" * 64)
    _edit_tables(grasp_data / "objects", tmp_path / "reshaped", reshaped)
    assert datagen(["recipes", "restore", str(recipes), str(tmp_path / "r2"), "--objects",
                    str(tmp_path / "reshaped"), "--relabel"]) == 2
    assert "another shape" in capsys.readouterr().err


def test_perturbed_rows_need_relabel_and_then_label_beside_the_table(grasp_data, made, tmp_path, capsys):  # noqa: F811
    """Perturbed rows beside the tables change what labels a scene: restore refuses without
    --relabel, and relabelling labels with them (held ones as positives past the table's
    rows, failed ones as extra negatives)."""
    from sim_bridge.datagen.perturbed_grasps import perturbed_path

    recipes = tmp_path / "recipes"
    scene_recipes.pack(made, recipes)
    objects = tmp_path / "with_perturbed"
    shutil.copytree(grasp_data / "objects", objects)
    (objects / "objects" / "perturbed").mkdir()
    n_rows = {}
    for f in sorted((objects / "objects").glob("*.npz")):
        t = dict(np.load(f))
        held = np.flatnonzero(t["grasped"])
        n_rows[f.stem] = len(t["grasped"])
        moved = {k: np.concatenate([t[k][held]] * 2) for k in
                 ("X_object_tcp_candidate", "X_object_tcp", "scores_n", "mode", "finger_joint_angles")}
        # the first copy: held where it was, 5 N stronger (stands for a row that held after
        # the move; it wins its voxel); the second: 15 mm shallower, failed
        moved["scores_n"][:len(held)] += 5.0
        shallower = moved["X_object_tcp_candidate"][len(held):]
        shallower[:, :3, 3] -= 0.015 * shallower[:, :3, 2]
        grasped = np.arange(2 * len(held)) < len(held)
        shift = np.zeros((2 * len(held), 3))
        shift[len(held):, 2] = -0.015
        np.savez(perturbed_path(objects / "objects", f.stem), **moved, grasped=grasped, shift_tcp_m=shift,
                 finger_joint_names=t["finger_joint_names"], parent=np.concatenate([held, held]))
    args = ["recipes", "restore", str(recipes), str(tmp_path / "out"), "--objects", str(objects),
            "--meshes", str(grasp_data / "meshes"), "--no-progress"]
    assert datagen(args) == 2
    assert "differ from those that labelled these scenes" in capsys.readouterr().err
    assert datagen(args + ["--relabel"]) == 0
    capsys.readouterr()
    past, negatives = 0, {"before": 0, "after": 0}
    for i in range(4):
        with np.load(made / "scenes" / f"{i:06d}.npz") as a, np.load(tmp_path / "out" / "scenes" / f"{i:06d}.npz") as b:
            names = [str(n) for n in b["object_names"]]
            past += sum(int(g) >= n_rows[names[k]] for k, g in zip(b["label_object"], b["label_grasp"]))
            negatives["before"] += len(a["negative_index"])
            negatives["after"] += len(b["negative_index"])
    assert past > 0, "no label came from a perturbed row"
    assert negatives["after"] > negatives["before"], negatives
    report = data_report.collect(objects, tmp_path / "out")  # counts them as this test did
    assert report["labels_from_perturbed"] == past and report["negatives_per_scene"].sum() == negatives["after"]
    text = data_report.report_text(report)
    n_held = report["perturbed"]["unmoved"][0]
    assert f"perturbed rows (datagen perturb) of 3 objects: shallower 0/{n_held} held (0%); unmoved {n_held}/{n_held}" \
        in text and "labels from perturbed rows:" in text


def test_table_size_study_relabels_with_cut_tables(grasp_data, made, tmp_path, capsys):  # noqa: F811
    from sim_bridge.studies import table_size_study
    recipes = tmp_path / "recipes"
    scene_recipes.pack(made, recipes)
    out = tmp_path / "study.json"
    argv = ["--recipes", str(recipes), "--tables", str(grasp_data / "objects"), "--meshes",
            str(grasp_data / "meshes"), "--sizes", "20,80,1000", "--every", "1", "--workers", "1",
            "--out", str(out), "--no-progress"]
    assert table_size_study.main(argv) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    counts = {int(i): c for i, c in __import__("json").loads(out.read_text())["counts"].items()}
    recorded = {i: int(r["label_count"]) for i, r in scene_recipes.read_block(next(recipes.glob("*.npz"))).items()}
    assert sorted(counts) == [0, 1, 2, 3]
    for i, c in counts.items():
        assert c["20"] <= c["80"] <= c["1000"] == recorded[i]  # uncut: the scene's own labels
    assert sum(c["20"] for c in counts.values()) < sum(recorded.values())
    assert last == f"labels_per_scene_median_at_1000={np.median(list(recorded.values())):g}"
    assert table_size_study.main(argv) == 0  # resumes: nothing left to do, same answer
    assert capsys.readouterr().out.strip().splitlines()[-1] == last


def test_restore_writes_only_a_models_validation_scenes_when_asked(grasp_data, made, tmp_path, capsys):  # noqa: F811
    """--validation-of MODEL: the scenes that model's training held out (its seed and
    fraction, split by file name), what score_calibration reads, and no others; an
    unreadable model file is one sentence."""
    from gravgrasp_detector.perception import model_file, networks
    from gravgrasp_detector.perception.tsdf import TSDFVolume
    from gravgrasp_detector.training.scenes import split_scenes

    recipes = tmp_path / "recipes"
    assert datagen(["recipes", "pack", str(made), str(recipes)]) == 0
    names = [f"{i:06d}.npz" for i in range(4)]
    seed = next(s for s in range(100) if 0 < len(split_scenes(names, 0.5, s)[1]) < 4)
    model = tmp_path / "m.pt"
    model_file.save_model(model, networks.GraspNet(), TSDFVolume(),
                          training_data={"config": {"validation_fraction": 0.5, "seed": seed}})
    out = tmp_path / "val"
    base = ["recipes", "restore", str(recipes), str(out), "--objects", str(grasp_data / "objects"),
            "--meshes", str(grasp_data / "meshes"), "--workers", "1", "--no-progress"]
    capsys.readouterr()
    assert datagen(base + ["--validation-of", str(model)]) == 0
    assert sorted(f.name for f in (out / "scenes").glob("*.npz")) == split_scenes(names, 0.5, seed)[1]
    (tmp_path / "junk.pt").write_text("not a model")
    assert datagen(base + ["--validation-of", str(tmp_path / "junk.pt")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("datagen recipes: --validation-of:"), err
