import json

import numpy as np
import pytest

from sim_bridge.datagen.data_report import main
from sim_bridge.datagen.object_grasps import MODE_NAMES

pytestmark = pytest.mark.drake


def write_table(d, name, modes, scores):
    modes = np.asarray(modes, np.uint8)
    np.savez(d / f"{name}.npz", mode=modes, grasped=modes != 2, scores_n=np.asarray(scores, np.float32),
             wall_time_s=np.full(len(modes), 2.0, np.float32), mode_names=np.asarray(MODE_NAMES))


def test_report_counts_and_last_lines(tmp_path, capsys):
    objects = tmp_path / "objects"
    objects.mkdir()
    write_table(objects, "a", [0, 0, 1, 2], np.full((4, 6), 10.0))
    write_table(objects, "b", [1, 2], np.full((2, 6), 5.0))
    (objects / "c.skip.json").write_text(json.dumps({"name": "c", "reason": "c: mass 0.0 kg is not positive"}))
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    np.savez(scenes / "000000.npz", label_score=np.array([3.0, 4.0], np.float32), label_mode=np.array([0, 1], np.uint8),
             arrangement=np.asarray("pile"), n_grasps_collision_free=np.int64(9), n_grasps_dropped_executed=np.int64(2))
    assert main([str(tmp_path)]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert out[-4:] == ["objects=2", "grasps=4", "power_fraction=0.5000", "labels_per_scene_median=2"]
    assert "  c: mass 0.0 kg is not positive" in out  # the reason names the object once, not twice
    assert any("labels per scene mean 2.0" in line for line in out)
    # 9 grasps passed every check (2 more failed where executed and are not among them):
    # 9 valid grasps on 2 labelled voxels
    assert any("valid grasps per scene" in line and "median 9," in line and "4.5 per labelled voxel" in line
               for line in out), out
    assert (tmp_path / "report.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # committed tables and regenerated scenes live apart: --scenes names the scene stage's --out
    tables = tmp_path / "tables"
    (objects).rename(tables)
    assert main([str(tables), "--scenes", str(tmp_path), "--png", str(tmp_path / "r2.png")]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1] == "labels_per_scene_median=2"
    assert main([str(tables), "--png", str(tmp_path / "r3.png")]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1] == "labels_per_scene_median=n/a"


def test_report_on_an_empty_directory_is_one_clear_line(tmp_path, capsys):
    assert main([str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "no grasp tables" in err and len(err.strip().splitlines()) == 1


def test_report_counts_wraps_by_the_rule_and_the_toward_the_palm_rows(tmp_path, capsys):
    from sim_bridge.datagen.object_grasps import CONTACT_LINK_NAMES
    objects = tmp_path / "objects"
    (objects / "toward_palm").mkdir(parents=True)
    joints = np.asarray(["left_coupler", "right_coupler"])
    palm = 1 << CONTACT_LINK_NAMES.index("base")
    pad = 1 << CONTACT_LINK_NAMES.index("left_pad")

    def rows(path, modes, contacts, couplers, own=True):
        modes = np.asarray(modes, np.uint8)
        extra = dict(mode_names=np.asarray(MODE_NAMES), contact_link_names=np.asarray(CONTACT_LINK_NAMES)) if own else {}
        np.savez(path, mode=modes, grasped=modes != 2, scores_n=np.full((len(modes), 6), 20.0, np.float32),
                 contacts=np.asarray(contacts, np.uint16), finger_joint_names=joints,
                 finger_joint_angles=np.asarray(couplers, np.float32), **extra)
    # held: a wrap (palm, both couplers 0.1 rad past their stop); palm but one coupler at its
    # stop (recorded "power" by an older rule: not a wrap); a pad pinch; one not held
    rows(objects / "a.npz", [0, 0, 1, 2], [palm, palm, pad, 0],
         [[-0.1, -0.1], [-0.1, 0.0], [0.0, 0.0], [0.0, 0.0]])
    rows(objects / "toward_palm" / "a.npz", [0, 1], [palm | pad, palm], [[-0.2, -0.06], [-0.01, -0.3]], own=False)
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    np.savez(scenes / "000000.npz", label_score=np.array([30.0, 50.0, 10.0], np.float32),
             label_mode=np.array([0, 0, 1], np.uint8), arrangement=np.asarray("pile"))
    assert main([str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "wraps (held grasps meeting the wrap rule): 1 (33.3% of held)" in out
    assert "toward-the-palm rows (datagen wrap) of 1 objects: 2 closed, 2 held, 1 wraps; with them: 2 wraps of 5 held" in out
    assert "median 30.0 N (power 40.0 N, precision 10.0 N)" in out


def test_report_gives_the_rescorings_core_hours_and_the_rows_it_lost(tmp_path, capsys):
    """A table of `datagen rescore`: only the rows held in its source were simulated again
    (the closing is unchanged, only the drive differs), so only their time is the
    rescoring's; a row held in the source and not now is counted."""
    import dataclasses
    from sim_bridge.physics.contact import SimSettings
    source_dir, objects = tmp_path / "v3", tmp_path / "v6" / "objects"
    source_dir.mkdir()
    objects.mkdir(parents=True)
    old = SimSettings.for_labels()
    new = dataclasses.replace(old, drive="self_locking")

    def table(path, modes, seconds, settings, **extra):
        modes = np.asarray(modes, np.uint8)
        np.savez(path, mode=modes, grasped=modes != 2, scores_n=np.full((len(modes), 6), 9.0, np.float32),
                 wall_time_s=np.asarray(seconds, np.float32), mode_names=np.asarray(MODE_NAMES),
                 sim_settings=np.asarray(json.dumps(dataclasses.asdict(settings))), **extra)
    table(source_dir / "a.npz", [1, 1, 0, 2, 2], [1.0, 1.0, 1.0, 0.5, 0.5], old)
    # rows 0-2 simulated again (3 + 4 + 5 s; row 1 no longer held), rows 3-4 copied
    table(objects / "a.npz", [1, 2, 0, 2, 2], [3.0, 4.0, 5.0, 0.5, 0.5], new,
          rescored_from=np.asarray(str(source_dir / "a.npz")))
    assert main([str(tmp_path / "v6"), "--png", str(tmp_path / "r.png")]) == 0
    out = capsys.readouterr().out
    assert ("rescored tables (datagen rescore): 1 objects, 3 rows simulated again in 0.00 core-hours "
            "(the other rows copied); held in the source but not now: 1 of 3 (33.3%)") in out, out
    from sim_bridge.datagen.data_report import collect
    assert collect(tmp_path / "v6")["rescored"]["wall_time_s"] == 12.0
    (source_dir / "a.npz").unlink()  # a source that cannot be read is said, not guessed
    assert main([str(tmp_path / "v6"), "--png", str(tmp_path / "r.png")]) == 0
    assert "1 tables' sources not found" in capsys.readouterr().out
