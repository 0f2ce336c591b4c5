"""Why does Ours lose attempts before the lift that Binary does not? (issue 42, item 1)

Every before-the-lift failure of the chosen methods in committed benchmark rounds
(`FAILURES`: report.outcome_class's no_object, timeout (the fingers never stopped
closing), jammed_on_approach, lift_blocked, and a round that ended with every detected
grasp refused by the executor, `all_refused`) is replayed to the view it was picked in
and diagnosed there (analysis.pick_diagnosis): where the pick's TCP sat against the
observed surface (inside / band / free / unobserved), whether VGN's mask keeps it, how
far the open hand's approach gets before it meets a true object or the table, its
validness, score and mode, and what the comparison methods (`COMPARE`: Binary for Ours,
Ours for Binary; Ours ranked by validness x score) pick first in the same view (the first
of their grasps the executor would start).

A replay is trusted only while it repeats the round: the rounds ran on a Xeon and may
diverge on another CPU (doc/benchmark-speed.md). An attempt is diagnosed only when its
replayed pose equals the recorded one; the replay stops at the first attempt whose pose
or outcome differs, and every failure after that is counted as not diagnosed. A refused
round end is diagnosed (its final view's top grasp) only when the whole round repeated.

    python -m sim_bridge.studies.before_lift_diagnosis --results sim_bridge/results/heldout_v4 \\
        --methods ours,binary --weights 0.1,0.5,1.5 --out sim_bridge/results/before_lift_diagnosis
    python -m sim_bridge.studies.before_lift_diagnosis --out sim_bridge/results/before_lift_diagnosis --report

One JSON line per round in --out/rounds.jsonl, by results, method, weight and scene (a
rerun skips those there); --report prints the Markdown table, the summary by surface class and
by lever (LEVERS: the rule each applies), and last `diagnosed=N of M`. The replay needs
the rounds' model files (their sha256 is checked; --model NAME=PATH for another copy).
"""

from __future__ import annotations

import argparse
import collections
import pathlib
import re
import sys
import time

import numpy as np

from ..analysis import pick_diagnosis
from ..analysis.replay import SurfaceSamples, closing_region_contents, rebuild_cell, recorded_round
from ..benchmark import run_files
from ..benchmark.clearing import clear_table
from ..benchmark.clutter_benchmark import parse_weights
from ..benchmark.methods import METHODS
from ..benchmark.methods.vgn import FINGER_BASE_Z_M
from ..benchmark.protocol import weight_key
from ..benchmark.report import attempt_scores, outcome_class
from ..physics.scenes import TABLE_HEIGHT_M
from . import detection_levers  # noqa: F401  (registers the lever methods: rounds name them)

FAILURES = ("no_object", "timeout", "jammed_on_approach", "lift_blocked", "all_refused")
# whom each method's picks are compared with in the same view
COMPARE = {"ours": ("binary", "ours_expected"), "binary": ("ours",)}
OTHER_HEADER = "the other's pick (Binary's for Ours, Ours' for Binary)"
VALIDNESS_FLOOR = 0.9  # Binary's picks: median validness 0.97; Ours' 0.84-0.90
GUARDED_WITHIN_M = 0.01  # the guarded approach's setting in heldout_v4_guarded
# lever -> (what it changes, the rule by which it could address a diagnosed failure)
LEVERS = {
    "guarded approach": ("execution", "the arm's contact stop halted the approach (jammed_on_approach), or "
                                      "the approach meets something (first contact), at most "
                                      f"{GUARDED_WITHIN_M * 1e3:.0f} mm short of the grasp pose"),
    "VGN mask": ("selection", "VGN's mask drops the pick's TCP voxel (inside, or not within 2 dilations of "
                              "observed free space)"),
    "VGN mask at the base": ("selection", "VGN's mask drops the point where VGN's TCP would sit, 5 cm behind "
                                          "the finger tips on the pick's approach"),
    "validness floor": ("selection", f"the pick's validness is below {VALIDNESS_FLOOR}"),
    "validness x score": ("selection", "Ours ranked by validness x score picks another grasp in the same view"),
    "inside negatives": ("training", "the pick's TCP is inside or unobserved (behind the observed surface)"),
    "empty-close negatives": ("training", "closed on nothing (no_object, timeout) with no true object in "
                                          "the closing region"),
    "label-time clearance": ("training", "all_refused, or the approach meets something before the grasp pose"),
}
STOP_WORDS = re.compile(r"stopped by contact after ([0-9.]+) of ([0-9.]+) m")


