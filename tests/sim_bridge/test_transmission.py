"""The 2F-85's self-locking transmission (sim_bridge.physics.transmission): calibrated
against the back-drivable drive at the label settings (doc/grasp-simulation.md,
*Transmission*), stable, and engaged and released in the simulated cell as the real
gripper's lock is."""

import numpy as np
import pytest

from sim_bridge.physics.contact import SimSettings
from sim_bridge.physics.grasp_simulation import GraspSimulator, measure_squeeze_force_n
from sim_bridge.physics.objects import procedural_object
from sim_bridge.physics.scenes import TABLE_HEIGHT_M
from sim_bridge.studies.transmission_study import Z_PLUS, cylinder_pose
from sim_bridge.world import R_TOP_DOWN, SceneConfig, SimWorld, WorldSettings, pose

pytestmark = pytest.mark.drake

LOCKED = SimSettings.for_labels(drive="self_locking")
BACKDRIVABLE = SimSettings.for_labels(drive="backdrivable")
# The squeeze table of doc/grasp-simulation.md (back-drivable, dt 1 ms) [N]
SQUEEZE_TABLE_N = {0.01: 36.8, 0.05: 39.7, 0.08: 46.8}


@pytest.mark.parametrize("width_m", sorted(SQUEEZE_TABLE_N))
def test_the_locked_squeeze_is_the_calibrated_grip(width_m):
    # locked and held 0.3 s: the lock keeps the grip the motor made, no more, no less
    assert measure_squeeze_force_n(width_m, LOCKED) == pytest.approx(SQUEEZE_TABLE_N[width_m], rel=0.03)


def evaluate(diameter_m, depth_m, settings):
    sim = GraspSimulator(procedural_object("cylinder", (diameter_m, 0.2), mass_kg=0.5), settings)
    return sim.evaluate(cylinder_pose(depth_m))


@pytest.fixture(scope="module")
def locked_cylinders():
    return {(d, z): evaluate(d, z, LOCKED) for d, z in ((0.065, -0.020), (0.065, 0.0), (0.040, -0.015), (0.040, 0.010))}


def test_a_locked_pinch_slides_along_the_cylinder_as_friction_allows(locked_cylinders):
    # friction-limited: the lock must not squeeze harder while the pads slide
    free = evaluate(0.065, 0.0, BACKDRIVABLE)
    locked = locked_cylinders[(0.065, 0.0)]
    assert free.mode == locked.mode == "precision"
    assert 1.0 <= locked.scores_n[0] / free.scores_n[0] <= 1.15, (locked.scores_n, free.scores_n)
    assert np.all(np.isfinite(locked.scores_n))


@pytest.mark.parametrize("diameter_m,power_depth_m,pinch_depth_m", [(0.065, -0.020, 0.0), (0.040, -0.015, 0.010)])
def test_an_enclosing_grasp_resists_pull_out_twice_its_pinch(locked_cylinders, diameter_m, power_depth_m, pinch_depth_m):
    power, pinch = locked_cylinders[(diameter_m, power_depth_m)], locked_cylinders[(diameter_m, pinch_depth_m)]
    assert power.mode == "power" and pinch.mode == "precision"
    assert power.scores_n[Z_PLUS] >= 2.0 * pinch.scores_n[Z_PLUS], (power.scores_n, pinch.scores_n)


def test_the_backdrivable_drive_lets_the_wrap_open():
    # the drive the lock replaces: pulled out along +z, the Ø65 wrap opens at about
    # its pinch's force (doc: 71.5 N), where the locked one holds twice that
    free = evaluate(0.065, -0.020, BACKDRIVABLE)
    assert free.mode == "power" and free.scores_n[Z_PLUS] < 100.0


def test_the_drive_is_validated_and_old_records_read_as_backdrivable():
    with pytest.raises(ValueError, match="drive"):
        SimSettings(drive="screw").validate()
    assert SimSettings.from_record({"time_step_s": 1e-3}).drive == "backdrivable"


