"""Per-object stage end to end with the real Drake grasp simulation (tiny jobs):
bad objects get one reason, outputs are equal on a local process pool, a local Dask
cluster, and after a SIGKILL + resume; a finished table grows by whole blocks."""

import os
import pathlib
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import trimesh

from sim_bridge.datagen.antipodal_sampling import SamplingSettings
from sim_bridge.datagen.cli import run_object_stage
from sim_bridge.datagen.object_grasps import load_table
from sim_bridge.datagen.object_sources import mesh_sources

pytestmark = pytest.mark.drake

GRASPS = 4
BLOCK = 2
SEED = 7
SAMPLING = SamplingSettings(sampler="resting")  # the CLI's default


def write_urdf(d, name, mesh, mass):
    mesh.export(d / f"{name}.obj")
    (d / f"{name}.urdf").write_text(f"""<?xml version="1.0"?>
<robot name="{name}"><link name="base_link">
  <inertial><mass value="{mass}"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial>
  <visual><geometry><mesh filename="{name}.obj"/></geometry></visual>
  <collision><geometry><mesh filename="{name}.obj"/></geometry></collision>
</link></robot>
""")


@pytest.fixture(scope="module")
def good_meshes(tmp_path_factory):
    d = tmp_path_factory.mktemp("meshes")
    write_urdf(d, "cylinder50", trimesh.creation.cylinder(radius=0.025, height=0.10, sections=32), 0.2)
    write_urdf(d, "box40", trimesh.creation.box((0.04, 0.06, 0.08)), 0.15)
    return d


@pytest.fixture(scope="module")
def reference(good_meshes, tmp_path_factory):
    """The tiny job on a local process pool (2 workers)."""
    out = tmp_path_factory.mktemp("ref")
    s = run_object_stage(out, mesh_sources(good_meshes), GRASPS, SEED, workers=2, block_size=BLOCK, progress=False,
                         sampling=SAMPLING)
    assert s["ok"] == 2 and s["error"] == 0
    return out


def tables(out):
    return {p.stem: load_table(p) for p in sorted((pathlib.Path(out) / "objects").glob("*.npz"))}


def assert_same_tables(a_dir, b_dir):
    a, b = tables(a_dir), tables(b_dir)
    assert sorted(a) == sorted(b) and a
    for name in a:
        assert sorted(a[name]) == sorted(b[name])
        for key in a[name]:
            if key == "wall_time_s":  # the only field that measures the machine
                continue
            np.testing.assert_array_equal(a[name][key], b[name][key], err_msg=f"{name}:{key}")


def test_tables_hold_simulated_grasps(reference):
    for name, t in tables(reference).items():
        assert t["X_object_tcp"].shape == (GRASPS, 4, 4) and t["scores_n"].shape == (GRASPS, 6)
        assert int(t["n_blocks"]) == GRASPS // BLOCK and int(t["block_size"]) == BLOCK
        assert str(t["source_kind"]) == "mesh" and str(t["source"]) == f"{name}.urdf"
        modes = [str(t["mode_names"][m]) for m in t["mode"]]
        # a held grasp has a mode and positive scores; a failed one says why
        for m, g, sc, why in zip(modes, t["grasped"], t["scores_n"], t["reason"]):
            assert (m != "none") == bool(g)
            assert (sc > 0).all() if g else (why != "")
        assert (t["wall_time_s"] > 0).all()
        # sampled per resting pose: each candidate names a pose of the table's list
        assert len(t["rest_probability"]) >= 1 and abs(t["rest_probability"].sum() - 1) < 1e-9
        assert ((t["rest_pose"] >= 0) & (t["rest_pose"] < len(t["rest_probability"]))).all()
    assert not list((pathlib.Path(reference) / "objects").rglob("*.tmp"))
    assert not (pathlib.Path(reference) / "objects" / ".parts").exists()