class _Enough(Exception):
    """Raised from the wrapped execute once the replay has what it needs (or diverged)."""


def find_failures(record: dict) -> list:
    """[(attempt number, outcome class)] of the before-the-lift failures of a round record;
    a round that ended with every grasp refused adds (len(attempts) + 1, "all_refused")."""
    found = [(n, outcome_class(a)) for n, a in enumerate(record["attempts"], 1)]
    found = [(n, c) for n, c in found if c in FAILURES]
    if record["end"] == "no_feasible_grasp":
        found.append((len(record["attempts"]) + 1, "all_refused"))
    return found


def _pick(grasp) -> dict:
    return {"pose": np.asarray(grasp.pose).round(6).tolist(), "validness": round(float(grasp.validness), 4),
            "score_n": None if not np.isfinite(grasp.score_n) else round(float(grasp.score_n), 4)}


def _first_feasible(cell, grasps, tsdf):
    for rank, g in enumerate(grasps):
        if not cell.feasible(g, tsdf):
            return rank, g
    return None, None


def diagnose_view(cell, view_state, grasp, compare: dict, mask=None) -> dict:
    """The diagnosis of `grasp` in the view it was picked from (view_state: tsdf, grasps,
    View, object samples), and the comparison methods' first feasible picks there."""
    tsdf, _, view, points = view_state
    approach_m = cell.limits.pregrasp_distance_m
    mask = pick_diagnosis.vgn_mask(view.grid) if mask is None else mask
    X = np.asarray(grasp.pose)
    d = pick_diagnosis.diagnose_pick(view, X, approach_m, cell.limits.hand, points, TABLE_HEIGHT_M, mask)
    d["truth_in_closing_region"] = {n: v["samples"] for n, v in
                                    closing_region_contents(X, tsdf, points)["objects"].items()}
    others = {}
    for name, detect in compare.items():
        rank, g = _first_feasible(cell, detect(tsdf), tsdf)
        if g is None:
            others[name] = None
            continue
        Xo = np.asarray(g.pose)
        od = pick_diagnosis.diagnose_pick(view, Xo, approach_m, cell.limits.hand, points, TABLE_HEIGHT_M, mask)
        others[name] = {"rank": rank, **_pick(g), "same": pick_diagnosis.same_pick(X, Xo),
                        **{k: od[k] for k in ("tcp_class", "vgn_keeps", "first_contact")}}
    d["compare"] = others
    return d


