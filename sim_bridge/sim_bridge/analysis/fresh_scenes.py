"""A run's methods against Binary over its later scenes only: the scenes a decisive run
added to the ones its lever was chosen on (issue 42: the 32-scene runs hold the 16 tuning
scenes, whose figures a choice has seen, and 16 new ones, whose figures it has not):

    python -m sim_bridge.analysis.fresh_scenes RUN --after 16 [--methods ours_sure] [--reference ours]

Reads the run's attempts.json (run its --report first). The scenes left out are the first
`--after` of the benchmark's order (packed_000, pile_000, packed_001, ...; 0: every scene).
Per method and weight: SR of each over the fresh scenes, the mean per-scene SR difference to
the reference (Binary unless `--reference` names another method) with its paired bootstrap
interval and sign-flip p (benchmark/paired.py). Prints
`p_paired_<method>_vs_<reference>_<kg>_fresh=` and `diff_<method>_vs_<reference>_<kg>_fresh=` lines."""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

from ..benchmark.paired import compare_paired
from ..benchmark.protocol import scene_ids, weight_in_name
from ..benchmark.report import summarize
from .run_vs_run import load_rounds


def fresh_rounds(rounds: list, after: int) -> list:
    """The rounds of the scenes past the first `after` of the benchmark's order."""
    seen = set(scene_ids(after))
    return [r for r in rounds if r["scene_id"] not in seen]


def fresh_comparisons(rounds: list, after: int, methods=None, reference: str = "binary") -> list:
    """compare_paired against `reference` over the rounds of scenes past the first `after`, each
    row with the pooled SR of the method (SR) and of the reference (SR_reference) over the scenes
    it pairs."""
    fresh = [r for r in fresh_rounds(rounds, after) if r["attempts"]]
    rows = []
    for c in compare_paired(fresh, reference):
        if (methods and c["method"] not in methods) or not c["scenes"]:
            continue
        of = {name: {r["scene_id"]: r for r in fresh if r["method"] == name and r["mass_kg"] == c["mass_kg"]}
              for name in (c["method"], reference)}
        shared = of[c["method"]].keys() & of[reference].keys()
        pooled = summarize([rs[s] for rs in of.values() for s in shared],
                           {name: [c["mass_kg"]] for name in of})
        c["SR"], c["SR_reference"] = (row["SR"] for row in pooled)
        rows.append(c)
    return rows


def table_lines(rows, after: int, reference: str = "binary") -> list:
    lines = [f"Scenes after the first {after}: per scene, paired against {reference}.", "",
             f"| method | weight [kg] | scenes | SR | SR {reference} | per scene: SR − SR {reference} | 95 % CI | p |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        lines.append(f"| {r['method']} | {r['mass_kg']:g} | {r['scenes']} | {100 * r['SR']:.1f} % | "
                     f"{100 * r['SR_reference']:.1f} % | {100 * r['diff']:+.1f} pts | {100 * r['ci95'][0]:+.1f} to "
                     f"{100 * r['ci95'][1]:+.1f} | {r['p_value']:.3f} |")
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run", help="a benchmark run's --out, after its --report")
    p.add_argument("--after", type=int, required=True, help="leave out the first N scenes (the tuning scenes)")
    p.add_argument("--methods", default="", help="comma-separated; default every method beside the reference")
    p.add_argument("--reference", default="binary", help="the method the others are compared with (default binary)")
    args = p.parse_args(argv)
    if args.after < 0:
        print(f"fresh_scenes: --after {args.after}: give a number of scenes >= 0", file=sys.stderr)
        return 2
    try:
        rows = fresh_comparisons(load_rounds(args.run), args.after, [m for m in args.methods.split(",") if m],
                                 args.reference)
    except (ValueError, OSError, KeyError, json.JSONDecodeError) as e:
        print(f"fresh_scenes: {e}", file=sys.stderr)
        return 2
    if not rows:
        print(f"fresh_scenes: no method pairs with {args.reference} on a scene after the first {args.after} in "
              f"{pathlib.Path(args.run)}", file=sys.stderr)
        return 2
    print("\n".join(table_lines(rows, args.after, args.reference)))
    vs = f"vs_{args.reference}"
    for r in rows:
        print(f"p_paired_{r['method']}_{vs}_{weight_in_name(r['mass_kg'])}_fresh={r['p_value']:.3f}")
    for r in rows:
        print(f"diff_{r['method']}_{vs}_{weight_in_name(r['mass_kg'])}_fresh={r['diff']:+.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
