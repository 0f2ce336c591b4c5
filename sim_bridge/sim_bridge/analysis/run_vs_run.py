"""The same methods in two benchmark runs of the same scenes, compared scene by scene:
what a run-wide setting changes (an execution lever such as the guarded approach, which
Ours and Binary both run under, so a run's own report cannot show it). Reads each run's
attempts.json (what its `--report` counted: the current model files' rounds only):

    python -m sim_bridge.analysis.run_vs_run BASE LEVER [--methods ours,binary]

Per method and weight both ran: SR in each, the mean per-scene SR difference (LEVER −
BASE) with its paired bootstrap interval and sign-flip p (benchmark/paired.py), and the
attempts lost before the lift in each (report.before_lift_losses), all over the scenes both
runs have a round of. Refuses runs whose
shared scenes differ. Prints `p_paired_<method>_<kg>=` and `diff_<method>_<kg>=` lines."""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

from ..benchmark import run_files
from ..benchmark.paired import compare_paired
from ..benchmark.protocol import weight_in_name
from ..benchmark.report import before_lift_losses


def load_rounds(run_dir) -> list:
    """The rounds of a run's attempts.json, each with its attempts (outcome classes)."""
    path = pathlib.Path(run_dir) / "attempts.json"
    if not path.exists():
        raise ValueError(f"{path} is missing: run the benchmark's --report on {run_dir} first")
    data = json.loads(path.read_text())
    by_round = {}
    for a in data["attempts"]:
        by_round.setdefault((a["method"], float(a["mass_kg"]), a["scene_id"]), []).append(a)
    return [{**r, "mass_kg": float(r["mass_kg"]),
             "attempts": by_round.get((r["method"], float(r["mass_kg"]), r["scene_id"]), [])}
            for r in data["rounds"]]


def check_same_scenes(base_dir, lever_dir) -> int:
    """How many scenes the runs share; ValueError if a shared one differs."""
    base = {s["scene_id"]: s for s in run_files.scenes_file(base_dir).records()}
    lever = {s["scene_id"]: s for s in run_files.scenes_file(lever_dir).records()}
    shared = sorted(base.keys() & lever.keys())
    if not shared:
        raise ValueError(f"{base_dir} and {lever_dir} share no scene: run the lever on the base run's scenes "
                         f"(copy its {run_files.SCENES} into the lever run first)")
    for name in shared:
        if base[name] != lever[name]:
            raise ValueError(f"scene {name} differs between {base_dir} and {lever_dir}: not the same scenes, "
                             "so not a paired comparison (copy the base run's scenes.jsonl into the lever run first)")
    return len(shared)


def compare_runs(base: list, lever: list, methods) -> list:
    """[{method, mass_kg, scenes, SR_base, SR_lever, diff, ci95, p_value, before_lift_base,
    before_lift_lever}] for each method and weight both runs have; every figure over the
    scenes both runs have a round of (with attempts) only."""
    out = []
    for method in methods:
        for kg in sorted({r["mass_kg"] for r in lever if r["method"] == method}):
            runs = {name: {r["scene_id"]: r for r in rounds if r["method"] == method and r["mass_kg"] == kg
                           and r["attempts"]} for name, rounds in (("base", base), ("lever", lever))}
            shared = sorted(runs["base"].keys() & runs["lever"].keys())
            if not shared:
                continue
            paired = {name: [{**rs[s], "method": name} for s in shared] for name, rs in runs.items()}
            c, = compare_paired(paired["base"] + paired["lever"], reference="base")
            row = {"method": method, "mass_kg": kg, "scenes": c["scenes"], "diff": c["diff"], "ci95": c["ci95"],
                   "p_value": c["p_value"]}
            for name, rs in paired.items():
                row[f"SR_{name}"] = sum(r["successes"] for r in rs) / sum(len(r["attempts"]) for r in rs)
                row[f"before_lift_{name}"] = before_lift_losses(rs)[(name, kg)]["total"]
            out.append(row)
    return out


def table_lines(rows, base_name: str, lever_name: str) -> list:
    lines = [f"| method | weight [kg] | scenes | SR {base_name} | SR {lever_name} | per scene: difference | 95 % CI "
             f"| p | lost before the lift ({base_name} → {lever_name}) |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        lines.append(f"| {r['method']} | {r['mass_kg']:g} | {r['scenes']} | {100 * r['SR_base']:.1f} % | "
                     f"{100 * r['SR_lever']:.1f} % | {100 * r['diff']:+.1f} pts | {100 * r['ci95'][0]:+.1f} to "
                     f"{100 * r['ci95'][1]:+.1f} | {r['p_value']:.3f} | {r['before_lift_base']} → "
                     f"{r['before_lift_lever']} |")
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("base", help="the run without the setting (its --out)")
    p.add_argument("lever", help="the run with it, on the same scenes")
    p.add_argument("--methods", default="ours,binary", help="comma-separated; default ours,binary")
    args = p.parse_args(argv)
    try:
        shared = check_same_scenes(args.base, args.lever)
        rows = compare_runs(load_rounds(args.base), load_rounds(args.lever), args.methods.split(","))
    except (ValueError, OSError, KeyError, json.JSONDecodeError) as e:
        print(f"run_vs_run: {e}", file=sys.stderr)
        return 2
    if not rows:
        print(f"run_vs_run: no method of {args.methods} ran at a weight in both runs ({shared} shared scenes)",
              file=sys.stderr)
        return 2
    print("\n".join(table_lines(rows, pathlib.Path(args.base).name, pathlib.Path(args.lever).name)))
    for r in rows:
        print(f"p_paired_{r['method']}_{weight_in_name(r['mass_kg'])}={r['p_value']:.3f}")
    for r in rows:
        print(f"diff_{r['method']}_{weight_in_name(r['mass_kg'])}={r['diff']:+.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
