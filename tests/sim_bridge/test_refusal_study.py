"""The refusal study: grasps the executor refuses for collision, executed anyway in the
benchmark's Drake cell."""
import dataclasses
import json

import numpy as np
import pytest
import trimesh

from gravgrasp_detector.perception.detection import Grasp
from gravgrasp_detector.perception.tsdf import TSDFVolume
from sim_bridge.studies import refusal_study as study
from sim_bridge.benchmark.protocol import Protocol
from sim_bridge.benchmark import run_files
from sim_bridge.benchmark.rounds import RoundTask
from sim_bridge.benchmark.sim_cell import SimCell
from sim_bridge.datagen.object_sources import ObjectSource
from sim_bridge.datagen.voxel_labels import RESOLUTION
from sim_bridge.physics.scenes import TABLE_HEIGHT_M, VOLUME_SIZE_M

from test_datagen_objects import write_urdf

CUBE_M = 0.045


def top_down(centre, shift_x_m=0.0):
    """A top-down grasp (approach -z, fingers closing along x) at the cube's centre,
    shifted along the closing axis."""
    X = np.eye(4)
    X[:3, :3] = np.column_stack([[0.0, 1, 0], [1.0, 0, 0], [0.0, 0, -1]])  # e_x, e_y = e_z x e_x, e_z
    X[:3, 3] = centre + [shift_x_m, 0, 0]
    return X


@pytest.fixture
def cube_cell(tmp_path, monkeypatch):
    """make_cell replaced: one 45 mm cube, and a detector that ranks first a grasp whose
    open left finger comes down through the cube's top, then the centred grasp."""
    write_urdf(tmp_path, "cube", trimesh.creation.box((CUBE_M,) * 3), 0.1)
    centre = np.array([0.15, 0.15, TABLE_HEIGHT_M + CUBE_M / 2])
    X_obj = np.eye(4)
    X_obj[:3, 3] = centre
    source = ObjectSource(kind="mesh", name="cube", path=str(tmp_path / "cube.urdf"))
    scene = {"scene_id": "cube_000", "arrangement": "packed",
             "objects": [{"source": dataclasses.asdict(source), "X_task_object": X_obj.tolist()}]}
    grasps = [Grasp(top_down(centre, 0.0425), 60.0, 0.9, (0, 0, 0)), Grasp(top_down(centre), 40.0, 0.9, (0, 0, 0))]

    def make_cell(task):
        volume = TSDFVolume(size_m=VOLUME_SIZE_M, resolution=RESOLUTION)
        return SimCell(task.scene, task.mass_kg, task.protocol, volume, detect=lambda tsdf: grasps), {}

    monkeypatch.setattr(study, "make_cell", make_cell)
    return RoundTask("ours", "", "", 0.5, scene, Protocol())


@pytest.mark.drake
def test_a_grasp_refused_for_collision_is_executed_without_the_check_and_compared(cube_cell):
    record = study.run_scene(study.SceneTask(cube_cell, top=2, baseline=None))
    refused, centred = record["candidates"]
    assert refused["verdict"] == "collision" and refused["refusal"].startswith(study.COLLISION)
    assert refused["voxels"] > 0 and "left distal link" in refused["parts"], refused
    assert refused["same_view"]  # the fresh copy of the scene settled to the same view
    # executed, not refused again: the finger lands on the cube's top
    assert refused["outcome"] not in ("refused", "success"), refused
    assert centred["verdict"] == "accepted" and centred["voxels"] == 0 and "outcome" not in centred
    assert record["first_accepted_rank"] == 1
    assert record["baseline"]["from"] == "executed here" and record["baseline"]["outcome"] == "success", record


def refused(voxels, outcome):
    return {"verdict": "collision", "voxels": voxels, "outcome": outcome}


def scene_record(kg, candidates, baseline="success"):
    return {"mass_kg": kg, "candidates": candidates,
            "baseline": None if baseline is None else {"outcome": baseline}}


def test_summary_bins_refusals_by_voxel_count_beside_the_benchmarks_pick():
    s = study.summarize([scene_record(1.5, [refused(1, "jammed_on_approach"), refused(3, "success"),
                                            {"verdict": "accepted", "voxels": 0}]),
                         scene_record(1.5, [refused(12, "jammed_on_approach")], baseline="dropped_in_hold"),
                         scene_record(1.5, [], baseline=None), scene_record(0.1, [refused(5, "success")])])
    w = s["1.5"]
    assert w["scenes"] == 3 and w["scenes_with_refusal"] == 2
    assert w["refused"] == {"1-3": {"jammed_on_approach": 1, "success": 1}, ">=11": {"jammed_on_approach": 1}}
    assert w["baseline"] == {"success": 1, "dropped_in_hold": 1}
    assert s["0.1"]["refused"] == {"4-10": {"success": 1}}
    lines = study.summary_lines(s)
    assert lines[0] == ("| weight [kg] | grasps | occupied voxels in the hand | n | success | dropped_in_hold "
                        "| jammed_on_approach |")
    assert "| 1.5 | refused for collision (2 of 3 scenes) | 1-3 | 2 | 1 | 0 | 1 |" in lines
    assert "| 1.5 | first accepted (the benchmark's pick) | 0 | 2 | 1 | 1 | 0 |" in lines


@pytest.fixture
def bench(tmp_path):
    d = tmp_path / "bench"
    d.mkdir(parents=True)
    (d / "config.json").write_text(json.dumps({"protocol": dataclasses.asdict(Protocol())}))
    run_files.scenes_file(d).put({"scene_id": "packed_000", "objects": []})
    model = tmp_path / "model.pt"
    model.write_bytes(b"not read: the scene's record is already there")
    return d, model


def test_main_resumes_from_its_records_and_prints_the_refused_success_fraction(bench, tmp_path, capsys):
    d, model = bench
    out = tmp_path / "out"
    sha = study.file_sha256(model)
    study.records_file(out).put(
        {"model_sha256": sha, "top": 5, "scene_id": "packed_000",
         **scene_record(1.5, [refused(2, "success"), refused(2, "jammed_on_approach"), refused(30, "jammed_on_approach")])})
    assert study.main(["--bench", str(d), "--model", str(model), "--out", str(out)]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1] == "refused_success_fraction=0.333"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["summary"]["1.5"]["refused"]["1-3"] == {"success": 1, "jammed_on_approach": 1}


@pytest.mark.parametrize("args, message", [(["--weights", "0,1"], "--weights"), (["--top", "0"], "--top"),
                                           (["--method", "nope"], "unknown --method"),
                                           (["--model", "/nonexistent.pt"], "not found")])
def test_bad_arguments_get_one_clear_message(bench, tmp_path, capsys, args, message):
    d, model = bench
    argv = ["--bench", str(d), "--model", str(model), "--out", str(tmp_path / "out"), *args]
    assert study.main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_a_directory_without_a_benchmark_run_is_named(tmp_path, capsys):
    assert study.main(["--bench", str(tmp_path), "--out", str(tmp_path / "out")]) == 2
    assert "holds no benchmark run" in capsys.readouterr().err
