"""Scene recipes: scenes from the real scene stage (Drake settling, ray-cast depth),
packed into recipes, deleted, and rebuilt from the recipes without the physics; the
rebuilt files must be the scene stage's, and `datagen scenes` must resume on them."""

import shutil

import numpy as np
import pytest

from sim_bridge.datagen import scene_recipes
from sim_bridge.datagen.cli import main as datagen

from test_datagen_scene_stage import grasp_data, run  # noqa: F401  (a module fixture, shared)

pytestmark = pytest.mark.drake


@pytest.fixture(scope="module")
def made(grasp_data, tmp_path_factory):  # noqa: F811
    out = tmp_path_factory.mktemp("recipes_scenes")
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
