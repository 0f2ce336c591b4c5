"""The execution-settings study's bookkeeping: agreement, what differs, the CPU ratio, and
its refusal of settings that do not exist (the paired replay itself runs as
`make execution-settings-study`; its rounds are committed)."""

from sim_bridge.studies.execution_settings_study import main, markdown, summarize


def attempt(n, old, new, cpu_old=10.0, cpu_new=3.0):
    return {"attempt": n, "recorded": old, "old": {"outcome": old, "cpu_s": cpu_old, "sim_s": 12.0},
            "new": {"fast": {"outcome": new, "cpu_s": cpu_new, "sim_s": 9.0}}, "validness": 0.9, "score": 10.0}


def test_agreement_counts_every_outcome_and_lists_each_difference():
    records = [{"method": "ours", "mass_kg": 1.5, "scene_id": "packed_000",
                "attempts": [attempt(1, "success", "success"), attempt(2, "dropped", "dropped_in_hold")]},
               {"method": "binary", "mass_kg": 0.1, "scene_id": "pile_000",
                "attempts": [attempt(1, "success", "success"), attempt(2, "no_object", "success")]}]
    s = summarize(records, ("fast",))["settings"]["fast"]
    assert s["attempts"] == 4
    assert s["outcome_agreement"] == 0.5
    assert s["success_agreement"] == 0.75  # dropped -> dropped_in_hold is still a failure
    assert s["attempt_cpu_ratio"] == 0.3
    assert [(d["round"], d["attempt"]) for d in s["differing"]] == [("ours 1.5 kg packed_000", 2),
                                                                   ("binary 0.1 kg pile_000", 2)]
    assert s["by_method_weight"]["binary@0.1"] == {"attempts": 2, "old_successes": 1, "new_successes": 2}
    assert "no_object | success" in markdown(summarize(records, ("fast",)))


def test_an_unknown_setting_is_one_clear_error(capsys):
    assert main(["--settings", "warp", "--report", "--out", "unused"]) == 2
    assert "execution settings 'warp'" in capsys.readouterr().err


def test_the_noise_floor_arm_moves_the_grasp_30_um_across_the_pads_and_is_reported_as_such(tmp_path):
    import numpy as np
    from gravgrasp_detector.perception.detection import Grasp
    from sim_bridge.studies.execution_settings_study import NUDGE_M, NUDGED, nudged

    R = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # x_tcp along task y
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = R, (0.1, 0.2, 0.1)
    g = Grasp(pose=pose, score_n=10.0, validness=0.9, voxel_index=(1, 2, 3))
    moved = nudged(g)
    np.testing.assert_allclose(moved.pose[:3, 3] - pose[:3, 3], (0.0, NUDGE_M, 0.0), atol=1e-12)
    np.testing.assert_array_equal(moved.pose[:3, :3], R)
    assert g.pose[1, 3] == 0.2  # the original is untouched
    record = {"method": "binary", "mass_kg": 1.5, "scene_id": "pile_000",
              "attempts": [{"attempt": 1, "recorded": "success",
                            "old": {"outcome": "success", "cpu_s": 10.0, "sim_s": 12.0},
                            "new": {NUDGED: {"outcome": "dropped", "cpu_s": 10.0, "sim_s": 12.0}}}]}
    s = summarize([record], (NUDGED,))["settings"][NUDGED]
    assert s["outcome_agreement"] == 0.0 and s["lift_speed_mps"] == 0.05
    assert "the noise floor" in markdown(summarize([record], (NUDGED,)))
    assert main(["--settings", f"{NUDGED},lift_only", "--methods", "binary", "--report",
                 "--out", str(tmp_path / "study")]) == 0
