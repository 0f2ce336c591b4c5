"""studies.before_lift_split: a run's attempts lost before the lift (closed on nothing, contact
stops), by the picked grasp's validness and by when in the round."""

import json

from sim_bridge.studies import before_lift_split


def pose(x_m):
    return [[1, 0, 0, x_m], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]


def write_attempts(run, attempts):
    """attempts.json as `benchmark --report` writes it, one round per method in the listed
    order; attempts: [(method, validness, outcome, reason[, TCP x in m])]."""
    run.mkdir(parents=True)
    rounds = [{"method": m, "mass_kg": 1.5, "scene_id": "packed_000", "end": "table_clear"}
              for m in dict.fromkeys(m for m, *_ in attempts)]
    run.joinpath("attempts.json").write_text(json.dumps({"rounds": rounds, "attempts": [
        {"method": m, "mass_kg": 1.5, "scene_id": "packed_000", "validness": v, "outcome": o, "reason": why,
         "attempt": i, "pose": pose(x[0] if x else 0.1 * i)}
        for i, (m, v, o, why, *x) in enumerate(attempts)]}))


def test_bands_count_losses_before_the_lift_only(tmp_path, capsys):
    run = tmp_path / "run"
    write_attempts(run, [
        ("binary_scored", 0.91, "unreachable", "arm could not reach the grasp pose: stopped by contact after 3 tries"),
        ("binary_scored", 0.93, "no_object", ""),
        ("binary_scored", 0.94, "dropped", ""),  # lost after the lift: not counted
        ("binary_scored", 0.96, "success", ""),
        ("binary", 0.92, "unreachable", "target outside the arm's workspace"),  # not a contact stop
        ("binary", 1.0, "success", ""), ("binary", 0.5, "no_object", "")])
    counts = before_lift_split.band_counts(before_lift_split.load_rounds(run), ["binary_scored", "binary"], (0.9, 0.95))
    assert counts["binary_scored"] == [(0.0, 0.9, 0, 0), (0.9, 0.95, 2, 3), (0.95, 1.0, 0, 1)]
    assert counts["binary"] == [(0.0, 0.9, 1, 1), (0.9, 0.95, 0, 1), (0.95, 1.0, 0, 1)]  # 1.0 is in the last band
    assert before_lift_split.main([str(run), "--bands", "0.9,0.95"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert "| binary_scored | — | 2 / 3 (67 %) | 0 / 1 (0 %) |" in out
    assert out[-2:] == ["lost_before_lift_binary_scored_0.9_0.95=2/3", "lost_before_lift_binary_0.9_0.95=0/1"]
    assert "| binary_scored | 1 / 1 (100 %) | 1 / 3 (33 %) | 0 |" in out  # the first attempt was stopped


def test_losses_split_by_when_in_the_round_and_repeats_of_a_failed_place(tmp_path):
    run = tmp_path / "run"
    stop = "arm could not reach the grasp pose: stopped by contact after 1 try"
    write_attempts(run, [("binary_scored", 0.95, "success", "", 0.0),
                         ("binary_scored", 0.92, "unreachable", stop, 0.2),
                         ("binary_scored", 0.92, "unreachable", stop, 0.205),  # the same place again
                         ("binary_scored", 0.93, "no_object", "", 0.4)])  # elsewhere
    counts = before_lift_split.position_counts(before_lift_split.load_rounds(run), ["binary_scored"])
    assert counts["binary_scored"] == {"first": (0, 1), "later": (3, 3), "repeats": 1}


def test_bad_bands_and_unknown_methods_are_refused_with_one_line(tmp_path, capsys):
    run = tmp_path / "run"
    write_attempts(run, [("binary", 0.95, "success", "")])
    assert before_lift_split.main([str(run), "--bands", "0.95,0.9"]) == 2
    assert before_lift_split.main([str(run), "--bands", "x"]) == 2
    assert before_lift_split.main([str(run), "--methods", "ours"]) == 2
    assert before_lift_split.main([str(tmp_path / "absent")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 4 and "increasing validness edges" in err[0] and "no rounds of ours" in err[2]
    assert "--report" in err[3]
