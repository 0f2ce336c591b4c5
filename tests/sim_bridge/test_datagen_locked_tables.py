"""`datagen rescore` and `datagen wrap` on a copy of a committed table (the 43 mm
procedural cube): the same candidates simulated again with the locked drive, failed rows
copied where the closing is unchanged; held precision candidates turned and moved toward
the palm, closed again with the table's own settings, appended for labelling."""
import json
import pathlib
import shutil

import numpy as np
import pytest

from sim_bridge.datagen.cli import main as datagen
from sim_bridge.datagen.object_grasps import MODE_NAMES, load_table
from sim_bridge.datagen.perturbed_grasps import load_labelling_table
from sim_bridge.datagen.power_grasps import wrap_path
from sim_bridge.physics.contact import SimSettings
from sim_bridge.datagen.rescored_tables import closing_unchanged

pytestmark = pytest.mark.drake

COMMITTED = pathlib.Path(__file__).resolve().parents[2] / "models" / "grasp_tables_v3" / "objects"
NAME = "proc0_00012"


@pytest.fixture(scope="module")
def rescored(tmp_path_factory):
    src = tmp_path_factory.mktemp("v3")
    (src / "objects").mkdir()
    shutil.copy(COMMITTED / f"{NAME}.npz", src / "objects")
    out = tmp_path_factory.mktemp("v6")
    args = ["rescore", "--objects", str(src), "--out", str(out), "--sim-setting", "drive=self_locking",
            "--max-held-rows", "2", "--workers", "1", "--no-progress"]
    assert datagen(args) == 0
    return out, args


def test_rescore_simulates_the_same_candidates_with_the_new_drive(rescored, capsys):
    out, args = rescored
    old, new = load_table(COMMITTED / f"{NAME}.npz"), load_table(out / "objects" / f"{NAME}.npz")
    settings = json.loads(str(new["sim_settings"]))
    assert settings["drive"] == "self_locking"
    assert {k: v for k, v in settings.items() if k not in ("drive", "lock_stiffness_nm_per_rad",
                                                           "lock_damping_nm_s_per_rad")} \
        == json.loads(str(old["sim_settings"]))  # only the drive changed
    assert len(new["grasped"]) == 2 and new["grasped"].all()  # a sample of held rows: the closing is the same
    rows = [int(np.flatnonzero(np.all(old["X_object_tcp_candidate"] == x, axis=(1, 2)))[0])
            for x in new["X_object_tcp_candidate"]]
    assert old["grasped"][rows].all()
    np.testing.assert_allclose(new["X_object_tcp"], old["X_object_tcp"][rows], atol=2e-4)  # settled alike
    assert datagen(args) == 0 and "objects_done=0 kept=1" in capsys.readouterr().out  # resumes


def test_wrap_moves_precision_grasps_toward_the_palm_and_appends_them(rescored, capsys):
    out, _ = rescored
    assert datagen(["wrap", "--objects", str(out), "--per-object", "1", "--workers", "1", "--no-progress"]) == 0
    assert "wrap: objects_done=1 kept=0 closings=1" in capsys.readouterr().out
    z = load_table(wrap_path(out / "objects", NAME))
    table = load_table(out / "objects" / f"{NAME}.npz")
    assert (table["mode"][z["parent"]] == MODE_NAMES.index("precision")).all()
    for parent, T, X in zip(z["parent"], z["offset_tcp"], z["X_object_tcp_candidate"]):
        np.testing.assert_allclose(table["X_object_tcp_candidate"][parent] @ T, X, atol=1e-5)
        depth = (T[:3, :3].T @ T[:3, 3])[2]
        assert 0.0 <= depth <= 0.04 + 1e-6  # toward the palm, along the turned approach
    assert json.loads(str(z["settings"]))["sim"]["drive"] == "self_locking"  # the table's own
    merged = load_labelling_table(out / "objects", NAME)
    assert len(merged["grasped"]) == len(table["grasped"]) + 1


def test_only_settings_that_act_after_settling_keep_the_closings():
    base = SimSettings.for_labels()
    assert closing_unchanged(base, SimSettings.for_labels(drive="self_locking", max_force_n=100.0))
    assert not closing_unchanged(base, SimSettings.for_labels(time_step_s=2e-3))


def test_a_bad_override_is_one_message(tmp_path, capsys):
    with pytest.raises(SystemExit):
        datagen(["rescore", "--objects", str(COMMITTED.parent), "--out", str(tmp_path), "--sim-setting", "drive=screw"])
    assert "drive 'screw'" in capsys.readouterr().err
