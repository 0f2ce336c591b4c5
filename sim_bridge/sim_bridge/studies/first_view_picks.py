"""What would another selection have picked in the first view of committed benchmark
rounds, and would its approach meet something? A screen for issue 42's selection levers
before they cost benchmark rounds.

A round's first view needs no replay of attempts: the scene settles and the detector sees
it once. So, cheaply (seconds a round), each round's first view is rebuilt from its
committed scene, protocol and model file (sha256 checked), and its recorded first pick
(attempt 1: the grasp at its recorded rank, trusted only when the replayed pose equals the
recorded one to 2e-6) is diagnosed as before_lift_diagnosis does (analysis.pick_diagnosis:
where its TCP sat, whether VGN's mask keeps it at the TCP and where VGN's TCP would sit,
what its approach meets), beside the first feasible pick of each `--compare` selection in
the same view: the same pick or another, where it sits, whether its approach meets a true
object or the table before the grasp pose. A selection is one of VGN's masks
(detection_levers.VGN_MASKS, on the round's own model: the default) or a method of the
project's models (`binary_scored`, `ours`, ...: its own model file).

The first pick is all it sees: a failure later in a round happened in a view this does
not rebuild (before_lift_diagnosis replays those, at ~2 CPU-min a round), and "meets
something" is geometry, the open hand's bounding boxes against the true surfaces, not the
arm's 60 N contact stop: a pick that meets something may still be executed. It can miss
what matters: `binary_scored` passed it and then lost 32 of its 217 later attempts before the
lift against 2 of its 62 first ones (studies.before_lift_split; sim_bridge/doc/levers.md).

    python -m sim_bridge.studies.first_view_picks --results sim_bridge/results/heldout_v4 \\
        --weights 0.1,0.5,1.5 --out sim_bridge/results/free_space_mask_first_view   # and --method binary
    python -m sim_bridge.studies.first_view_picks --results sim_bridge/results/heldout_v4_decisive \\
        --method binary --weights 1.5 --compare binary_scored,ours --out sim_bridge/results/first_view_binary_scored
    python -m sim_bridge.studies.first_view_picks --out sim_bridge/results/free_space_mask_first_view --report

One JSON line per round in --out/rounds.jsonl, by results, method, weight and scene (a
rerun skips those there); --report prints the counts by the first attempt's outcome.
"""

from __future__ import annotations

import argparse
import collections
import pathlib
import sys
import time

import numpy as np

from ..analysis import pick_diagnosis
from ..analysis.replay import SurfaceSamples, rebuild_cell, recorded_round
from ..benchmark import run_files
from ..benchmark.clutter_benchmark import parse_weights
from ..benchmark.methods import METHODS
from ..benchmark.protocol import weight_key
from ..benchmark.report import outcome_class
from .before_lift_diagnosis import FAILURES, STUDY_KEY, benchmark_rounds, diagnose_view
from .detection_levers import VGN_MASKS, lever_detector

MASKS = tuple(VGN_MASKS)


def selections(names, model_path, protocol) -> dict:
    """{name: detect} of each selection (module doc): a mask on `model_path`, or a method's
    detector on its own model file."""
    out = {}
    for name in names:
        if name in MASKS:
            out[name] = lever_detector(model_path, protocol, restrict=VGN_MASKS[name]).detect
        else:
            out[name] = METHODS[name].make(METHODS[name].default_path(), protocol).detect
    return out


def check_selections(names) -> None:
    """ValueError naming what is wrong with a --compare list, before any round runs."""
    for name in names:
        if name in MASKS:
            continue
        if name not in METHODS or METHODS[name].hand != "2f85":
            raise ValueError(f"--compare {name!r}: use a mask ({', '.join(MASKS)}) or a method of the "
                             f"project's models (e.g. ours, binary_scored)")
        method = METHODS[name]
        for f in (method.default_path(), *(method.default_path().parent / c for c in method.companions)):
            if not f.is_file():
                raise ValueError(f"--compare {name}: model file {f} not found")


