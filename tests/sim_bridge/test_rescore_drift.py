"""rescore_drift on a committed table and a copy of it marked as rescored with the
locked drive: rows held in the source and not now are counted from the tables; copied
failures are closed again, and the closing's verdict is the one evaluate gives."""
import dataclasses
import json
import pathlib

import numpy as np
import pytest

from sim_bridge.datagen.object_grasps import load_table
from sim_bridge.datagen.object_sources import object_from_table
from sim_bridge.physics.contact import SimSettings
from sim_bridge.physics.grasp_simulation import GraspSimulator
from sim_bridge.studies.rescore_drift import drift, held_after_closing, main

pytestmark = pytest.mark.drake

COMMITTED = pathlib.Path(__file__).resolve().parents[2] / "models" / "grasp_tables_v3" / "objects" / "proc0_00012.npz"


def rescored_copy(tmp_path, lose_row):
    """The committed table as a rescore of it would look with nothing changed, but `lose_row`
    (held in the source) no longer held."""
    t = dict(np.load(COMMITTED))
    settings = dataclasses.asdict(SimSettings.from_record(json.loads(str(t["sim_settings"]))))
    grasped = t["grasped"].copy()
    assert grasped[lose_row]
    grasped[lose_row] = False
    d = tmp_path / "v6" / "objects"
    d.mkdir(parents=True)
    np.savez(d / COMMITTED.name, **dict(t, grasped=grasped, sim_settings=np.asarray(json.dumps(
        dict(settings, drive="self_locking"))), rescored_from=np.asarray(str(COMMITTED))))
    return d


def test_counts_both_directions(tmp_path, capsys):
    d = rescored_copy(tmp_path, lose_row=0)
    failures = drift(sorted(d.glob("*.npz")))["failures"]
    source = load_table(COMMITTED)
    assert len(failures) == int((~source["grasped"].astype(bool)).sum())  # row 0 was simulated again, not copied
    assert main([str(d), "--sample", "2", "--out", str(tmp_path / "rows.json")]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert out[0].startswith("held in the source, not now: 1 of 351 (0.3%)"), out
    assert out[-1].startswith("held_now_of_copied_failures=")
    rows = json.loads((tmp_path / "rows.json").read_text())
    assert len(rows) == 2 and all(not source["grasped"][r["row"]] for r in rows)


def test_the_closing_decides_held_as_evaluate_does():
    t = load_table(COMMITTED)
    sim = GraspSimulator(object_from_table(t, ()), SimSettings.from_record(json.loads(str(t["sim_settings"]))))
    failed = int(np.flatnonzero(~t["grasped"].astype(bool))[0])
    for i in (0, failed):
        X = t["X_object_tcp_candidate"][i].astype(float)
        assert held_after_closing(sim, X) == sim.evaluate(X).grasped


def test_tables_without_a_readable_source_are_one_message(tmp_path, capsys):
    d = tmp_path / "objects"
    d.mkdir()
    np.savez(d / "a.npz", grasped=np.ones(2, bool), rescored_from=np.asarray(str(tmp_path / "gone.npz")))
    assert main([str(d)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no rescored table with a readable source" in err[0]
