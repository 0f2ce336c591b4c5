"""Which of the paper's claims hold here: each claim a paired per-scene comparison on the
committed rounds of the runs the README's table reads (results_table.RUNS), printed as one
Markdown table so it cannot be typed wrong.

    python -m sim_bridge.benchmark.paper_claims [--runs HELDOUT_RUN,PROCEDURAL_RUN]

The claims (Ko et al., Sec. V-C and Fig. 5; "heavy" there is more than 1 kg):
- Ours ahead of Ours-Precision at heavy weights (power labels pay), at each weight over 1 kg;
- Ours has the smallest drop in SR from 0.1 to 1.5 kg: per scene, the other method's drop
  minus Ours' (positive: Ours dropped less), against Binary and Ours-Precision;
- Ours ahead even at light weights: Ours against Binary and Ours-Precision at 0.1 kg;
- Ours-Precision on par with VN-EdgeGraspNet at heavy weights, from the run itself where it
  has VN-EdgeGraspNet's rounds, else from the baselines run of that object set.

A verdict reads the sign and the sign-flip p value (benchmark/paired.py): "holds" is the
claimed sign at p < 0.05, "same sign, n.s." the claimed sign without it, "opposite, n.s."
and "opposite" the other sign, "level" no difference at all. "On par" holds where p >= 0.05 ("no difference shown": a
wide interval cannot show equality), and not where p < 0.05 ("no: ahead" or "no: behind").
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from .paired import bootstrap_ci, scene_rates, sign_flip_p
from .results_table import BASELINE_RUNS, REPO_ROOT, RUNS
from .run_files import rounds_file

SIGNIFICANT_P = 0.05
HEAVY_ABOVE_KG = 1.0  # the paper's "heavy-weight region (more than 1 kg)"
LIGHT_KG, DROP_TO_KG = 0.1, 1.5  # the light end of the paper's Fig. 5, and the weight its drop runs to
POWER_CLAIM = "Ours ahead of Ours-Precision"  # the paper's main claim: power labels pay at heavy weights
NAMES = {"ours": "Ours", "ours_precision": "Ours-Precision", "binary": "Binary", "vn_edge": "VN-EdgeGraspNet"}


def paired(diffs) -> dict:
    """{scenes, diff, ci95, p_value} of per-scene differences (empty: scenes 0)."""
    diffs = list(diffs)
    if not diffs:
        return {"scenes": 0}
    return {"scenes": len(diffs), "diff": float(np.mean(diffs)), "ci95": bootstrap_ci(diffs),
            "p_value": sign_flip_p(diffs)}


def difference(rates: dict, method: str, reference: str, kg: float) -> dict:
    """`method` − `reference` at `kg`, per scene over the scenes both have an SR for."""
    own, ref = rates.get((method, kg), {}), rates.get((reference, kg), {})
    return paired(own[s] - ref[s] for s in sorted(own.keys() & ref.keys()))


def drop_difference(rates: dict, reference: str, light_kg: float = LIGHT_KG, heavy_kg: float = DROP_TO_KG) -> dict:
    """Per scene, `reference`'s SR drop from `light_kg` to `heavy_kg` minus Ours' (positive:
    Ours dropped less), over the scenes where all four SRs exist."""
    series = [rates.get((m, kg), {}) for m in ("ours", reference) for kg in (light_kg, heavy_kg)]
    scenes = sorted(set.intersection(*(set(s) for s in series)))
    ours_light, ours_heavy, ref_light, ref_heavy = series
    return paired((ref_light[s] - ref_heavy[s]) - (ours_light[s] - ours_heavy[s]) for s in scenes)


def verdict(result: dict, on_par: bool = False) -> str:
    """The cell: the verdict, then the mean per-scene difference, its interval, p and scenes."""
    if not result.get("scenes"):
        return "not run"
    d, (lo, hi), p = result["diff"], result["ci95"], result["p_value"]
    if on_par:
        word = "no difference shown" if p >= SIGNIFICANT_P else ("no: ahead" if d > 0 else "no: behind")
    elif math.isclose(d, 0.0, abs_tol=1e-9):
        word = "level"
    elif d > 0:
        word = "**holds**" if p < SIGNIFICANT_P else "same sign, n.s."
    else:
        word = "opposite" if p < SIGNIFICANT_P else "opposite, n.s."
    return (f"{word}: {100 * d:+.1f} pts ({100 * lo:+.1f} to {100 * hi:+.1f}), p = {p:.2g}, "
            f"{result['scenes']} scenes").replace("-", "−")


def claims(rounds: list, baseline_rounds: list) -> list:
    """[(claim, cell)] for one object set: its run's rounds and its baselines run's."""
    rates, base = scene_rates(rounds), scene_rates(baseline_rounds)
    heavy = sorted({kg for (m, kg) in rates if m == "ours" and kg > HEAVY_ABOVE_KG})
    rows = [(f"{POWER_CLAIM} at {kg:g} kg", verdict(difference(rates, "ours", "ours_precision", kg)))
            for kg in heavy]
    rows += [(f"Ours drops less than {NAMES[ref]} from {LIGHT_KG:g} to {DROP_TO_KG:g} kg",
              verdict(drop_difference(rates, ref))) for ref in ("binary", "ours_precision")]
    rows += [(f"Ours ahead of {NAMES[ref]} at {LIGHT_KG:g} kg", verdict(difference(rates, "ours", ref, LIGHT_KG)))
             for ref in ("binary", "ours_precision")]
    edge = rates if any(m == "vn_edge" for m, _ in rates) else base
    edge_heavy = sorted({kg for (m, kg) in edge if m == "vn_edge" and kg > HEAVY_ABOVE_KG})
    rows += [(f"Ours-Precision on par with VN-EdgeGraspNet at {kg:g} kg",
              verdict(difference(edge, "ours_precision", "vn_edge", kg), on_par=True)) for kg in edge_heavy]
    return rows


def table_lines(root: Path = REPO_ROOT, runs=None) -> list:
    """The claims table as Markdown lines: a row per claim, a column per object set; `runs`
    (one run directory per object set, in RUNS' order) replaces RUNS' runs."""
    runs = RUNS if runs is None else tuple(zip((label for label, _ in RUNS), runs, strict=True))
    columns = {label: dict(claims(rounds_file(root / run).records(),
                                  rounds_file(root / BASELINE_RUNS[label]).records()
                                  if (root / BASELINE_RUNS[label]).is_dir() else []))
               for label, run in runs}
    rows = list(dict.fromkeys(claim for cells in columns.values() for claim in cells))
    heavy = [c for c in rows if c.startswith(f"{POWER_CLAIM} at ") and float(c.split()[-2]) > HEAVY_ABOVE_KG]
    if not heavy:  # the main claim is never silently absent
        rows.insert(0, f"{POWER_CLAIM} above {HEAVY_ABOVE_KG:g} kg")
    lines = ["| the paper's claim | " + " | ".join(columns) + " |", "| --- |" + " --- |" * len(columns)]
    lines += [f"| {claim} | " + " | ".join(cells.get(claim, "not run") for cells in columns.values()) + " |"
              for claim in rows]
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", default="", help="comma-separated run directories, one per object set ("
                   + ", ".join(label for label, _ in RUNS) + "); default: the README table's runs")
    args = p.parse_args(argv)
    runs = [r for r in args.runs.split(",") if r] or None
    if runs is not None and len(runs) != len(RUNS):
        p.error(f"--runs needs {len(RUNS)} run directories ({', '.join(label for label, _ in RUNS)}), got {len(runs)}")
    missing = [r for r in runs or () if not rounds_file(r).path.is_file()]
    if missing:
        p.error(f"no rounds.jsonl in {', '.join(missing)}: give benchmark run directories (--out of a benchmark run)")
    print("\n".join(table_lines(REPO_ROOT, runs and [str(Path(r).resolve()) for r in runs])))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