def diagnose_round(results_dir, method, mass_kg, scene_id, model_paths: dict) -> dict:
    """Replay one committed round up to its last before-the-lift failure and diagnose
    each failure (module doc). model_paths: {method: file} for the round's method and its
    COMPARE methods. -> the round's diagnosis record."""
    t0 = time.process_time()
    results_dir = pathlib.Path(results_dir)
    recorded = recorded_round(results_dir, method, mass_kg, scene_id)
    failures = find_failures(recorded)
    out = {"results": results_dir.name, "method": method, "mass_kg": mass_kg, "scene_id": scene_id,
           "model_sha256": recorded["model_sha256"], "end": recorded["end"], "failures": [], "successes": []}
    if not failures:
        return {**out, "replayed": 0, "diverged_at": None, "cpu_s": 0.0}
    cell, protocol = rebuild_cell(results_dir, recorded, model_paths[method])
    # the comparison methods' detectors, as the benchmark makes them (a volume each, unused)
    compare = {name: METHODS[name].make(model_paths[name], protocol).detect
               for name in COMPARE.get(method, ()) if name in model_paths}
    wanted = {n: c for n, c in failures}
    last = max(n for n, _ in failures if n <= len(recorded["attempts"])) if any(
        n <= len(recorded["attempts"]) for n, _ in failures) else None
    samples, state, done = SurfaceSamples(cell.world, pick_diagnosis.sample_surface), {}, []
    detect, execute = cell.detect, cell.execute

    def observed_detect():
        tsdf, grasps = detect()
        view = pick_diagnosis.View(*cell.volume.tsdf_and_weights(), tsdf[1], np.asarray(tsdf[2]))
        if not np.array_equal(view.grid, tsdf[0]):
            raise RuntimeError("the volume no longer holds the view the detector read")
        state["view"] = (tsdf, grasps, view, samples.now())
        return tsdf, grasps

    def observed_execute(grasp, tsdf):
        result = execute(grasp, tsdf)  # Refused propagates: clear_table tries the next grasp
        n = len(done) + 1
        if n > len(recorded["attempts"]):  # the round went on where the record ended: diverged
            done.append(False)
            raise _Enough
        rec = recorded["attempts"][n - 1]
        same_pose = np.allclose(rec["pose"], result["pose"], atol=2e-6)
        same = same_pose and rec["outcome"] == result["outcome"]
        done.append(same)
        view = state["view"]
        if n in wanted:
            entry = {"attempt": n, "outcome": wanted[n], "reason": rec["reason"], "rank": rec["rank"],
                     "mode": rec.get("mode", ""), **attempt_scores(rec, recorded["target"]),
                     "replayed_outcome": result["outcome"], "same_pose": bool(same_pose)}
            if same_pose:
                entry["diagnosis"] = diagnose_view(cell, view, grasp, compare)
            out["failures"].append(entry)
        elif same_pose and rec["outcome"] == "success":
            # where the picks that worked sat: what a selection lever would also take away
            X = np.asarray(grasp.pose)
            mask = pick_diagnosis.vgn_mask(view[2].grid)
            out["successes"].append({
                "attempt": n, "validness": rec["validness"],
                "tcp_class": str(pick_diagnosis.surface_class(view[2], X[:3, 3])[0]),
                "vgn_keeps": pick_diagnosis.vgn_keeps(view[2], X[:3, 3], mask),
                "vgn_keeps_base": pick_diagnosis.vgn_keeps(view[2], X[:3, 3] + FINGER_BASE_Z_M * X[:3, 2], mask)})
        if not same or (n >= (last or 0) and "all_refused" not in wanted.values()):
            raise _Enough
        return result

    cell.detect, cell.execute = observed_detect, observed_execute
    cell.settle()
    cell.remove_fallen()
    try:
        ended = clear_table(cell, len(cell.objects_on_table()), protocol.attempts_per_object)["end"]
    except _Enough:
        ended = None
    diverged = next((n for n, ok in enumerate(done, 1) if not ok), None)
    if "all_refused" in wanted.values():
        n = len(recorded["attempts"]) + 1
        entry = {"attempt": n, "outcome": "all_refused", "reason": recorded.get("refused", {}).get("first", [""])[0],
                 "rank": 0, "mode": "", "replayed_outcome": ended or "", "same_pose": False}
        if ended == "no_feasible_grasp" and diverged is None and len(done) == len(recorded["attempts"]):
            tsdf, grasps, _, _ = state["view"]
            top = grasps[0]
            entry.update(same_pose=True, validness=round(float(top.validness), 4),
                         score_n=round(float(top.score_n), 4) if np.isfinite(top.score_n) else None,
                         refused_because=cell.feasible(top, tsdf)[:200],
                         diagnosis=diagnose_view(cell, state["view"], top, compare))
        out["failures"].append(entry)
    # failures the replay never reached (it diverged before them)
    reached = {f["attempt"] for f in out["failures"]}
    for n, c in failures:
        if n not in reached:
            rec = recorded["attempts"][n - 1]
            out["failures"].append({"attempt": n, "outcome": c, "reason": rec["reason"], "rank": rec["rank"],
                                    "mode": rec.get("mode", ""), **attempt_scores(rec, recorded["target"]),
                                    "replayed_outcome": "", "same_pose": False})
    out["failures"].sort(key=lambda f: f["attempt"])
    return {**out, "replayed": len(done), "diverged_at": diverged, "cpu_s": round(time.process_time() - t0, 1)}


# the report


def recorded_stop_m(reason: str):
    """How far the arm's contact stop let the approach get, from the executor's words
    ("stopped by contact after 0.038 of 0.050 m"); None if it did not stop."""
    m = STOP_WORDS.search(reason or "")
    return (float(m.group(1)), float(m.group(2))) if m else None


def levers_of(failure: dict) -> list:
    """The levers (LEVERS) that could address a diagnosed failure, by their rules."""
    d, out = failure["diagnosis"], []
    contact = d["first_contact"]
    stop = recorded_stop_m(failure["reason"]) if failure["outcome"] == "jammed_on_approach" else None
    short_m = (stop[1] - stop[0]) if stop else (contact["short_m"] if contact else None)
    if short_m is not None and 0 < short_m <= GUARDED_WITHIN_M:
        out.append("guarded approach")
    if not d["vgn_keeps"]:
        out.append("VGN mask")
    if not d["vgn_keeps_base"]:
        out.append("VGN mask at the base")
    if failure.get("validness") is not None and failure["validness"] < VALIDNESS_FLOOR:
        out.append("validness floor")
    other = d["compare"].get("ours_expected")
    if other is not None and not other["same"]:
        out.append("validness x score")
    if d["tcp_class"] in ("inside", "unobserved"):
        out.append("inside negatives")
    if failure["outcome"] in ("no_object", "timeout") and not d["truth_in_closing_region"]:
        out.append("empty-close negatives")
    if failure["outcome"] == "all_refused" or (contact and contact["short_m"] > 0):
        out.append("label-time clearance")
    return out