def test_bad_objects_are_skipped_with_one_reason(tmp_path):
    d = tmp_path / "bad"
    d.mkdir()
    write_urdf(d, "nomass", trimesh.creation.box((0.04, 0.04, 0.04)), 0.0)
    write_urdf(d, "huge", trimesh.creation.box((0.15, 0.15, 0.15)), 1.0)
    (d / "broken.urdf").write_text("<robot><link name='a'>")  # truncated XML
    write_urdf(d, "flat", trimesh.Trimesh([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]], [[0, 1, 2]]), 0.1)
    s = run_object_stage(tmp_path / "out", mesh_sources(d), 2, 0, workers=1, progress=False)
    reasons = {e["name"]: e.get("reason", "") for e in s["entries"]}
    assert {e["status"] for e in s["entries"]} == {"skipped"}, s["entries"]
    assert "mass" in reasons["nomass"]
    assert "stroke" in reasons["huge"]
    assert "XML" in reasons["broken"]
    assert reasons["flat"].startswith("flat") and "volume" in reasons["flat"]
    # the report is on disk and a rerun does not retry them
    assert (tmp_path / "out" / "objects" / "report.json").exists()
    again = run_object_stage(tmp_path / "out", mesh_sources(d), 2, 0, workers=1, progress=False)
    assert again["skipped"] == 4


def test_dask_local_cluster_gives_the_same_tables(good_meshes, reference, tmp_path):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        # through the scheduler address, as `datagen --scheduler tcp://...` does
        s = run_object_stage(tmp_path, mesh_sources(good_meshes), GRASPS, SEED, block_size=BLOCK,
                             scheduler=cluster.scheduler_address, progress=False, sampling=SAMPLING)
    assert s["ok"] == 2
    assert_same_tables(reference, tmp_path)


def test_killed_run_resumes_to_the_same_tables(good_meshes, reference, tmp_path):
    cmd = [sys.executable, "-m", "sim_bridge.datagen", "objects", "--meshes", str(good_meshes),
           "--grasps-per-object", str(GRASPS), "--seed", str(SEED), "--out", str(tmp_path),
           "--workers", "1", "--block-size", str(BLOCK), "--no-progress"]
    proc = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    objects = tmp_path / "objects"
    deadline = time.monotonic() + 240
    try:
        # kill as soon as some work is on disk but the job is not finished
        while time.monotonic() < deadline and proc.poll() is None:
            if list(objects.glob(".parts/*/*.npz")) or list(objects.glob("*.npz")):
                break
            time.sleep(0.2)
        assert proc.poll() is None, proc.stderr.read().decode()
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    assert len(list(objects.glob("*.npz"))) < 2  # it really was interrupted
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert "ok=2" in done.stdout
    assert not list(objects.rglob("*.tmp"))
    assert_same_tables(reference, tmp_path)


def test_a_table_only_rebuilds_the_object_it_was_made_for(reference, good_meshes, tmp_path):
    from sim_bridge.datagen.object_sources import object_from_table
    from sim_bridge.physics.objects import ObjectError

    t = load_table(pathlib.Path(reference) / "objects" / "cylinder50.npz")
    assert object_from_table(t, [good_meshes]).name == "cylinder50"
    write_urdf(tmp_path, "cylinder50", trimesh.creation.cylinder(radius=0.027, height=0.10, sections=32), 0.2)
    with pytest.raises(ObjectError, match="regenerate"):
        object_from_table(t, [tmp_path])


def test_a_finished_table_grows_by_whole_blocks(good_meshes, reference, tmp_path):
    import shutil

    shutil.copytree(pathlib.Path(reference) / "objects", tmp_path / "objects")
    s = run_object_stage(tmp_path, mesh_sources(good_meshes), GRASPS + BLOCK, SEED, workers=2, block_size=BLOCK,
                         progress=False, sampling=SAMPLING)
    assert s["ok"] == 2
    old, new = tables(reference), tables(tmp_path)
    for name in old:
        assert int(new[name]["n_blocks"]) == GRASPS // BLOCK + 1
        assert len(new[name]["mode"]) == GRASPS + BLOCK
        for key in ("X_object_tcp_candidate", "X_object_tcp", "scores_n", "mode", "grasped", "reason", "rest_pose"):
            np.testing.assert_array_equal(new[name][key][:GRASPS], old[name][key], err_msg=f"{name}:{key}")
        # the new block is new work, not a copy of an old one
        assert not np.isin(new[name]["X_object_tcp_candidate"][GRASPS:, 0, 3],
                           old[name]["X_object_tcp_candidate"][:, 0, 3]).any()
    # a different block size would change what the blocks are: refused
    with pytest.raises(ValueError, match="block-size"):
        run_object_stage(tmp_path, mesh_sources(good_meshes), 8, SEED, workers=1, block_size=4, progress=False)