def test_the_cell_locks_on_an_object_and_an_open_command_releases_it():
    box = procedural_object("box", (0.03, 0.05, 0.05), mass_kg=0.3)
    X = pose(p=(0.15, 0.15, TABLE_HEIGHT_M + 0.026))
    world = SimWorld(SceneConfig(objects=((box, X),)), WorldSettings(contact=SimSettings(drive="self_locking")))
    actuators = world._model.hand.actuators
    ok, message = world.move_tcp(pose(R_TOP_DOWN, (0.15, 0.15, TABLE_HEIGHT_M + 0.03)), 0.25)
    assert ok, message
    world.command_fingers(0.0, 0.1, 40.0)
    for _ in range(150):
        world.advance(0.01)
        if world.finger_status()[1] == "blocked":
            break
    width, state = world.finger_status()
    assert state == "blocked" and width == pytest.approx(0.05, abs=0.004)
    world.advance(0.02)
    assert world.fingers_locked() and all(a.has_controller() for a in actuators)
    checkpoint = world.checkpoint()
    world.hold_fingers()  # rGTO = 0: the lock keeps the grip
    assert world.fingers_locked()
    world.command_fingers(0.085, 0.1, 40.0)
    assert not world.fingers_locked() and not any(a.has_controller() for a in actuators)
    world.advance(0.8)
    assert world.finger_width_m() > 0.08
    world.rewind(checkpoint)  # the gains are the plant's: a rewind puts them back
    assert world.fingers_locked() and all(a.has_controller() for a in actuators)


def test_the_backdrivable_cell_never_locks():
    box = procedural_object("box", (0.03, 0.05, 0.05), mass_kg=0.3)
    X = pose(p=(0.15, 0.15, TABLE_HEIGHT_M + 0.026))
    world = SimWorld(SceneConfig(objects=((box, X),)), WorldSettings(contact=SimSettings(drive="backdrivable")))
    ok, message = world.move_tcp(pose(R_TOP_DOWN, (0.15, 0.15, TABLE_HEIGHT_M + 0.03)), 0.25)
    assert ok, message
    world.command_fingers(0.0, 0.1, 40.0)
    world.advance(1.0)
    assert world.finger_status()[1] == "blocked" and not world.fingers_locked()


def test_two_rescored_tables_are_compared_row_by_row(tmp_path, capsys):
    from sim_bridge.studies import transmission_study as ts

    def write(d, scores, grasped, X=np.eye(4)):
        (d / "objects").mkdir(parents=True)
        np.savez(d / "objects" / "box.npz", X_object_tcp_candidate=np.stack([X, X]).astype(np.float32),
                 mode=np.array([1, 1], np.uint8), grasped=np.array(grasped), scores_n=np.array(scores, np.float32),
                 finger_joint_names=np.zeros(0, "<U1"), finger_joint_angles=np.zeros((2, 0), np.float32))
    write(tmp_path / "locked", [[30, 30, 80, 80, 26, 25], [10] * 6], [True, True])
    write(tmp_path / "free", [[30, 30, 45, 45, 25, 24], [10] * 6], [True, False])
    c = ts.compare_tables(tmp_path / "locked", tmp_path / "free")
    assert (c["rows"], c["mode_differs"], c["held_differs"], c["held_in_both"]) == (2, 0, 1, 1)
    assert c["wraps"] is None and c["not_wraps"]["median_locked_n"][2] == 80.0
    assert c["not_wraps"]["min_score_ratio_p10_p50_p90"][1] == pytest.approx(25 / 24, abs=1e-3)
    write(tmp_path / "other", [[1] * 6] * 2, [True, True], X=2 * np.eye(4))
    assert ts.main(["--compare-tables", str(tmp_path / "locked"), str(tmp_path / "other")]) == 2
    assert "other candidates" in capsys.readouterr().err


def test_locked_ramps_on_a_committed_table_stay_finite_and_in_the_hand():
    """The study's stability check on two held rows of a committed table (the 43 mm
    procedural cube): every ramp finite, the object still in the hand after a locked idle hold."""
    import pathlib

    from sim_bridge.studies import transmission_study as ts

    path = pathlib.Path(__file__).resolve().parents[2] / "models" / "grasp_tables_v3" / "objects" / "proc0_00012.npz"
    held = tuple(int(r) for r in np.flatnonzero(np.load(path)["grasped"])[:2])
    rows = ts.run_stability(ts.StabilityTask(str(path), held, ()))
    assert [r["grasped"] for r in rows] == [True, True]
    assert all(r["finite"] and r["ramps"] == 6 and r["idle_moved_m"] < ts.SNAP_OUT_M for r in rows), rows
