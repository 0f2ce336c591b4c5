"""The paper's Fig. 5 with its baselines, side by side: SR and CR
against object weight (0.1, 0.5, 1.5 kg), one line per method, the held-out meshes and
the procedural objects in two columns, plus a Markdown table; from the rounds on disk of
the two runs `make benchmark-baselines` fills (sim_bridge/doc/baselines.md):

    python -m sim_bridge.benchmark.baselines_figure

Partial results are fine: every cell says how many of the run's scenes it pools, a
method or weight without rounds is a gap in its line and "—" in the table, and the
legend gives each method's rounds. Only rounds of each method's current file count (its
model_sha256, as the benchmark's report; where the file is not on this machine, all).
The statistics are the benchmark report's (report.summarize: pooled SR/CR with Wilson
intervals; paired.compare_paired: per scene, paired), not a second implementation.
"""

from __future__ import annotations

import argparse
import io
import math
import pathlib
import sys

from gravgrasp_detector import atomic_files
from gravgrasp_detector.perception.model_file import file_sha256

from . import run_files
from .methods import METHODS, MethodFileMissing
from .paired import compare_paired
from .report import summarize

RUNS = (("held-out meshes", "sim_bridge/results/baselines_heldout"),
        ("procedural objects", "sim_bridge/results/baselines_procedural"))
WEIGHTS_KG = (0.1, 0.5, 1.5)  # the paper's range
# (method, label), in the legend's order: the paper's three on the 2F-85, the baselines on
# the Panda hand, VGN's detector on the 2F-85
FIGURE_METHODS = (("ours", "Ours"), ("binary", "Binary"), ("ours_precision", "Ours-Precision"),
                  ("vgn", "VGN"), ("vn_edge", "VN-EdgeGraspNet"), ("vgn_2f85", "VGN's grasps"))
# VGN's grasps on the 2F-85 separate the detector from the hand at the ends of the range only
PLANNED_WEIGHTS_KG = {"vgn_2f85": (0.1, 1.5)}
HAND_NAMES = {"2f85": "2F-85", "panda": "Panda"}
# Where Ours' gain over VGN comes from (doc/baselines.md, "What this answers"): each step
# changes one thing, at the weights VGN's grasps on the 2F-85 ran
CHAIN_STEPS = (("vgn", "vgn_2f85", "the hand"), ("vgn_2f85", "binary", "the detector and its data"),
               ("binary", "ours", "the labels"), ("vgn", "ours", "all of it"))
# GIGA (arXiv 2104.01542) Table I, VGN with one side view: the sanity anchor at 0.1 kg
GIGA_VGN_SR = {"packed": 0.745, "pile": 0.607}


def planned(method: str) -> tuple:
    return PLANNED_WEIGHTS_KG.get(method, WEIGHTS_KG)


def label(method: str) -> str:
    return f"{dict(FIGURE_METHODS)[method]} ({HAND_NAMES[METHODS[method].hand]})"


def current_sha(method: str, models_dir, baselines_dir=None):
    """sha256 of the method's file now; None where it is not on this machine."""
    try:
        return file_sha256(METHODS[method].locate(models_dir, baselines_dir))
    except MethodFileMissing:
        return None


def load_run(run_dir, models_dir="models", baselines_dir=None) -> dict:
    """{"rounds": the figure's methods' rounds at WEIGHTS_KG of the current files,
    "scenes": the run's scene count, "stale": rounds of other files, left out}."""
    run_dir = pathlib.Path(run_dir)
    rounds, stale = [], 0
    ran = run_files.rounds_file(run_dir).records()
    for method, _ in FIGURE_METHODS:
        sha = current_sha(method, models_dir, baselines_dir)
        for w in WEIGHTS_KG:
            for r in ran:
                if r["method"] != method or float(r["mass_kg"]) != float(w):
                    continue
                if sha is None or r.get("model_sha256") == sha:
                    rounds.append(r)
                else:
                    stale += 1
    scenes = len(run_files.scenes_file(run_dir))
    return {"rounds": rounds, "scenes": scenes or len({r["scene_id"] for r in rounds}), "stale": stale}


def summary(run: dict) -> list:
    """report.summarize's rows, every figure method at its planned weights (0 rounds: NaN)."""
    return summarize(run["rounds"], {m: list(planned(m)) for m, _ in FIGURE_METHODS})


# the table