def _score_n(failure):
    """Its score in N (None: a binary model's); outputs written before score_n say `score`."""
    return failure.get("score_n", failure.get("score"))


def _fmt(v, digits=2):
    return "–" if v is None else f"{v:.{digits}f}"


def _contact(f, d):
    c, stop = d["first_contact"], recorded_stop_m(f["reason"])
    text = "clear" if c is None else f"{c['approach_m'] * 1e3:.0f} mm ({c['what'][:14]}, {c['part']})"
    return text + (f"; arm stopped at {stop[0] * 1e3:.0f} mm" if stop else "")


def _other(o):
    if o is None:
        return "none feasible"
    return (f"{'same' if o['same'] else 'other'}: {o['tcp_class']}, v {o['validness']:.2f}, "
            f"{'clear' if o['first_contact'] is None else 'contact'}")


def _other_cell(d, name):
    return _other(d["compare"][name]) if name in d["compare"] else ""


def report_lines(records: list) -> list:
    rows, lines = [], ["| method | kg | scene | att. | outcome | TCP | to surface | first contact (approach "
                       f"from the pre-grasp) | validness | score | mode | {OTHER_HEADER} | v x s pick | levers |",
                       "|" + "---|" * 14]
    for r in sorted(records, key=lambda r: (r["results"], r["method"], r["mass_kg"], r["scene_id"])):
        for f in r["failures"]:
            d = f.get("diagnosis")
            rows.append((r, f))
            if d is None:
                lines.append(f"| {r['method']} | {r['mass_kg']} | {r['scene_id']} | {f['attempt']} | {f['outcome']} | "
                             "not diagnosed (replay diverged) | | | "
                             f"{_fmt(f.get('validness'))} | {_fmt(_score_n(f), 1)} | {f['mode']} | | | |")
                continue
            lines.append(f"| {r['method']} | {r['mass_kg']} | {r['scene_id']} | {f['attempt']} | {f['outcome']} | "
                         f"{d['tcp_class']}{'' if d['vgn_keeps'] else ' (VGN drops)'}"
                         f"{'' if d['vgn_keeps_base'] else ' (VGN drops base)'} | "
                         f"{d['surface_distance_mm']:.0f} mm | {_contact(f, d)} | "
                         f"{_fmt(f.get('validness'))} | {_fmt(_score_n(f), 1)} | {f['mode']} | "
                         f"{_other_cell(d, next(iter(d['compare']), None))} | {_other_cell(d, 'ours_expected')} | "
                         f"{', '.join(levers_of(f))} |")
    diagnosed = [(r, f) for r, f in rows if "diagnosis" in f]
    lines += ["", "Diagnosed failures by method: where the pick's TCP sat, and the levers that could address "
                  "them (a failure can count for several):", ""]
    by_method = collections.defaultdict(list)
    for r, f in diagnosed:
        by_method[r["method"]].append(f)
    for method, fs in sorted(by_method.items()):
        classes = collections.Counter(f["diagnosis"]["tcp_class"] for f in fs)
        levers = collections.Counter(lv for f in fs for lv in levers_of(f))
        lines.append(f"- {method} ({len(fs)}): " + ", ".join(f"{c} {classes[c]}" for c in pick_diagnosis.SURFACE_CLASSES)
                     + "; " + ", ".join(f"{lv} {levers[lv]}/{len(fs)}" for lv in LEVERS))
    succ = collections.defaultdict(list)
    for r in records:
        succ[r["method"]] += r["successes"]
    for method, ss in sorted(succ.items()):
        if ss:
            dropped = sum(not s["vgn_keeps"] for s in ss)
            dropped_base = sum(not s["vgn_keeps_base"] for s in ss)
            low = sum(s["validness"] < VALIDNESS_FLOOR for s in ss)
            classes = collections.Counter(s["tcp_class"] for s in ss)
            lines.append(f"- {method}, replayed successes ({len(ss)}, what a selection lever would also cost): "
                         + ", ".join(f"{c} {classes[c]}" for c in pick_diagnosis.SURFACE_CLASSES)
                         + f"; VGN's mask would drop {dropped} (at the base {dropped_base}), "
                         f"the validness floor {low}")
    lines += ["", "Levers and their rules:", ""] + [f"- {k} ({kind}): {rule}" for k, (kind, rule) in LEVERS.items()]
    cpu = [r["cpu_s"] for r in records if r["replayed"]]
    if cpu:
        lines.append(f"\nCPU per replayed round: mean {np.mean(cpu):.0f} s, max {max(cpu):.0f} s ({len(cpu)} rounds)")
    lines.append(f"diagnosed={len(diagnosed)} of {len(rows)}")
    return lines


