"""Where do a method's attempts lost before the lift fall? (issue 42)

Every attempt of a benchmark run (its attempts.json, written by `benchmark --report`) that
was lost before the lift (closed on nothing or stopped by the arm's contact limit:
report.outcome_class), split two ways:

- by the validness of the grasp it picked: when a method that ranks Binary's grasps another
  way (`binary_scored`: by Ours' score) loses more than Binary *in the same band*, its
  ranking, not the validness floor, chose worse places;
- by when in the round: a round's first attempt (the view a first-view screen such as
  studies.first_view_picks sees), a later one, and a later one at the place the attempt
  before it had just failed at (the scene unchanged, the detector picks it again).

    python -m sim_bridge.studies.before_lift_split sim_bridge/results/heldout_v4_decisive \\
        --methods binary_scored,binary [--bands 0.9,0.95,0.97,0.99]

Prints two Markdown tables and last `lost_before_lift_<method>_<low>_<high>=` lines for the
band from the first edge to the second, the band a validness floor at the first edge admits
first.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from ..analysis.run_vs_run import load_rounds
from ..benchmark.report import ATTEMPT_LOSSES, outcome_class

BANDS = (0.9, 0.95, 0.97, 0.99)
SAME_PLACE_M = 0.01  # a repeat: the TCP within this of the attempt before it


def lost_before_lift(attempt: dict) -> bool:
    return outcome_class(attempt) in ATTEMPT_LOSSES


def _share(lost: int, n: int) -> str:
    return f"{lost} / {n} ({100 * lost / n:.0f} %)" if n else "—"


def band_counts(rounds: list, methods, edges=BANDS) -> dict:
    """{method: [(low, high, lost before the lift, attempts)]} over the bands cut at `edges`
    (below the first, then between edges, then from the last to 1 inclusive)."""
    bounds = [(0.0, edges[0]), *zip(edges, edges[1:]), (edges[-1], 1.0)]
    out = {}
    for method in methods:
        attempts = [a for r in rounds if r["method"] == method for a in r["attempts"]]
        rows = []
        for i, (low, high) in enumerate(bounds):
            last = i == len(bounds) - 1
            inside = [a for a in attempts if low <= a["validness"] < high or (last and a["validness"] == high)]
            rows.append((low, high, sum(map(lost_before_lift, inside)), len(inside)))
        out[method] = rows
    return out


def position_counts(rounds: list, methods) -> dict:
    """{method: {first: (lost, attempts), later: (lost, attempts), repeats: lost}}: a round's
    first attempt against its later ones; repeats, the later losses at the place (TCP within
    SAME_PLACE_M) of an attempt just lost before the lift."""
    out = {}
    for method in methods:
        first, later, repeats = [0, 0], [0, 0], 0
        for r in (r for r in rounds if r["method"] == method):
            attempts = sorted(r["attempts"], key=lambda a: a.get("attempt", 0))
            for i, a in enumerate(attempts):
                tally = first if i == 0 else later
                tally[0] += lost_before_lift(a)
                tally[1] += 1
                if i and lost_before_lift(a) and lost_before_lift(attempts[i - 1]):
                    step = np.asarray(a["pose"])[:3, 3] - np.asarray(attempts[i - 1]["pose"])[:3, 3]
                    repeats += bool(np.linalg.norm(step) < SAME_PLACE_M)
        out[method] = {"first": tuple(first), "later": tuple(later), "repeats": repeats}
    return out


def position_lines(counts: dict) -> list:
    return ["| method | first attempt of a round | later attempts | of those, where the attempt before had just failed |",
            "| --- | --- | --- | --- |"] + [
        f"| {m} | {_share(*c['first'])} | {_share(*c['later'])} | {c['repeats']} |" for m, c in counts.items()]


def table_lines(counts: dict) -> list:
    bands = next(iter(counts.values()))
    lines = ["| method | " + " | ".join(f"validness {lo:g}–{hi:g}" for lo, hi, *_ in bands) + " |",
             "|" + " --- |" * (len(bands) + 1)]
    for method, rows in counts.items():
        lines.append(f"| {method} | " + " | ".join(_share(lost, n) for *_, lost, n in rows) + " |")
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run", help="a benchmark run's --out, after its --report")
    p.add_argument("--methods", default="binary_scored,binary", help="comma-separated (default binary_scored,binary)")
    p.add_argument("--bands", default=",".join(f"{e:g}" for e in BANDS), help="increasing validness edges in (0, 1)")
    args = p.parse_args(argv)
    try:
        edges = tuple(float(e) for e in args.bands.split(","))
    except ValueError:
        edges = ()
    if not edges or any(not 0 < e < 1 for e in edges) or list(edges) != sorted(set(edges)):
        print(f"before_lift_split: --bands {args.bands}: give increasing validness edges between 0 and 1, "
              "e.g. 0.9,0.95,0.97,0.99", file=sys.stderr)
        return 2
    methods = [m for m in args.methods.split(",") if m]
    try:
        rounds = load_rounds(args.run)
    except (ValueError, OSError, json.JSONDecodeError) as e:
        print(f"before_lift_split: {e}", file=sys.stderr)
        return 2
    missing = [m for m in methods if not any(r["method"] == m for r in rounds)]
    if missing:
        print(f"before_lift_split: no rounds of {', '.join(missing)} in {args.run}'s attempts.json: run its --report "
              "with them in --methods", file=sys.stderr)
        return 2
    counts = band_counts(rounds, methods, edges)
    print("Attempts lost before the lift (closed on nothing, contact stops) / attempts, by the picked grasp's "
          "validness:\n")
    print("\n".join(table_lines(counts)))
    print("\nThe same losses by when in the round:\n")
    print("\n".join(position_lines(position_counts(rounds, methods))))
    low, high = edges[0], edges[1] if len(edges) > 1 else 1.0
    for method, rows in counts.items():
        lost, n = next((lost, n) for lo, hi, lost, n in rows if (lo, hi) == (low, high))
        print(f"lost_before_lift_{method}_{low:g}_{high:g}={lost}/{n}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
