"""What predicted score does an executed grasp need to hold m kg? (issue 42, the payload floor)

`score_calibration` compares the network's score with the simulated labels; executed
grasps hold less than their labels (label_execution_study). This study asks the benchmark's
own attempts instead. From committed benchmark rounds of one model file (its sha256 in each
round), every attempt that got the object into the closed hand and started the lift
("placed": success, or dropped in the lift, the hold or the shake) is a sample of

    P(held | placed, predicted score s [N], weight m g [N]) = sigmoid(a + b s + c m g)

fitted by logistic regression; the score a grasp needs for P = p at mass m is then
(logit p - a - c m g) / b: an offset plus (c / b) newtons of score per newton of weight,
which is what `detection.payload_min_score_n` would take instead of a bare factor. Beside
it, what placement itself depends on: the fraction of all attempts placed per validness bin.

The picks are those the methods chose (mostly high scores), so the fit describes the range
they cover, not the whole score head. A round copied into several result directories by
`analysis.paired_run` counts once. Tune only on tuning rounds (the held-out meshes listed in
models/vgn_heldout_meshes.txt, procedural seed 1000).

    python -m sim_bridge.studies.executed_score_calibration --model models/gravgrasp.pt \
        --results sim_bridge/results/heldout_v4 --results sim_bridge/results/procedural_v4 ... \
        --out sim_bridge/results/executed_score_calibration.json

Prints the tables and, last, `score_for_hold_<p>_at_<m>kg_n=`.
"""
from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys

import numpy as np

from gravgrasp_detector import atomic_files
from gravgrasp_detector.perception.model_file import file_sha256

from ..benchmark import run_files
from ..benchmark.report import AFTER_LIFT, attempt_scores, outcome_class, wilson_interval

G_MPS2 = 9.81
PLACED = ("success", *AFTER_LIFT)
SCORE_BINS_N = (0.0, 30.0, 40.0, 50.0, 60.0, 80.0, math.inf)
VALIDNESS_BINS = (0.0, 0.7, 0.8, 0.9, 0.95, 0.98, 1.0 + 1e-9)
HOLD_LEVELS = (0.8, 0.9)
REPORT_MASSES_KG = (0.1, 0.5, 1.5, 2.5, 4.0)
BOOTSTRAP_DRAWS = 1000
SEED = 0
RIDGE = 1e-6  # keeps Newton's step defined on separable data


def load_attempts(results_dirs, model_sha256: str) -> list:
    """One row per attempt of every round run with that model file: {round, mass_kg,
    score_n, validness, outcome}. Rounds copied between directories count once."""
    rows, seen = [], set()
    for d in results_dirs:
        ran = run_files.rounds_file(d)
        if not len(ran):
            raise ValueError(f"{d} has no rounds: give a benchmark output directory (--out of the benchmark)")
        for r in ran.records():
            if r.get("model_sha256") != model_sha256 or "attempts" not in r:
                continue
            key = (r["scene_id"], r["method"], float(r["mass_kg"]), json.dumps(r["attempts"], sort_keys=True))
            if key in seen:
                continue
            seen.add(key)
            for a in r["attempts"]:
                s = attempt_scores(a, r.get("target", "score"))
                rows.append({"round": len(seen) - 1, "mass_kg": float(r["mass_kg"]), "score_n": s["score_n"],
                             "validness": s["validness"], "outcome": outcome_class(a)})
    return rows


def fit_logistic(X, y, iterations: int = 100) -> np.ndarray:
    """Weights w (intercept first) of P(y) = sigmoid(w0 + X w[1:]), by Newton's method."""
    X = np.c_[np.ones(len(X)), np.asarray(X, float)]
    y = np.asarray(y, float)
    w = np.zeros(X.shape[1])
    for _ in range(iterations):
        p = 1.0 / (1.0 + np.exp(-(X @ w)))
        hessian = (X * (p * (1 - p))[:, None]).T @ X + RIDGE * np.eye(len(w))
        step = np.linalg.solve(hessian, X.T @ (p - y) + RIDGE * w)
        w -= step
        if np.max(np.abs(step)) < 1e-10:
            break
    return w


def score_needed_n(w, hold_p: float, mass_kg: float) -> float:
    """The predicted score [N] at which the fit gives P(held | placed) = hold_p at mass_kg."""
    a, b, c = w
    if b <= 0:
        return math.nan  # the score does not help: no score is enough
    return (math.log(hold_p / (1 - hold_p)) - a - c * mass_kg * G_MPS2) / b


def placed_rows(rows) -> list:
    return [r for r in rows if r["outcome"] in PLACED and r["score_n"] is not None]


def hold_fit(rows) -> np.ndarray:
    placed = placed_rows(rows)
    if len({r["outcome"] == "success" for r in placed}) < 2 or len({r["mass_kg"] for r in placed}) < 2:
        raise ValueError(f"{len(placed)} placed attempts: the fit needs held and dropped ones at two weights or more")
    X = [[r["score_n"], r["mass_kg"] * G_MPS2] for r in placed]
    return fit_logistic(X, [r["outcome"] == "success" for r in placed])


def bootstrap_needed(rows, hold_p: float, mass_kg: float, draws: int = BOOTSTRAP_DRAWS) -> tuple:
    """95 % interval of score_needed_n, resampling whole rounds (their attempts are not independent)."""
    rng = np.random.default_rng(SEED)
    by_round = {}
    for r in rows:
        by_round.setdefault(r["round"], []).append(r)
    rounds = list(by_round.values())
    values = []
    for _ in range(draws):
        sample = [r for i in rng.integers(0, len(rounds), len(rounds)) for r in rounds[i]]
        try:
            values.append(score_needed_n(hold_fit(sample), hold_p, mass_kg))
        except (ValueError, np.linalg.LinAlgError):
            continue
    values = np.array([v for v in values if math.isfinite(v)])
    return tuple(np.percentile(values, [2.5, 97.5])) if values.size else (math.nan, math.nan)