# the command


STUDY_KEY = ("results", "method", "mass_kg", "scene_id")  # a study record: which run's round it looked at


def benchmark_rounds(results_dir, methods, weights, scenes=()):
    """(method, kg, round record) of a benchmark run's rounds, only of `scenes` where given;
    ValueError where a method has no rounds at a weight."""
    ran = run_files.rounds_file(results_dir).records()
    for method in methods:
        for kg in weights:
            found = [r for r in ran if r["method"] == method and float(r["mass_kg"]) == float(kg)]
            if not found:
                raise ValueError(f"no rounds of {method} at {weight_key(kg)} kg in {results_dir}")
            for r in found:
                if not scenes or r["scene_id"] in scenes:
                    yield method, kg, r


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("--results", action="append", help="a benchmark output directory (repeat for several); "
                   "default sim_bridge/results/heldout_v4")
    p.add_argument("--methods", default="ours,binary")
    p.add_argument("--weights", default="0.1,0.5,1.5", help="kg, comma-separated")
    p.add_argument("--scenes", default="", help="only these scene ids, comma-separated")
    p.add_argument("--max-rounds", type=int, help="stop after this many rounds with a failure (a sample)")
    p.add_argument("--model", action="append", default=[], help="NAME=PATH: the file a method's rounds ran")
    p.add_argument("--out", required=True)
    p.add_argument("--report", action="store_true", help="print the table of what --out holds, run nothing")
    args = p.parse_args(argv)
    out = pathlib.Path(args.out)
    if args.report:
        records = run_files.study_rounds_file(out, STUDY_KEY).records()
        if not records:
            print(f"before_lift_diagnosis: no rounds in {out}: run without --report first", file=sys.stderr)
            return 2
        print("\n".join(report_lines(records)))
        return 0
    try:
        methods = [m for m in args.methods.split(",") if m]
        unknown = [m for m in methods if m not in METHODS]
        if unknown:
            raise ValueError(f"unknown methods {unknown}: use names of benchmark.methods.METHODS")
        paths = {name: METHODS[name].default_path() for name in {*methods, *(c for m in methods
                                                                           for c in COMPARE.get(m, ()))}}
        for item in args.model:
            name, _, path = item.partition("=")
            if not path:
                raise ValueError(f"--model {item!r}: give NAME=PATH")
            paths[name] = pathlib.Path(path)
        missing = [f"{n}: {p}" for n, p in paths.items() if not pathlib.Path(p).is_file()]
        if missing:
            raise ValueError(f"model files not found ({', '.join(missing)}): pass --model NAME=PATH")
        weights = parse_weights(args.weights)
        scenes = {s for s in args.scenes.split(",") if s}
        rounds = 0
        done = run_files.study_rounds_file(out, STUDY_KEY)
        for results in args.results or ["sim_bridge/results/heldout_v4"]:
            for method, kg, recorded in benchmark_rounds(results, methods, weights, scenes):
                if not find_failures(recorded):
                    continue
                if args.max_rounds is not None and rounds >= args.max_rounds:
                    break
                rounds += 1
                sid = recorded["scene_id"]
                if done.get(pathlib.Path(results).name, method, kg, sid) is not None:
                    continue
                record = diagnose_round(results, method, kg, sid, paths)
                done.put(record)
                n = sum("diagnosis" in x for x in record["failures"])
                print(f"{pathlib.Path(results).name} {method} {weight_key(kg)} kg {sid}: {n} of "
                      f"{len(record['failures'])} failures diagnosed, "
                      f"replayed {record['replayed']} attempts in {record['cpu_s']} s CPU", flush=True)
    except ValueError as e:
        print(f"before_lift_diagnosis: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