def _pct(x: float) -> str:
    return "—" if math.isnan(x) else f"{100 * x:.1f} %"


def _cell(row, key: str, scenes: int) -> str:
    if row is None:
        return "not run"
    if not row["rounds"]:
        return f"— (0/{scenes})"
    n = row["attempts"] if key == "SR" else row["objects"]
    return f"{_pct(row[key])} ({row['successes']}/{n}; {row['rounds']}/{scenes})"


def _paired_cell(c, sign: int = -1) -> str:
    """A compare_paired result (method − reference) times `sign`: by default reference −
    method (Ours − method), with its bootstrap interval and sign-flip p."""
    if c is None or math.isnan(c["diff"]):
        return "—"
    lo, hi = sorted(sign * x for x in c["ci95"])
    return f"{sign * 100 * c['diff']:+.1f} ({100 * lo:+.1f} to {100 * hi:+.1f}; p = {c['p_value']:.2g}; {c['scenes']})"


def chain_lines(runs: list) -> list:
    """The gain split along CHAIN_STEPS: per scene, paired, each step (later − earlier) over
    the scenes both of its methods ran."""
    weights = PLANNED_WEIGHTS_KG["vgn_2f85"]
    lines = ["Where the gain comes from: each step changes one thing; later − earlier, SR per scene, paired, "
             "over the scenes both ran (the steps add up to the whole only where every method ran every scene).",
             "", "| objects | step | what changes | " + " | ".join(f"{w:g} kg" for w in weights) + " |",
             "| --- | --- | --- | " + " | ".join("---" for _ in weights) + " |"]
    for name, run in runs:
        paired = {(c["reference"], c["method"], c["mass_kg"]): c  # once per reference: the bootstrap is not free
                  for reference in {earlier for earlier, _, _ in CHAIN_STEPS}
                  for c in compare_paired(run["rounds"], reference=reference)}
        for earlier, later, what in CHAIN_STEPS:
            cells = [_paired_cell(paired.get((earlier, later, w)), sign=1) for w in weights]
            lines.append(f"| {name} | {label(earlier)} → {label(later)} | {what} | " + " | ".join(cells) + " |")
    return lines


def anchor_lines(label_: str, run: dict) -> list:
    """VGN's SR at 0.1 kg per arrangement against GIGA's Table I."""
    cells = []
    for arrangement, giga in GIGA_VGN_SR.items():
        rs = [r for r in run["rounds"] if r["method"] == "vgn" and r["scene_id"].startswith(arrangement)]
        (row,) = summarize(rs, {"vgn": [0.1]})
        cells.append(f"{arrangement} {_pct(row['SR'])} ({row['successes']}/{row['attempts']}; {row['rounds']} rounds; "
                     f"GIGA {100 * giga:.1f} %)")
    return [f"- {label_}: " + ", ".join(cells)]


def table_lines(runs: list) -> list:
    """runs: [(label, load_run's dict)] -> Markdown."""
    header = " | ".join(f"{key} {w:g} kg" for key in ("SR", "CR") for w in WEIGHTS_KG)
    lines = ["SR = successes / attempts, CR = successes / objects, pooled over the rounds; in brackets: "
             "successes / attempts (SR) or objects (CR); rounds / the run's scenes.", "",
             f"| objects | method | {header} |", "| --- | --- | " + " | ".join("---" for _ in range(6)) + " |"]
    for name, run in runs:
        rows = {(r["method"], r["mass_kg"]): r for r in summary(run)}
        for method, _ in FIGURE_METHODS:
            cells = [_cell(rows.get((method, w)), key, run["scenes"]) for key in ("SR", "CR") for w in WEIGHTS_KG]
            lines.append(f"| {name} | {label(method)} | " + " | ".join(cells) + " |")
    lines += ["", "Ours − method, SR per scene, paired (benchmark/paired.py): mean difference in points, "
              "bootstrap 95 % interval, sign-flip p, scenes both ran.", "",
              "| objects | method | " + " | ".join(f"{w:g} kg" for w in WEIGHTS_KG) + " |",
              "| --- | --- | " + " | ".join("---" for _ in WEIGHTS_KG) + " |"]
    for name, run in runs:
        paired = {(c["method"], c["mass_kg"]): c for c in compare_paired(run["rounds"], reference="ours")}
        for method, _ in FIGURE_METHODS[1:]:
            lines.append(f"| {name} | {label(method)} | "
                         + " | ".join(_paired_cell(paired.get((method, w))) if w in planned(method) else "not run"
                                      for w in WEIGHTS_KG) + " |")
    lines += [""] + chain_lines(runs)
    lines += ["", "VGN's SR at 0.1 kg against the published anchor (GIGA Table I, one side view):", ""]
    for name, run in runs:
        lines += anchor_lines(name, run)
    stale = [f"{run['stale']} in {name}" for name, run in runs if run["stale"]]
    if stale:
        lines += ["", f"Left out, run with another model file than the current one: {', '.join(stale)} rounds."]
    return lines


