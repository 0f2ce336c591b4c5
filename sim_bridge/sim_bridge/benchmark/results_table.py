"""The README's results table and figure, printed from committed results so they cannot be
typed wrong.

`python -m sim_bridge.benchmark.results_table [--figure PNG]` reads the shipped models' benchmark runs
(`results.json` and `comparisons.json`, which `benchmark --report` writes) and prints one
Markdown table: per run and shipped method, SR at each weight with its 95 % Wilson interval,
and the mean per-scene difference to Binary with its paired sign-flip p value; a cell run on
fewer scenes than the run's most says on how many. Under each run, the paper's power-grasp
effect (Ours − Ours-Precision per scene, paired; `power_grasp_effect.json`). `--figure` also
draws SR and CR against weight for those methods and, dashed, the paper's baselines of the
baselines runs (Panda hand, 0.1-1.5 kg, 16 scenes), both object sets side by side. The
levers run beside them are in levers.md (`lever_table`). tests/sim_bridge/test_results_table.py
checks that README.md holds exactly this output.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

# The decisive runs of the shipped models (models/*.pt; 32 scenes), in the order the table
# shows them, and the methods it shows: the shipped models' only.
RUNS = (("held-out meshes", "sim_bridge/results/heldout_v4_decisive"),
        ("procedural objects", "sim_bridge/results/procedural_v4_decisive"))
SHOWN = ("ours", "binary", "ours_precision")
METHOD_NAMES = {"ours": "**Ours**", "binary": "Binary", "ours_expected": "Ours, ranked by validness × score",
                "ours_precision": "Ours-Precision", "ours_ey_ez": "Ours, ey-ez rotation",
                "ours_quat": "Ours, quaternion rotation"}
# The row under each run's methods: Ours − Ours-Precision per scene (paired.power_grasp_effect)
POWER_EFFECT_ROW = "Ours − Ours-Precision, per scene"
# The figure adds the paper's baselines, from the runs that compared them (16 scenes each)
BASELINE_RUNS = {"held-out meshes": "sim_bridge/results/baselines_heldout",
                 "procedural objects": "sim_bridge/results/baselines_procedural"}
BASELINES = {"vgn": "VGN (Panda)", "vn_edge": "VN-EdgeGraspNet (Panda)", "vgn_2f85": "VGN's grasps on the 2F-85"}
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
        cell += ", " + _paired(paired)
    return cell.replace("-", "−")


def _paired(c: dict) -> str:
    """A per-scene paired difference (benchmark/paired.py's entry) and its p value."""
    return f"{100 * c['diff']:+.1f} pts, p = {c['p_value']:.2g}".replace("-", "−")


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
        effect_file = root / run / "power_grasp_effect.json"
        if effect_file.is_file():  # the paper's power-grasp effect, as `benchmark --report` wrote it
            effect = {c["mass_kg"]: c for c in json.loads(effect_file.read_text())}
            lines.append(f"| {label} | {POWER_EFFECT_ROW} | "
                         + " | ".join(_effect_cell(effect.get(w)) for w in weights) + " |")
    return lines


def _effect_cell(c: dict | None) -> str:
    """Ours − Ours-Precision per scene, paired, with its p value; a dash where either did not run."""
    return "—" if not c or math.isnan(c["diff"]) else _paired(c)


def figure_series(root: Path = REPO_ROOT) -> dict:
    """{object set: [(label, dashed, [results.json rows with rounds, by weight])]}: the table's
    methods from RUNS, then BASELINES from BASELINE_RUNS."""
    series = {}
    for label, run in RUNS:
        sources = [(run, SHOWN, False), (BASELINE_RUNS[label], tuple(BASELINES), True)]
        for source, methods, dashed in sources:
            rows = [r for r in json.loads((root / source / "results.json").read_text()) if r.get("rounds")]
            for method in methods:
                mine = sorted((r for r in rows if r["method"] == method), key=lambda r: r["mass_kg"])
                name = BASELINES.get(method) or METHOD_NAMES[method].strip("*")
                lo, hi = min(r["rounds"] for r in mine), max(r["rounds"] for r in mine)
                series.setdefault(label, []).append((f"{name}: {lo if lo == hi else f'{lo}-{hi}'} scenes", dashed, mine))
    return series


def plot(path, root: Path = REPO_ROOT) -> None:
    """2 x 2: SR (top) and CR (bottom) against weight, one column per object set; bars: 95 %
    Wilson intervals."""
    # lazy: matplotlib only for the figure, not for the table the README test reads
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from gravgrasp_detector import atomic_files

    series = figure_series(root)
    fig, axes = plt.subplots(2, len(series), figsize=(5.4 * len(series), 7.2), sharex=True, sharey=True, squeeze=False)
    colours = plt.get_cmap("tab10").colors
    for col, (label, lines) in enumerate(series.items()):
        for row_i, key in enumerate(("SR", "CR")):
            ax = axes[row_i, col]
            for i, (name, dashed, rows) in enumerate(lines):
                x, y = [r["mass_kg"] for r in rows], [100 * r[key] for r in rows]
                err = [[y_ - 100 * r[f"{key}_ci95"][0] for y_, r in zip(y, rows)],
                       [100 * r[f"{key}_ci95"][1] - y_ for y_, r in zip(y, rows)]]
                ax.errorbar(x, y, yerr=err, fmt="o--" if dashed else "o-", color=colours[i], capsize=3, label=name)
            ax.set_ylim(-2, 102)
            ax.set_xticks([0.1, 0.5, 1.5, 4.0])
            ax.grid(alpha=0.3)
            if row_i == 0:
                ax.set_title(label)
                ax.legend(fontsize=7, loc="upper right")
            else:
                ax.set_xlabel("object weight [kg]")
            if col == 0:
                ax.set_ylabel(f"{'success' if key == 'SR' else 'clear'} ratio {key} [%]")
    fig.suptitle("Clutter removal against object weight (solid: the shipped models, 2F-85; dashed: the paper's "
                 "baselines)\npython -m sim_bridge.benchmark.results_table --figure " + str(path), fontsize=9)
    fig.tight_layout()
    atomic_files.save_figure(path, fig, dpi=90)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--figure", metavar="PNG", help="also draw SR and CR against weight into this file")
    args = p.parse_args(argv)
    print("\n".join(table_lines()))
    if args.figure:
        plot(args.figure)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
