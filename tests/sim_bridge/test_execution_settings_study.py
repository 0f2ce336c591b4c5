"""The execution-settings study's bookkeeping: agreement, what differs, the CPU ratio, and
its refusal of settings that do not exist (the paired replay itself runs as
`make execution-settings-study`; its rounds are committed)."""
import pytest

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
