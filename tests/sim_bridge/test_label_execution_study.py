"""The label execution study: labels executed in the benchmark's Drake cell."""
import json

import numpy as np
import pytest
import trimesh

from sim_bridge.studies import label_execution_study as study
from sim_bridge.datagen.object_grasps import MODE_NAMES
from sim_bridge.datagen.voxel_labels import voxel_index
from sim_bridge.physics.scenes import TABLE_HEIGHT_M

from test_datagen_objects import write_urdf

CUBE_M = 0.045
POWER, PRECISION = MODE_NAMES.index("power"), MODE_NAMES.index("precision")


@pytest.fixture(scope="module")
def cube_scene(tmp_path_factory):
    """One 45 mm cube on the table, two labels: a top-down grasp across its middle, and
    a sideways one (approach horizontal), outside the executor's cone."""
    root = tmp_path_factory.mktemp("label_execution")
    meshes, objects, scenes = root / "meshes", root / "objects" / "objects", root / "scenes" / "scenes"
    for d in (meshes, objects, scenes):
        d.mkdir(parents=True)
    write_urdf(meshes, "cube", trimesh.creation.box((CUBE_M,) * 3), 0.1)
    np.savez(objects / "cube.npz", name=np.asarray("cube"), source_kind=np.asarray("mesh"),
             source=np.asarray("cube.urdf"))
    centre = np.array([0.15, 0.15, TABLE_HEIGHT_M + CUBE_M / 2])
    X_obj = np.eye(4)
    X_obj[:3, 3] = centre
    # e_x, e_z of the TCP (y closes, z approaches): straight down, and sideways
    e_x = np.array([[0.0, 1, 0], [0, 0, 1]], np.float32)
    e_z = np.array([[0.0, 0, -1], [1, 0, 0]], np.float32)
    np.savez(scenes / "000000.npz", object_names=np.asarray(["cube"]), X_task_object=X_obj[None].astype(np.float32),
             arrangement=np.asarray("packed"), label_object=np.zeros(2, np.uint8),
             label_mode=np.asarray([PRECISION, POWER], np.uint8), label_score=np.asarray([30.0, 3.0], np.float32),
             label_e_x=e_x, label_e_z=e_z, label_index=voxel_index([centre, centre]).astype(np.uint8))
    return root


@pytest.mark.drake
def test_a_centred_top_down_label_holds_and_a_sideways_one_is_refused(cube_scene):
    base = dict(objects_dir=str(cube_scene / "objects" / "objects"), mesh_dirs=(str(cube_scene / "meshes"),))
    scene = str(cube_scene / "scenes" / "scenes" / "000000.npz")
    held = study.run_label(study.LabelTask(scene, 0, 0.5, **base))
    assert held["outcome"] == "success", held
    assert held["label_mode"] == "precision" and held["holds_weight_by_label"]  # 30 N >= 0.5 kg g
    assert held["moved_mm"] < study.MOVED_MM
    sideways = study.run_label(study.LabelTask(scene, 1, 0.5, **base))
    assert sideways["outcome"] == "refused" and "cone" in sideways["reason"], sideways
    assert not sideways["holds_weight_by_label"]  # 3 N < 0.5 kg g


def record(mode, outcome, holds=True, kg=1.5):
    return {"label_mode": mode, "outcome": outcome, "holds_weight_by_label": holds, "mass_kg": kg}


def test_summary_counts_outcomes_per_mode_and_weight_and_keeps_moved_apart():
    s = study.summarize([record("power", "success"), record("power", "jammed_on_approach"),
                         record("power", "dropped_in_hold", holds=False), record("power", "moved"),
                         record("power", "refused"), record("precision", "success", kg=0.1)])
    power = s["power"]["1.5"]
    assert power["n"] == 4 and power["moved"] == 1
    assert power["outcomes"] == {"success": 1, "jammed_on_approach": 1, "dropped_in_hold": 1, "refused": 1}
    assert power["success_if_label_holds"] == [1, 2]  # the refused one was not executed
    assert power["success_if_label_drops"] == [0, 1]
    assert s["precision"]["0.1"]["outcomes"] == {"success": 1}
    lines = study.summary_lines(s)
    assert lines[0].startswith("| label mode | weight [kg] | labels | success |")
    assert "| power | 1.5 | 4 | 1 |" in lines[2] and lines[2].endswith("| 1 / 2 | 0 / 1 | 1 |")


def test_main_resumes_from_the_attempt_files_and_prints_the_approach_failures(cube_scene, tmp_path, capsys):
    attempts = tmp_path / "attempts"
    attempts.mkdir()
    # both labels already executed: main only reads them back (no simulation)
    for label, mode, outcome in ((0, "precision", "success"), (1, "power", "jammed_on_approach")):
        (attempts / f"000000_{label:05d}_0.5.json").write_text(json.dumps(
            {**record(mode, outcome, kg=0.5), "scene": "000000", "label": label}))
    argv = ["--scenes", str(cube_scene / "scenes"), "--objects", str(cube_scene / "objects"),
            "--meshes", str(cube_scene / "meshes"), "--out", str(tmp_path), "--per-mode", "1", "--weights", "0.5"]
    assert study.main(argv) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1] == "approach_failure_fraction=0.500"
    summary = json.loads((tmp_path / "summary.json").read_text())["summary"]
    assert summary["power"]["0.5"]["outcomes"] == {"jammed_on_approach": 1}


@pytest.mark.parametrize("args, message", [(["--weights", "0.5,-1"], "--weights"),
                                           (["--scenes", "/nonexistent"], "no scenes in")])
def test_bad_arguments_get_one_clear_message(cube_scene, tmp_path, capsys, args, message):
    argv = ["--scenes", str(cube_scene / "scenes"), "--objects", str(cube_scene / "objects"),
            "--out", str(tmp_path), *args]
    assert study.main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
