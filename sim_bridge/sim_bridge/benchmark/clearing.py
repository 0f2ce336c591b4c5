"""The clutter-removal round's rules (paper/VGN protocol): `clear_table` drives a cell
until the table is clear or a stopping rule ends the round, and `success_rates` turns
its attempts into SR and CR. The in-process benchmark (`sim_cell.SimCell`) and the ROS
demo (`ros.clutter_demo`) both run them, so both count the same way. No Drake, no ROS."""

from __future__ import annotations

import math

CONSECUTIVE_FAILURES_END = 2
ATTEMPTS_PER_OBJECT = 3
MAX_REFUSALS_KEPT = 5  # reasons kept when a round ends with no feasible grasp


class Refused(Exception):
    """The cell would not start this grasp (the executor's own checks: workspace, reach,
    the open hand against the scene): no attempt; the next-ranked grasp is tried."""


class Fault(Exception):
    """The cell cannot go on (the executor disarmed on a fault; a robot would wait for a
    person): no attempt, and the round ends."""


class Stalled(Exception):
    """detect() saw no fresh view (the camera or the TSDF stopped): the round ends with
    that reason, never read as "nothing detected"."""


def clear_table(cell, n_objects: int, attempts_per_object: int = ATTEMPTS_PER_OBJECT) -> dict:
    """Clear a table. `cell`:

        objects_on_table() -> names of the objects still on the table
        detect() -> (scene, grasps): a fresh view and the grasps detected in it, best first;
            raises Stalled when no fresh view comes (the round ends)
        execute(grasp, scene) -> {"outcome": "success" or why not, ...}: one attempt;
            raises Refused (try the next grasp) or Fault (the round ends)
        remove_fallen() -> names of the objects that left the table since the last call

    A round ends when the table is clear, after CONSECUTIVE_FAILURES_END failures in a
    row, at attempts_per_object x n_objects attempts, when nothing is detected, when no
    detected grasp is executable, on a Fault, or when the view stalls.
    -> {end, attempts, fell_off} (+ fault: its message, when a Fault ended the round;
    + stalled: why, when no fresh view came;
    + refused: {grasps, first: the first refusal reasons}, when no grasp was feasible);
    each attempt is {rank, grasps_detected, skipped_infeasible, **execute's dict, success}
    (the benchmark's execute puts `grasp_fields` and the executor's stopped_by_contact there)."""
    attempts, fell_off, failures = [], [], 0
    max_attempts = attempts_per_object * n_objects
    while True:
        if not cell.objects_on_table():
            end = "table_clear"
            break
        if failures >= CONSECUTIVE_FAILURES_END:
            end = "consecutive_failures"
            break
        if len(attempts) >= max_attempts:
            end = "attempt_limit"
            break
        try:
            scene, grasps = cell.detect()
        except Stalled as e:
            return {"end": "view_stalled", "attempts": attempts, "fell_off": fell_off, "stalled": str(e)}
        if not grasps:
            end = "no_grasp_detected"
            break
        result, rejected = None, []
        try:
            for rank, g in enumerate(grasps):
                try:
                    result = cell.execute(g, scene)
                    break
                except Refused as e:
                    rejected.append(str(e))
        except Fault as e:
            return {"end": "executor_fault", "attempts": attempts, "fell_off": fell_off, "fault": str(e)}
        if result is None:
            end = "no_feasible_grasp"
            break
        fell_off += cell.remove_fallen()
        success = result["outcome"] == "success"
        attempts.append({"rank": rank, "grasps_detected": len(grasps), "skipped_infeasible": len(rejected),
                         **result, "success": success})
        failures = 0 if success else failures + 1
    record = {"end": end, "attempts": attempts, "fell_off": fell_off}
    if end == "no_feasible_grasp":  # why the cell would start none of the last detection's grasps
        record["refused"] = {"grasps": len(rejected), "first": [r[:200] for r in rejected[:MAX_REFUSALS_KEPT]]}
    return record


def grasp_fields(grasp) -> dict:
    """What an attempt record keeps of the grasp it executed (a detection.Grasp): score_n,
    the gravity-rejection score in N (None for a model without one: a binary model, VGN;
    records never hold a probability under a newton's name), validness, and rank_key, what
    the method ranked its grasps by (score_n, validness or validness x score_n). Records
    before these fields (schema 1) hold one `score`: report.attempt_scores reads both."""
    score_n = float(grasp.score_n)
    return {"score_n": None if math.isnan(score_n) else round(score_n, 4),
            "validness": round(float(grasp.validness), 4), "rank_key": round(float(grasp.rank_key), 4)}


def success_rates(successes: int, attempts: int, objects: int, empty: float = math.nan) -> tuple:
    """(SR, CR): SR = successes / attempts, CR = successes / objects (cleared of those
    on the table); `empty` where there is nothing to divide by (nan for the benchmark's
    pooled statistics)."""
    return (successes / attempts if attempts else empty, successes / objects if objects else empty)
