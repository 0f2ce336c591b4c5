"""The benchmark's attempt records: score_n in newtons or nothing, validness and rank_key
apart (clearing.grasp_fields), and the report reading both them and the committed
schema-1 records, whose one `score` is newtons or a probability by the round's target."""
import json
import math
import pathlib

import numpy as np
import pytest

from gravgrasp_detector.perception.detection import Grasp
from sim_bridge.benchmark import clearing, report, run_files

RESULTS = run_files.rounds_file(pathlib.Path(__file__).resolve().parents[2] / "sim_bridge" / "results" / "heldout_v4")


def test_a_record_keeps_newtons_validness_and_the_rank_key_apart():
    score = clearing.grasp_fields(Grasp(np.eye(4), 57.43211, 0.8, (1, 2, 3), rank_key=0.8 * 57.43211))
    assert score == {"score_n": 57.4321, "validness": 0.8, "rank_key": pytest.approx(45.9457)}
    binary = clearing.grasp_fields(Grasp(np.eye(4), math.nan, 0.97, (1, 2, 3), rank_key=0.97))
    assert binary == {"score_n": None, "validness": 0.97, "rank_key": 0.97}  # no probability under N
    json.dumps(binary, allow_nan=False)  # strict JSON: no NaN in a record


def test_clear_table_keeps_the_cells_fields_in_each_attempt():
    class Cell:
        def __init__(self):
            self.on_table = ["a"]

        def objects_on_table(self):
            return self.on_table

        def detect(self):
            return None, [Grasp(np.eye(4), math.nan, 0.9, (0, 0, 0), rank_key=0.9)]

        def execute(self, grasp, scene):
            self.on_table = []
            return {"outcome": "success", "reason": "held", **clearing.grasp_fields(grasp),
                    "stopped_by_contact": False}

        def remove_fallen(self):
            return []

    (attempt,) = clearing.clear_table(Cell(), 1)["attempts"]
    assert {k: attempt[k] for k in ("score_n", "validness", "rank_key", "success")} == {
        "score_n": None, "validness": 0.9, "rank_key": 0.9, "success": True}


def test_the_report_reads_new_records_and_the_committed_old_ones():
    new = {"score_n": None, "validness": 0.97, "rank_key": 0.97}
    assert report.attempt_scores(new, "binary") == new
    # committed schema-1 rounds: `score` is the validness for binary, newtons for ours
    binary, ours = RESULTS.get("binary", 0.1, "packed_000"), RESULTS.get("ours", 0.1, "packed_000")
    assert binary["schema_version"] == ours["schema_version"] == 1
    a = binary["attempts"][0]
    assert report.attempt_scores(a, binary["target"]) == {"score_n": None, "validness": a["validness"],
                                                          "rank_key": a["validness"]}
    a = ours["attempts"][0]
    assert a["score"] > 1.0  # newtons
    assert report.attempt_scores(a, ours["target"]) == {"score_n": a["score"], "validness": a["validness"],
                                                        "rank_key": None}


@pytest.mark.parametrize("flag, reason, expected", [
    (True, "arm could not reach the grasp pose: protective stop; backed out to the pre-grasp", "jammed_on_approach"),
    (True, "arm could not reach the lift pose: halted; opened and backed out to the pre-grasp", "lift_blocked"),
    (False, "arm could not reach the grasp pose: stopped by contact after 0.1 of 0.2 m", "unreachable"),
    (None, "arm could not reach the grasp pose: stopped by contact after 0.1 of 0.2 m", "jammed_on_approach"),
    (None, "arm could not reach the grasp pose: outside the arm's reach", "unreachable"),
])
def test_a_contact_stop_is_the_records_flag_and_old_records_words(flag, reason, expected):
    attempt = {"outcome": "unreachable", "reason": reason}
    if flag is not None:  # None: a schema-1 record, from before the flag
        attempt["stopped_by_contact"] = flag
    assert report.outcome_class(attempt) == expected