def binned(values, flags, edges) -> list:
    """[(lo, hi, n, fraction true, wilson interval)] of flags over bins of values."""
    values, flags = np.asarray(values, float), np.asarray(flags, bool)
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (values >= lo) & (values < hi)
        n, k = int(sel.sum()), int(flags[sel].sum())
        if n:
            out.append((lo, hi, n, k / n, wilson_interval(k, n)))
    return out


def study(rows) -> dict:
    placed = placed_rows(rows)
    w = hold_fit(rows)
    needed = {f"{p}": {f"{m}": score_needed_n(w, p, m) for m in REPORT_MASSES_KG} for p in HOLD_LEVELS}
    hold_table = {}
    for m in sorted({r["mass_kg"] for r in placed}):
        at = [r for r in placed if r["mass_kg"] == m]
        hold_table[f"{m}"] = binned([r["score_n"] for r in at], [r["outcome"] == "success" for r in at], SCORE_BINS_N)
    judged = [r for r in rows if r["validness"] is not None]
    placement = binned([r["validness"] for r in judged], [r["outcome"] in PLACED for r in judged], VALIDNESS_BINS)
    return {"attempts": len(rows), "placed": len(placed), "rounds": len({r["round"] for r in rows}),
            "hold_fit": {"intercept": w[0], "per_score_n": w[1], "per_weight_n": w[2]},
            "score_per_weight_n": -w[2] / w[1] if w[1] > 0 else math.nan,
            "score_needed_n": needed, "hold_by_score": hold_table, "placed_by_validness": placement}


def report_lines(result: dict, interval=None) -> list:
    f = result["hold_fit"]
    lines = [f"{result['attempts']} attempts in {result['rounds']} rounds, {result['placed']} placed "
             "(in the closed hand when the lift started)", "",
             f"P(held | placed) = sigmoid({f['intercept']:.3f} + {f['per_score_n']:.4f} s {f['per_weight_n']:+.4f} m g)"
             f": {result['score_per_weight_n']:.2f} N of predicted score per newton of weight", "",
             "| held, by predicted score | " + " | ".join(f"{m} kg" for m in result["hold_by_score"]) + " |",
             "| --- |" + " --- |" * len(result["hold_by_score"])]
    for lo, hi in zip(SCORE_BINS_N[:-1], SCORE_BINS_N[1:]):
        cells = []
        for rows in result["hold_by_score"].values():
            row = next((x for x in rows if x[0] == lo), None)
            cells.append(f"{row[3]:.2f} ({row[2]})" if row else "")
        lines.append(f"| {lo:.0f}-{hi:.0f} N | " + " | ".join(cells) + " |")
    lines += ["", "| score needed [N] | " + " | ".join(f"{m} kg" for m in REPORT_MASSES_KG) + " |",
              "| --- |" + " --- |" * len(REPORT_MASSES_KG)]
    for p, by_mass in result["score_needed_n"].items():
        lines.append(f"| P(held) = {p} | " + " | ".join(f"{v:.1f}" for v in by_mass.values()) + " |")
    if interval:
        lines.append(f"\n95 % interval (rounds resampled) at P = {interval['hold_p']}, {interval['mass_kg']} kg: "
                     f"{interval['low_n']:.1f}-{interval['high_n']:.1f} N")
    lines += ["", "| validness | attempts | placed |", "| --- | --- | --- |"]
    lines += [f"| {lo:.2f}-{min(hi, 1.0):.2f} | {n} | {frac:.2f} ({ci[0]:.2f}-{ci[1]:.2f}) |"
              for lo, hi, n, frac, ci in result["placed_by_validness"]]
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("--model", required=True, help="the model file whose rounds count (matched by sha256)")
    p.add_argument("--results", action="append", required=True, help="a benchmark output directory (repeat)")
    p.add_argument("--out", required=True, help="the JSON to write")
    p.add_argument("--hold", type=float, default=0.8, help="P(held) of the printed last line")
    p.add_argument("--mass", type=float, default=1.5, help="kg, of the printed last line")
    p.add_argument("--bootstrap-draws", type=int, default=BOOTSTRAP_DRAWS, help="resamples of its interval")
    args = p.parse_args(argv)
    model = pathlib.Path(args.model)
    if not model.is_file():
        print(f"executed_score_calibration: no model file {model}: give the .pt the rounds ran", file=sys.stderr)
        return 2
    if not 0 < args.hold < 1:
        print(f"executed_score_calibration: --hold {args.hold}: give a probability between 0 and 1", file=sys.stderr)
        return 2
    sha = file_sha256(model)
    try:
        rows = load_attempts(args.results, sha)
        result = study(rows)
    except ValueError as e:
        print(f"executed_score_calibration: {e}", file=sys.stderr)
        return 2
    low, high = bootstrap_needed(rows, args.hold, args.mass, args.bootstrap_draws)
    interval = {"hold_p": args.hold, "mass_kg": args.mass, "low_n": low, "high_n": high}
    f = result["hold_fit"]
    result["needed_at_last_line_n"] = score_needed_n((f["intercept"], f["per_score_n"], f["per_weight_n"]),
                                                     args.hold, args.mass)
    result.update(model=str(model), model_sha256=sha, results=args.results, interval=interval)
    atomic_files.save_json(pathlib.Path(args.out), result)
    print("\n".join(report_lines(result, interval)))
    print(f"score_for_hold_{args.hold}_at_{args.mass}kg_n={result['needed_at_last_line_n']:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
