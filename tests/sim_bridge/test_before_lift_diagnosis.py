"""studies.before_lift_diagnosis without a replay: which recorded attempts are
before-the-lift failures, the executor's stop distance read back, the lever rules and
the report's last line."""

from sim_bridge.studies import before_lift_diagnosis as bld

JAMMED = ("arm could not reach the grasp pose: stopped by contact after 0.046 of 0.050 m: the force on "
          "the hand rose from 0 to 61 N, by more than the 60 N limit; backed out to the pre-grasp")


def attempt(outcome, reason=""):
    return {"outcome": outcome, "reason": reason, "rank": 0, "validness": 0.6, "score": 50.0, "mode": ""}


def test_failures_of_a_round_record():
    record = {"end": "no_feasible_grasp", "attempts": [
        attempt("success", "held 1.0 s"),
        attempt("no_object", "the grasp missed the object: the fingers stopped where they close on nothing"),
        attempt("dropped", "the object slipped out during the lift"),
        attempt("unreachable", JAMMED),
        attempt("unreachable", "arm could not reach the lift pose: stopped by contact after 0.004 of 0.1 m")]}
    assert bld.find_failures(record) == [(2, "no_object"), (4, "jammed_on_approach"), (5, "lift_blocked"),
                                         (6, "all_refused")]
    assert bld.find_failures({"end": "table_clear", "attempts": record["attempts"][:1]}) == []


def diagnosed(outcome, reason="", tcp_class="band", vgn_keeps=True, vgn_keeps_base=True, contact=None, truth=None, validness=0.95,
              other_same=True):
    return {"outcome": outcome, "reason": reason, "validness": validness,
            "diagnosis": {"tcp_class": tcp_class, "vgn_keeps": vgn_keeps, "vgn_keeps_base": vgn_keeps_base,
                          "first_contact": contact,
                          "surface_distance_mm": 5.0,
                          "truth_in_closing_region": truth or {},
                          "compare": {"binary": None,
                                      "ours_expected": {"same": other_same, "tcp_class": "band", "validness": 0.9,
                                                        "first_contact": None}}}}


def test_lever_rules():
    assert bld.recorded_stop_m(JAMMED) == (0.046, 0.05)
    # stopped 4 mm short, deep in an object, unsure: every lever but the empty close
    jammed = diagnosed("jammed_on_approach", JAMMED, "unobserved", False, False,
                       {"approach_m": 0.045, "short_m": 0.005, "what": "box", "part": "housing"},
                       validness=0.6, other_same=False)
    assert bld.levers_of(jammed) == ["guarded approach", "VGN mask", "VGN mask at the base", "validness floor",
                                     "validness x score",
                                     "inside negatives", "label-time clearance"]
    # closed on nothing in the band, sure of itself, nothing met on the way: only the empty close
    assert bld.levers_of(diagnosed("no_object")) == ["empty-close negatives"]
    # a stop 30 mm short is too far for the guarded approach to close on
    far = diagnosed("jammed_on_approach", JAMMED.replace("0.046", "0.020"), contact=None)
    assert "guarded approach" not in bld.levers_of(far)
    # a true object between the pads: not an empty close
    assert bld.levers_of(diagnosed("no_object", truth={"box": 40})) == []


def test_report_counts_diagnosed_of_all():
    record = {"results": "heldout_v4", "method": "ours", "mass_kg": 1.5, "scene_id": "pile_000", "replayed": 3,
              "cpu_s": 60.0, "successes": [{"attempt": 1, "validness": 0.97, "tcp_class": "inside",
                                            "vgn_keeps": False, "vgn_keeps_base": True}],
              "failures": [{**diagnosed("no_object"), "attempt": 2, "mode": "", "score": 40.0},
                           {"attempt": 3, "outcome": "no_object", "reason": "", "mode": "", "validness": 0.7,
                            "score": 30.0, "same_pose": False}]}
    lines = bld.report_lines([record])
    assert lines[-1] == "diagnosed=1 of 2"
    assert any("not diagnosed" in line for line in lines)
    assert any("VGN's mask would drop 1 (at the base 0)" in line for line in lines)
