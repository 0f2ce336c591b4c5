"""studies.first_view_picks without a simulation: the report's counts by the
first attempt's outcome, and which first picks each mask takes away."""

from sim_bridge.studies import first_view_picks as mfv


def pick(same, contact=None, validness=0.95):
    return {"same": same, "tcp_class": "band", "validness": validness, "first_contact": contact}


def record(scene, outcome, tcp, finger_base, contact=None, same_pose=True):
    return {"results": "heldout_v4", "method": "ours", "mass_kg": 1.5, "scene_id": scene, "outcome": outcome,
            "validness": 0.7, "same_pose": same_pose, "cpu_s": 2.0, "detected": {"tcp": 8, "finger_base": 5},
            "diagnosis": {"tcp_class": "inside", "first_contact": contact,
                          "compare": {"tcp": tcp, "finger_base": finger_base}}}


BOX = {"what": "box", "approach_m": 0.04, "short_m": 0.01, "part": "housing"}


def test_report_counts_the_first_picks_each_mask_takes_away():
    records = [record("a", "success", pick(False, BOX), pick(True)),
               record("b", "success", pick(True), pick(True)),
               record("c", "jammed_on_approach", pick(False), pick(False, validness=0.97), contact=BOX),
               record("d", "no_object", None, pick(True)),
               record("e", "success", None, None, same_pose=False)]  # did not repeat: left out
    lines = mfv.report_lines(records)
    assert lines[0] == "heldout_v4 ours: 5 rounds, 4 first views repeated"
    # c's recorded pick met the box; tcp's other pick in a met it, d had none feasible
    assert lines[1] == ("- first picks whose approach meets something: ours (recorded) 1 of 4; "
                        "tcp 1 of 3 (none feasible 1); finger_base 0 of 4")
    success = lines.index("- first attempt success (2): TCP inside 2, band 0, free 0, unobserved 0; "
                          "approach meets something 0")
    assert lines[success + 1].startswith("  - mask tcp: drops the pick 1 (another pick 1, of which approach "
                                         "meets something 1, validness median 0.95; none feasible 0); keeps it 1")
    assert lines[success + 2].startswith("  - mask finger_base: drops the pick 0 (another pick 0")
    failed = lines.index("- first attempt before the lift (2): TCP inside 2, band 0, free 0, unobserved 0; "
                         "approach meets something 1")
    assert "mask tcp: drops the pick 2 (another pick 1" in lines[failed + 1] and "none feasible 1" in lines[failed + 1]
    assert "mask finger_base: drops the pick 1 (another pick 1" in lines[failed + 2]
    assert ("- heldout_v4 ours 1.5 kg c: jammed_on_approach, TCP inside, validness 0.70, meets box; tcp: another "
            "(band, validness 0.95, clear); finger_base: another (band, validness 0.97, clear)") in lines
    # of the 4 repeated first picks c met the box and failed; d met nothing and failed
    assert lines[-2] == ("recorded first picks that failed before the lift: meeting something 1 of 1 (100 %), "
                         "meeting nothing 1 of 3 (33 %)")
    assert lines[-1] == "CPU per round: mean 2.0 s, total 10 s (5 rounds)"


def test_report_names_method_selections_without_mask():
    r = record("a", "jammed_on_approach", None, None, contact=BOX)
    r["detected"] = {"binary_scored": 12}
    r["diagnosis"]["compare"] = {"binary_scored": pick(False, BOX, validness=0.93)}
    lines = mfv.report_lines([r])
    assert any(line.startswith("  - binary_scored: drops the pick 1 (another pick 1, of which approach meets "
                               "something 1, validness median 0.93") for line in lines)
    assert lines[-3].endswith("binary_scored: another (band, validness 0.93, meets something)")


def test_unknown_selection_is_refused_before_any_round():
    import pytest
    with pytest.raises(ValueError, match="--compare 'vgn'"):
        mfv.check_selections(["tcp", "vgn"])
    mfv.check_selections(["tcp", "finger_base", "binary_scored"])  # the shipped files are there
