"""mode_payload_study on a hand-made grasp table: a top-down grasp's f_g is its +z score,
a resting pose whose grasps all point up has none executable, and the shares are the
rest probabilities of the poses each mode holds at each weight."""
import numpy as np
import pytest

from sim_bridge.datagen.object_grasps import MODE_NAMES
from sim_bridge.studies import mode_payload_study as mps


def top_down(z_m=0.1):
    X = np.eye(4)
    X[:3, :3] = np.diag([1.0, -1.0, -1.0])  # approach (TCP z) straight down
    X[2, 3] = z_m
    return X


def table(scores_plus_z, modes, grasped):
    n = len(modes)
    scores = np.full((n, 6), 100.0)
    scores[:, 4] = scores_plus_z  # +z in the TCP frame: up, against gravity, for a top-down grasp
    flipped = np.eye(4)
    flipped[:3, :3] = np.diag([1.0, -1.0, -1.0])  # upside down: every approach points up
    return {"grasped": np.array(grasped), "X_object_tcp_candidate": np.stack([top_down()] * n).astype(np.float32),
            "mode": np.array([MODE_NAMES.index(m) for m in modes], np.uint8), "scores_n": scores.astype(np.float32),
            "rest_X_table_object": np.stack([np.eye(4), flipped]), "rest_probability": np.array([0.6, 0.2])}


def test_only_power_from_the_weight_its_score_alone_holds():
    t = table([50.0, 30.0, 90.0], ["power", "precision", "precision"], [True, True, False])  # 90 N: not held
    rows = {r["mass_kg"]: r for r in mps.study({"box": t}, (1.5, 4.0, 6.0))["weights"]}
    # the rest probabilities normalised over the object's poses: 0.75 and 0.25 (no grasp there)
    assert [rows[1.5][k] for k in ("precision", "power", "either", "only_power")] == pytest.approx([0.75, 0.75, 0.75, 0])
    assert [rows[4.0][k] for k in ("power", "only_power", "precision")] == pytest.approx([0.75, 0.75, 0])  # 39.2 N
    assert rows[6.0]["either"] == 0.0  # 58.9 N: neither
    assert rows[1.5]["power_share_of_holding_grasps"] == 0.5 and rows[4.0]["holding_grasps"] == 1


def test_the_best_of_each_mode_per_pose():
    t = table([50.0, 30.0, 70.0], ["power", "precision", "precision"], [True, True, True])
    result = mps.study({"box": t}, (4.0, 6.0))
    assert result["poses_with_both_modes"] == 1 and result["power_best_stronger"] == 0.0
    assert result["median_best_f_g_n"] == {"power": 50.0, "precision": 70.0}
    rows = {r["mass_kg"]: r for r in result["weights"]}
    assert rows[4.0]["only_power"] == 0.0 and rows[6.0]["only_precision"] == pytest.approx(0.75)


def test_a_grasp_into_the_table_does_not_count():
    t = table([50.0], ["power"], [True])
    t["X_object_tcp_candidate"][0, 2, 3] = 0.0  # the pinch point on the table: the finger tips below it
    assert mps.study({"box": t}, (1.5,))["weights"][0]["power"] == 0.0


def test_no_tables_is_one_sentence(tmp_path, capsys):
    assert mps.main(["--tables", str(tmp_path), "--out", str(tmp_path / "out.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "datagen objects" in err and str(tmp_path) in err


def test_a_power_grasp_that_does_not_wrap_counts_as_precision():
    t = table([50.0, 30.0], ["power", "power"], [True, True])
    t["finger_joint_names"] = np.array(["left_coupler", "right_coupler"])
    t["finger_joint_angles"] = np.array([[-0.3, -0.2], [0.0, -0.4]], np.float32)  # the second: one finger parallel
    result = mps.study({"box": t}, (1.5,))
    assert result["grasps"] == {"power": 1, "precision": 1}
    assert result["wrap_power_fraction"] == 0.5
    assert result["power_over_precision_best_fg"] == pytest.approx(50.0 / 30.0)