def test_perturbation_study_reproduces_held_grasps_and_loses_them_far_off(tmp_path, capsys):
    """Held candidates of a committed table (a 43 mm procedural cube, rebuilt from its
    index) still hold unmoved, in the table's own settings; moved 60 mm across the pads
    (the cube lies outside their 22 mm width) or 60 mm shallower (past the finger tips)
    none does. Bad input is one error."""
    import json

    from sim_bridge.studies import perturbation_study as ps

    out = tmp_path / "study.json"
    tables = pathlib.Path(__file__).resolve().parents[2] / "models" / "grasp_tables_v3"
    argv = ["--tables", str(tables), "--only", "proc0_00012", "--per-object", "2",
            "--shifts-mm", "0,60", "--workers", "1", "--out", str(out), "--no-progress"]
    assert ps.main(argv) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[-1] == "held_fraction_across_60mm=0.000"
    total = json.loads(out.read_text())["total"]
    assert total["unmoved 0"] == [2, 2]
    assert total["across+ 60"] == [0, 2] and total["across- 60"] == [0, 2] and total["shallower 60"] == [0, 2]
    with pytest.raises(SystemExit):
        ps.main(argv[:2] + ["--only", "no_such_object"])
    assert "no table for" in capsys.readouterr().err


def test_perturb_stage_moves_held_candidates_and_resumes(tmp_path, capsys):
    """`datagen perturb` on a copy of a committed table (the 43 mm procedural cube): held
    candidates moved 15 mm in their TCP frame, closed on in Drake, written beside the table;
    a rerun keeps the file; the labelling table is the table with those rows after it."""
    import shutil

    from sim_bridge.datagen.cli import main as datagen
    from sim_bridge.datagen.perturbed_grasps import load_labelling_table, perturbed_path

    committed = pathlib.Path(__file__).resolve().parents[2] / "models" / "grasp_tables_v3" / "objects"
    objects = tmp_path / "tables" / "objects"
    objects.mkdir(parents=True)
    shutil.copy(committed / "proc0_00012.npz", objects)
    args = ["perturb", "--objects", str(tmp_path / "tables"), "--per-object", "3", "--workers", "1", "--no-progress"]
    assert datagen(args) == 0
    assert "perturb: objects_done=1 kept=0 error=0 candidates=3" in capsys.readouterr().out
    out = perturbed_path(objects, "proc0_00012")
    z = dict(np.load(out))
    table = load_table(objects / "proc0_00012.npz")
    assert len(z["grasped"]) == 3 and table["grasped"][z["parent"]].all()  # moved from held rows
    np.testing.assert_allclose(np.linalg.norm(z["shift_tcp_m"], axis=1), 0.015, atol=1e-6)
    for parent, shift, X in zip(z["parent"], z["shift_tcp_m"], z["X_object_tcp_candidate"]):
        X0 = table["X_object_tcp_candidate"][parent]
        np.testing.assert_allclose(X[:3, 3] - X0[:3, 3], X0[:3, :3] @ shift, atol=1e-5)  # in its TCP frame
        assert shift[1] == 0 and shift[2] <= 0  # across the pads or shallower, never along the closing
    assert not any(str(r).startswith("simulation error") for r in z["reason"])

    mtime = out.stat().st_mtime_ns
    assert datagen(args) == 0
    assert "objects_done=0 kept=1" in capsys.readouterr().out and out.stat().st_mtime_ns == mtime
    merged = load_labelling_table(objects, "proc0_00012")
    n = len(table["grasped"])
    assert merged["table_rows"] == n and len(merged["grasped"]) == n + 3
    assert np.array_equal(merged["X_object_tcp_candidate"][n:], z["X_object_tcp_candidate"])
    assert merged["finger_joint_angles"].shape == (n + 3, table["finger_joint_angles"].shape[1])

    with pytest.raises(SystemExit):
        datagen(["perturb", "--objects", str(tmp_path / "nowhere")])
    assert "holds no grasp tables" in capsys.readouterr().err
