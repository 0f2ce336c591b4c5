"""The benchmark's methods (sim_bridge/benchmark/methods, issue 41): the registry (one clear
error for an unknown name, a missing baseline file skipped with one sentence), a method
added as one entry running a round through the real round logic on its own hand, and the
Panda hand's cell: the real GraspExecutor lifts a cylinder and reads a grasp on nothing
as no_object. The Drake parts need the baselines' panda_hand/ (skipped without it)."""
import dataclasses
import types

import numpy as np
import pytest

from gravgrasp_detector.perception import tsdf
from gravgrasp_detector.perception.hand_clearance import ROBOTIQ_2F85
from sim_bridge.benchmark import clutter_benchmark as cb
from sim_bridge.benchmark import methods, protocol, sim_cell
from sim_bridge.benchmark import rounds as bench_rounds
from sim_bridge.datagen.object_sources import procedural_sources
from sim_bridge.physics import panda_hand
from sim_bridge.physics.baseline_files import baselines_dir
from sim_bridge.physics.hands import HANDS
from sim_bridge.world import R_TOP_DOWN
from baselines import needs_panda  # tests/support

pytestmark = pytest.mark.drake


# -- the registry -------------------------------------------------------------------------

def test_an_unknown_method_is_one_error_naming_the_known_ones(tmp_path, capsys):
    with pytest.raises(ValueError) as err:
        methods.method_named("vgnn")
    message = str(err.value)
    assert "'vgnn'" in message and all(name in message for name in methods.METHODS) and "\n" not in message
    with pytest.raises(ValueError, match="unknown method 'vgnn'"):
        bench_rounds.resolve_methods(["vgnn"], tmp_path)
    assert cb.main(["--methods", "vgnn", "--out", str(tmp_path / "o"), "--workers", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "vgn" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_every_method_names_a_hand_the_cell_and_the_executor_know():
    assert set(methods.DEFAULT_METHODS) <= set(methods.METHODS)
    for m in methods.METHODS.values():
        assert m.hand in HANDS and m.hand in sim_cell.HAND_GEOMETRY and m.hand in sim_cell.GRIPPERS, m
    assert methods.METHODS["vgn"].hand == "panda" and methods.METHODS["ours"].hand == "2f85"
    assert sim_cell.HAND_GEOMETRY["2f85"] is ROBOTIQ_2F85
    panda = sim_cell.HAND_GEOMETRY["panda"]
    assert panda.open_width_m == pytest.approx(0.08) and panda.parts == panda_hand.HAND_PARTS
    assert not panda.closing_tips_modelled  # the 2F-85's linkage model is not the Panda's
    # a ranking variant runs its base's file, and --model for the base moves it along
    assert methods.METHODS["ours_expected"].default_path("m") == methods.METHODS["ours"].default_path("m")
    assert methods.METHODS["ours_expected"].file_of == "ours"


def test_a_missing_vgn_file_is_skipped_with_one_sentence_saying_where_to_get_it(tmp_path, capsys):
    notes = []
    assert bench_rounds.resolve_methods(["vgn"], tmp_path, baselines_dir=tmp_path, note=notes.append) == {}
    (note,) = notes
    assert note.startswith("benchmark: skipping vgn: ") and "vgn/vgn_conv.pth" in note
    assert "github.com/ethz-asl/vgn" in note and "--baselines DIR" in note and "\n" not in note
    # the CLI: the note, then one line saying no method can run, no traceback
    assert cb.main(["--methods", "vgn", "--baselines", str(tmp_path), "--out", str(tmp_path / "o"),
                    "--workers", "0"]) == 2
    out, err = capsys.readouterr()
    assert "skipping vgn" in out and "vgn_conv.pth" in out
    assert len(err.strip().splitlines()) == 1 and "--baselines DIR" in err and "Traceback" not in out + err


def test_vgn_with_its_weights_but_no_panda_hand_is_skipped_naming_the_hand_file(tmp_path):
    weights = baselines_dir() / "vgn" / "vgn_conv.pth"
    if not weights.is_file():
        pytest.skip(f"no {weights}")
    (tmp_path / "vgn").mkdir()
    (tmp_path / "vgn" / "vgn_conv.pth").symlink_to(weights)
    notes = []
    assert bench_rounds.resolve_methods(["vgn"], "models", baselines_dir=tmp_path, note=notes.append) == {}
    assert len(notes) == 1 and "panda hand" in notes[0] and "panda_hand/hand.urdf" in notes[0], notes


@needs_panda
def test_vgn_resolves_from_the_baselines_directory():
    weights = baselines_dir() / "vgn" / "vgn_conv.pth"
    if not weights.is_file():
        pytest.skip(f"no {weights}")
    assert bench_rounds.resolve_methods(["vgn"], "models", note=pytest.fail) == {"vgn": str(weights.resolve())}


# -- the Panda's cell -------------------------------------------------------------------------

def cylinder_scene():
    """A 34 mm upright cylinder (procedural test object 1) at the table's centre."""
    source = procedural_sources(protocol.PROCEDURAL_POOL, protocol.PROCEDURAL_SEED)[1]
    mesh = source.load().collision_mesh()
    X = np.eye(4)
    X[:3, 3] = [0.15, 0.15, 0.051 - mesh.bounds[0][2]]
    scene = {"scene_id": "packed_t", "arrangement": "packed",
             "objects": [{"source": dataclasses.asdict(source), "name": "c", "X_task_object": X.tolist()}]}
    return scene, float(mesh.extents[2])


def top_down(x, y, z):
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = R_TOP_DOWN, [x, y, z]
    return types.SimpleNamespace(pose=pose, score_n=float("nan"), validness=0.95, rank_key=0.95)  # no score in N


@needs_panda
def test_a_method_added_as_one_entry_runs_a_round_on_its_own_hand(tmp_path, monkeypatch):
    """A toy method (one registry entry: a file, the Panda hand, a detector proposing a
    top-down grasp 8 mm above the cylinder's top, as VGN's Panda TCP sits) through
    run_round, the real round logic: the executor opens to 80 mm, the Panda gripper reports
    the object held, the hold and shake pass, the table is clear, and the record names the
    hand."""
    scene, height_m = cylinder_scene()
    made = []

    def make_detector(path, proto):
        made.append((path, proto))
        return methods.Detector(lambda view: [top_down(0.15, 0.15, 0.05 + height_m + 0.008)],
                                tsdf.TSDFVolume(resolution=40), "binary")

    (tmp_path / "toy.txt").write_text("the toy's file")
    monkeypatch.setitem(methods.METHODS, "toy", methods.Method("toy", "panda", make_detector, "toy.txt"))
    path = bench_rounds.resolve_methods(["toy"], tmp_path, note=pytest.fail)["toy"]
    task = bench_rounds.RoundTask("toy", path, "sha", 0.3, scene, protocol.Protocol(time_step_s=0.002))
    cell, detector = bench_rounds.make_cell(task)
    assert made == [(path, task.protocol)] and detector.target == "binary"
    assert cell.hand == "panda" and cell.limits.hand.name == "panda"
    assert isinstance(cell.executor.gripper_factory(), sim_cell.PandaSimGripper)

    record = bench_rounds.run_round(task)
    assert record["hand"] == "panda" and record["method"] == "toy" and record["target"] == "binary"
    (attempt,) = record["attempts"]
    assert attempt["outcome"] == "success", attempt
    assert record["end"] == "table_clear" and record["successes"] == 1


def test_a_method_told_the_payload_gets_each_rounds_mass_and_the_others_do_not(tmp_path, monkeypatch):
    """Method.told_payload (ours_mass): make_cell passes the round's mass as payload_kg;
    a method not told keeps the plain make(path, protocol)."""
    scene, _ = cylinder_scene()
    made = []

    def make_detector(path, proto, **told):
        made.append(told)
        return methods.Detector(lambda view: [], tsdf.TSDFVolume(resolution=40), "gravity-score")

    (tmp_path / "toy.txt").write_text("the toy's file")
    for name, told in (("told", True), ("untold", False)):
        monkeypatch.setitem(methods.METHODS, name, methods.Method(name, "2f85", make_detector, "toy.txt",
                                                                  told_payload=told))
        path = bench_rounds.resolve_methods([name], tmp_path, note=pytest.fail)[name]
        for mass_kg in (0.1, 1.5):
            bench_rounds.make_cell(bench_rounds.RoundTask(name, path, "sha", mass_kg, scene, protocol.Protocol()))
    assert made == [{"payload_kg": 0.1}, {"payload_kg": 1.5}, {}, {}]


@needs_panda
def test_the_panda_cell_reads_a_grasp_on_nothing_as_no_object():
    scene, height_m = cylinder_scene()
    cell = sim_cell.SimCell(scene, 0.3, protocol.Protocol(time_step_s=0.002), tsdf.TSDFVolume(resolution=40),
                            detect=lambda view: [], hand="panda")
    view = cell.observe()
    nothing = top_down(0.05, 0.25, 0.05 + 0.06)  # away from the cylinder, fingertips 1 cm above the table
    assert cell.feasible(nothing, view) == ""
    result = cell.execute(nothing, view)
    assert result["outcome"] == "no_object" and "did not stop on an object" in result["reason"], result
    assert cell.executor.calibration.width_m < 0.002  # closing on nothing ends at 0 mm
    assert len(cell.objects_on_table()) == 1  # untouched
    assert cell.world.finger_width_m() == pytest.approx(panda_hand.MAX_OPENING_M, abs=1e-3)  # opened again
    # the Panda's boxes: a grasp whose hand would sit on the cylinder's top is refused
    on_top = top_down(0.15, 0.15, 0.05 + height_m - 0.01)
    assert "the open hand collides" in cell.feasible(on_top, view) and "hand:" in cell.feasible(on_top, view)


def test_a_hand_that_does_not_exist_is_one_error():
    scene, _ = cylinder_scene()
    with pytest.raises(ValueError, match="hand 'robotiq' does not exist: use one of '2f85'"):
        sim_cell.SimCell(scene, 0.3, protocol.Protocol(), tsdf.TSDFVolume(resolution=40), lambda view: [],
                         hand="robotiq")


def vgn_weights():
    weights = baselines_dir() / "vgn" / "vgn_conv.pth"
    if not weights.is_file():
        pytest.skip(f"no {weights}")
    return str(weights.resolve())


@needs_panda
def test_vgn_in_the_cell_grasps_a_lone_cylinder_with_the_panda():
    """The registry's vgn through make_cell: VGN's volume (40^3, 7.5 mm), the Panda hand,
    and VGN's best grasp that the executor starts lifts the cylinder (a VGN pose is the
    Panda's TCP). With clear_hand, only grasps whose open Panda hand clears the view."""
    scene, _ = cylinder_scene()
    task = bench_rounds.RoundTask("vgn", vgn_weights(), "sha", 0.3, scene, protocol.Protocol(time_step_s=0.002))
    cell, detector = bench_rounds.make_cell(task)
    assert cell.hand == "panda" and detector.target == "binary"
    assert detector.volume.resolution == 40 and detector.volume.voxel_size_m == pytest.approx(0.0075)
    cell.settle()
    view, grasps = cell.detect()
    assert 0 < len(grasps) <= task.protocol.max_grasps
    assert [g.validness for g in grasps] == sorted((g.validness for g in grasps), reverse=True)
    cleared = methods.METHODS["vgn"].make(task.model_path, dataclasses.replace(task.protocol, clear_hand=True))
    kept = cleared.detect(view)
    assert kept and all("the open hand collides" not in cell.feasible(g, view) for g in kept)
    rank, g = next((i, g) for i, g in enumerate(grasps) if cell.feasible(g, view) == "")
    result = cell.execute(g, view)
    assert result["outcome"] == "success", (rank, result)