# the figure


def plot(runs: list, path) -> None:
    """2 x 2: SR (top) and CR (bottom) against weight, one column per object set."""
    # lazy: matplotlib only for the figure, not for the table (as report.plot)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = dict(zip((m for m, _ in FIGURE_METHODS), plt.get_cmap("tab10").colors))
    fig, axes = plt.subplots(2, len(runs), figsize=(5.2 * len(runs), 7.2), sharex=True, sharey=True, squeeze=False)
    for col, (name, run) in enumerate(runs):
        rows = summary(run)
        for row_i, key in enumerate(("SR", "CR")):
            ax = axes[row_i, col]
            handles = []  # in FIGURE_METHODS' order (matplotlib lists lines before error bars)
            for method, _ in FIGURE_METHODS:
                rs = [r for r in rows if r["method"] == method and not math.isnan(r[key])]
                n = sum(r["rounds"] for r in rows if r["method"] == method)
                style = "-" if METHODS[method].hand == "2f85" else "--"
                legend = f"{label(method)}: {n}/{len(planned(method)) * run['scenes']} rounds"
                if not rs:
                    handles += ax.plot([], [], style, color=colours[method], label=legend + " (none yet)")
                    continue
                x = [r["mass_kg"] for r in rs]
                y = [100 * r[key] for r in rs]
                err = [[y_ - 100 * r[f"{key}_ci95"][0] for y_, r in zip(y, rs)],
                       [100 * r[f"{key}_ci95"][1] - y_ for y_, r in zip(y, rs)]]
                handles.append(ax.errorbar(x, y, yerr=err, fmt="o" + style, color=colours[method], capsize=3,
                                           label=legend))
            ax.set_ylim(-2, 102)
            ax.set_xticks(WEIGHTS_KG)
            ax.grid(alpha=0.3)
            if row_i == 0:
                ax.set_title(name)
                ax.legend(handles=handles, fontsize=7, loc="best")
            else:
                ax.set_xlabel("object weight [kg]")
            if col == 0:
                ax.set_ylabel(f"{'success' if key == 'SR' else 'clear'} ratio {key} [%]")
    fig.suptitle("Clutter removal against object weight (bars: 95 % Wilson intervals; dashed: Panda hand)",
                 fontsize=10)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    atomic_files.save_bytes(path, buf.getvalue())


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    # relative to the working directory, the project root, as the benchmark's own paths: so a
    # pinned worktree's code (ros_ws/run_pinned.sh) reads and writes the checkout's results
    p.add_argument("--heldout", default=RUNS[0][1], help="the held-out meshes' run")
    p.add_argument("--procedural", default=RUNS[1][1], help="the procedural objects' run")
    p.add_argument("--out-dir", default="sim_bridge/results",
                   help="where baselines_fig5.png and baselines_table.md go")
    p.add_argument("--models-dir", default="models")
    p.add_argument("--baselines", default=None, metavar="DIR", help="the baselines' files (their sha256)")
    args = p.parse_args(argv)
    runs = []
    for (name, _), run_dir in zip(RUNS, (args.heldout, args.procedural)):
        if not (pathlib.Path(run_dir) / "config.json").is_file():
            print(f"baselines_figure: {run_dir} holds no benchmark run (no config.json): run it from the project "
                  "root after `make benchmark-baselines`, or pass --heldout/--procedural", file=sys.stderr)
            return 2
        runs.append((name, load_run(run_dir, args.models_dir, args.baselines)))
    out = pathlib.Path(args.out_dir)
    lines = table_lines(runs)
    atomic_files.save_bytes(out / "baselines_table.md", ("\n".join(lines) + "\n").encode())
    plot(runs, out / "baselines_fig5.png")
    print("\n".join(lines))
    print(f"baselines_figure: {out / 'baselines_fig5.png'}, {out / 'baselines_table.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