def first_view(results_dir, method, mass_kg, scene_id, model_path, compare=MASKS) -> dict:
    """The record of one round's first view (module doc); compare: the selections' names."""
    t0 = time.process_time()
    results_dir = pathlib.Path(results_dir)
    recorded = recorded_round(results_dir, method, mass_kg, scene_id)
    out = {"results": results_dir.name, "method": method, "mass_kg": mass_kg, "scene_id": scene_id}
    if not recorded["attempts"]:
        return {**out, "outcome": None, "cpu_s": 0.0}
    first = recorded["attempts"][0]
    out.update(outcome=outcome_class(first), validness=first["validness"], rank=first["rank"])
    cell, protocol = rebuild_cell(results_dir, recorded, model_path)
    compared = selections(compare, model_path, protocol)
    cell.settle()
    cell.remove_fallen()
    tsdf, grasps = cell.detect()
    view = pick_diagnosis.View(*cell.volume.tsdf_and_weights(), tsdf[1], np.asarray(tsdf[2]))
    rank = first["rank"]
    if rank >= len(grasps) or not np.allclose(grasps[rank].pose, first["pose"], atol=2e-6):
        return {**out, "same_pose": False, "cpu_s": round(time.process_time() - t0, 1)}
    state = (tsdf, grasps, view, SurfaceSamples(cell.world, pick_diagnosis.sample_surface).now())
    d = diagnose_view(cell, state, grasps[rank], compared)
    return {**out, "same_pose": True, "diagnosis": d, "detected": {m: len(f(tsdf)) for m, f in compared.items()},
            "cpu_s": round(time.process_time() - t0, 1)}


def _group(record) -> str:
    o = record["outcome"]
    return "success" if o == "success" else "before the lift" if o in FAILURES else "after the lift"


def _pick_words(pick) -> str:
    if pick is None:
        return "none feasible"
    if pick["same"]:
        return "the same"
    meets = "meets something" if pick["first_contact"] else "clear"
    return f"another ({pick['tcp_class']}, validness {pick['validness']:.2f}, {meets})"


def _selections(records) -> list:
    """The selections compared in these records: the masks in MASKS' order, then methods."""
    names = {m for r in records for m in r.get("detected", {})}
    return [m for m in MASKS if m in names] + sorted(names - set(MASKS))


def _label(name) -> str:
    return f"mask {name}" if name in MASKS else name


def _meets_line(method, records) -> str:
    """How many first picks of the recorded method and of each selection meet something on
    the approach: the screen's figure (each pick's own approach, a "same" one's too: "same"
    allows pick_diagnosis.SAME_PICK_M and _DEG)."""
    d = [r["diagnosis"] for r in records]
    words = [f"{method} (recorded) {sum(x['first_contact'] is not None for x in d)} of {len(d)}"]
    for name in _selections(records):
        picks = [x["compare"][name] for x in d]
        meets = sum(p["first_contact"] is not None for p in picks if p is not None)
        none = sum(p is None for p in picks)
        words.append(f"{name} {meets} of {len(d) - none}" + (f" (none feasible {none})" if none else ""))
    return "- first picks whose approach meets something: " + "; ".join(words)


def _risk_line(seen) -> str:
    """What meeting something meant for the recorded first picks: how many failed before the
    lift among those that met something and those that did not."""
    words = []
    for meets in (True, False):
        rs = [r for r in seen if (r["diagnosis"]["first_contact"] is not None) == meets]
        failed = sum(_group(r) == "before the lift" for r in rs)
        share = f" ({100 * failed / len(rs):.0f} %)" if rs else ""
        words.append(f"{'meeting something' if meets else 'meeting nothing'} {failed} of {len(rs)}{share}")
    return "recorded first picks that failed before the lift: " + ", ".join(words)


