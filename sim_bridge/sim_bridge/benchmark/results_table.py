"""The README's results table, printed from committed results so it cannot be typed wrong.

`python -m sim_bridge.benchmark.results_table` reads the shipped models' benchmark runs
(`results.json` and `comparisons.json`, which `benchmark --report` writes) and prints one
Markdown table: per run and shipped method, SR at each weight with its 95 % Wilson interval,
and the mean per-scene difference to Binary with its paired sign-flip p value; a cell run on
fewer scenes than the run's most says on how many. The levers run beside them are in
levers.md (`lever_table`). tests/sim_bridge/test_results_table.py checks that README.md holds
exactly this output.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

# The decisive runs of the shipped models (models/*.pt; issue 42's 32 scenes), in the
# order the table shows them, and the methods it shows: the shipped models' only.
RUNS = (("held-out meshes", "sim_bridge/results/heldout_v4_decisive"),
        ("procedural objects", "sim_bridge/results/procedural_v4_decisive"))
SHOWN = ("ours", "binary", "ours_precision")
METHOD_NAMES = {"ours": "**Ours**", "binary": "Binary", "ours_expected": "Ours, ranked by validness × score",
                "ours_precision": "Ours-Precision", "ours_ey_ez": "Ours, ey-ez rotation",
                "ours_quat": "Ours, quaternion rotation"}
REPO_ROOT = Path(__file__).resolve().parents[3]


def _pct(x: float) -> str:
    return f"{100 * x:.1f} %"


def _cell(row: dict, comparison: dict | None, scenes: int) -> str:
    """SR (successes/attempts; Wilson interval; the scenes if fewer than `scenes`), then the
    difference to Binary per scene, paired, with its p value (the test that decides:
    benchmark/paired.py)."""
    lo, hi = row["SR_ci95"]
    fewer = f"; {row['rounds']} scenes" if row.get("rounds", scenes) < scenes else ""
    cell = f"{_pct(row['SR'])} ({row['successes']}/{row['attempts']}; {100 * lo:.0f}–{100 * hi:.0f}{fewer})"
    paired = (comparison or {}).get("paired")
    if paired and not math.isnan(paired["p_value"]):
        cell += f", {100 * paired['diff']:+.1f} pts, p = {paired['p_value']:.2g}"
    return cell.replace("-", "−")


def table_lines(root: Path = REPO_ROOT) -> list:
    """The table as Markdown lines, from the committed runs under `root`."""
    lines = []
    for label, run in RUNS:
        rows = [r for r in json.loads((root / run / "results.json").read_text())
                if r["method"] in SHOWN and r.get("attempts")]
        comparisons = json.loads((root / run / "comparisons.json").read_text())
        scenes = max(r.get("rounds", 0) for r in rows)
        weights = sorted({r["mass_kg"] for r in rows})
        if not lines:
            lines = ["| objects | method | " + " | ".join(f"SR {w:g} kg" for w in weights) + " |",
                     "| --- | --- | " + " | ".join("---" for _ in weights) + " |"]
        for method in dict.fromkeys(r["method"] for r in rows):
            by_weight = {r["mass_kg"]: r for r in rows if r["method"] == method}
            cells = []
            for w in weights:
                c = next((c for c in comparisons if c["method"] == method and c["mass_kg"] == w), None)
                cells.append(_cell(by_weight[w], c, scenes) if w in by_weight else "—")
            lines.append(f"| {label} | {METHOD_NAMES.get(method, method)} | " + " | ".join(cells) + " |")
    return lines


def main(argv=None) -> int:
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args(argv)
    print("\n".join(table_lines()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