def report_lines(records: list) -> list:
    """Counts by the first attempt's outcome (success, failed before the lift, after it)."""
    lines = []
    seen = [r for r in records if r.get("same_pose")]
    for results, method in sorted({(r["results"], r["method"]) for r in records}):
        ours = [r for r in records if (r["results"], r["method"]) == (results, method)]
        lines.append(f"{results} {method}: {sum(r['outcome'] is not None for r in ours)} rounds, "
                     f"{sum(bool(r.get('same_pose')) for r in ours)} first views repeated")
        lines.append(_meets_line(method, [r for r in ours if r.get("same_pose")]))
        by = collections.defaultdict(list)
        for r in ours:
            if r.get("same_pose"):
                by[_group(r)].append(r)
        for group in ("success", "before the lift", "after the lift"):
            rs = by.get(group, [])
            if not rs:
                continue
            d = [r["diagnosis"] for r in rs]
            classes = collections.Counter(x["tcp_class"] for x in d)
            lines.append(f"- first attempt {group} ({len(rs)}): TCP " + ", ".join(
                f"{c} {classes[c]}" for c in pick_diagnosis.SURFACE_CLASSES)
                + f"; approach meets something {sum(x['first_contact'] is not None for x in d)}")
            for mask in _selections(rs):
                picks = [x["compare"][mask] for x in d]
                none = sum(p is None for p in picks)
                same = sum(p is not None and p["same"] for p in picks)
                other = [p for p in picks if p is not None and not p["same"]]
                lines.append(f"  - {_label(mask)}: drops the pick {len(rs) - same}"
                             f" (another pick {len(other)}, of which approach meets something "
                             f"{sum(p['first_contact'] is not None for p in other)}, validness median "
                             f"{np.median([p['validness'] for p in other]) if other else float('nan'):.2f}; "
                             f"none feasible {none}); keeps it {same}; grasps detected median "
                             f"{np.median([r['detected'][mask] for r in rs]):.0f}")
    failed = sorted((r for r in seen if _group(r) == "before the lift"),
                    key=lambda r: (r["results"], r["method"], r["mass_kg"], r["scene_id"]))
    if failed:
        lines.append("first picks that failed before the lift (its approach's first contact; each selection's pick):")
    for r in failed:
        d = r["diagnosis"]
        picks = "; ".join(f"{m}: {_pick_words(d['compare'][m])}" for m in _selections([r]))
        contact = d["first_contact"]
        lines.append(f"- {r['results']} {r['method']} {r['mass_kg']} kg {r['scene_id']}: {r['outcome']}, "
                     f"TCP {d['tcp_class']}, "
                     f"validness {r['validness']:.2f}, meets {contact['what'] if contact else 'nothing'}; {picks}")
    lines.append(_risk_line(seen))
    cpu = [r["cpu_s"] for r in records if r.get("same_pose") is not None]
    if cpu:
        lines.append(f"CPU per round: mean {np.mean(cpu):.1f} s, total {sum(cpu):.0f} s ({len(cpu)} rounds)")
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("--results", action="append", help="a benchmark output directory (repeat for several); "
                   "default sim_bridge/results/heldout_v4")
    p.add_argument("--method", default="ours", help="a method of the project's models (its rounds are read)")
    p.add_argument("--weights", default="0.1,0.5,1.5", help="kg, comma-separated")
    p.add_argument("--model", help="the file the method's rounds ran (default: the method's)")
    p.add_argument("--compare", default=",".join(MASKS), help="selections to pick in the same view, comma-separated: "
                   "masks (" + ", ".join(MASKS) + ", on the rounds' model) or methods of the project's models")
    p.add_argument("--out", required=True)
    p.add_argument("--report", action="store_true", help="print the counts of what --out holds, run nothing")
    args = p.parse_args(argv)
    out = pathlib.Path(args.out)
    if args.report:
        records = run_files.study_rounds_file(out, STUDY_KEY).records()
        if not records:
            print(f"first_view_picks: no rounds in {out}: run without --report first", file=sys.stderr)
            return 2
        print("\n".join(report_lines(records)))
        return 0
    try:
        if args.method not in METHODS or METHODS[args.method].hand != "2f85":
            raise ValueError(f"--method {args.method!r}: use a method of the project's models (e.g. ours, binary)")
        compare = tuple(c for c in args.compare.split(",") if c)
        check_selections(compare)
        model = pathlib.Path(args.model) if args.model else METHODS[args.method].default_path()
        if not model.is_file():
            raise ValueError(f"model file {model} not found: pass --model PATH")
        done = run_files.study_rounds_file(out, STUDY_KEY)
        for results in args.results or ["sim_bridge/results/heldout_v4"]:
            for method, kg, recorded in benchmark_rounds(results, [args.method], parse_weights(args.weights)):
                sid = recorded["scene_id"]
                if done.get(pathlib.Path(results).name, method, kg, sid) is not None:
                    continue
                record = first_view(results, method, kg, sid, model, compare)
                done.put(record)
                print(f"{pathlib.Path(results).name} {method} {weight_key(kg)} kg {sid}: first attempt "
                      f"{record['outcome']}, repeated {record.get('same_pose')}, "
                      f"{record['cpu_s']} s CPU", flush=True)
    except ValueError as e:
        print(f"first_view_picks: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
