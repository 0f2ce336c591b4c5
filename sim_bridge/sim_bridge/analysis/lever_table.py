"""Issue 42's levers side by side, printed from committed results so it cannot be typed wrong.

`python -m sim_bridge.analysis.lever_table` reads, for each lever, the benchmark run that
measured it on each tuning set (`comparisons.json` and `attempts.json`, which `benchmark
--report` writes) and prints one Markdown table: the method's SR − Binary's per scene,
paired (benchmark/paired.py), at 0.1 and 1.5 kg with its p value; its attempts lost before
the lift against Binary's over those weights (report.before_lift_losses); CR of both at
each weight over the same scenes (a lever can raise SR by attempting less); and which of
the issue's three targets it meets there. A lever whose run is not there yet says so.
`--decisive` prints the same columns for the decisive runs instead, of the chosen lever and
of the shipped Ours: 32 scenes on each tuning set, their 16 new scenes alone (the ones no
choice saw), and the unseen procedural seed 2000. sim_bridge/doc/levers.md holds exactly both
outputs (tests/sim_bridge/test_lever_table.py); `--write` rewrites them there.
`--screen METHOD` applies the screen rule levers.md wrote before a screened method's rounds
(the direction of all three targets on both decisive runs' 32 scenes) and prints its verdict
last, `screen_<method>=passed|failed|incomplete`.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from pathlib import Path

from ..benchmark.paired import compare_paired
from ..benchmark.report import AFTER_LIFT, before_lift_losses, summarize
from .fresh_scenes import fresh_rounds
from .run_vs_run import load_rounds

HELDOUT, PROCEDURAL = "held-out meshes", "procedural seed 1000"
# (lever, kind, switch, method, {set: run}); the method is compared with Binary in its run.
# The guarded approach is a run's setting: Ours and Binary both run under it.
LEVERS = (
    ("none (the shipped Ours)", "—", "—", "ours",
     {HELDOUT: "heldout_v4_sure", PROCEDURAL: "procedural_v4_sure"}),
    ("rank by validness × score", "selection", "rank key validness × score (`detection_levers.expected_score`)", "ours_expected",
     {HELDOUT: "heldout_v4", PROCEDURAL: "procedural_v4"}),
    ("validness floor 0.9", "selection", "detect `validness_threshold:=0.9`", "ours_sure",
     {HELDOUT: "heldout_v4_sure", PROCEDURAL: "procedural_v4_sure"}),
    ("precision labels only, validness floor 0.9", "training + selection",
     "`train --data-subset precision-only`, detect `validness_threshold:=0.9`", "ours_precision_sure",
     {HELDOUT: "heldout_v4_precision_sure", PROCEDURAL: "procedural_v4_precision_sure"}),
    ("told the mass: surest grasp scored ≥ 1.5 × weight", "selection", "by validness among grasps of `min_score_n` ≥ 1.5 m g (`detection_levers`)",
     "ours_mass", {HELDOUT: "heldout_v4_mass"}),
    ("told the mass: calibrated need preferred", "selection", "rank key `detection_levers.preferring`", "ours_told",
     {HELDOUT: "heldout_v4_told"}),
    ("precision labels only", "training", "`train --data-subset precision-only`", "ours_precision",
     {HELDOUT: "heldout_v4", PROCEDURAL: "baselines_procedural"}),
    ("executor's clearance at label time", "training", "`label_clearance_lever --write`, then `train`", "ours_clearance",
     {HELDOUT: "heldout_v4_clearance", PROCEDURAL: "procedural_v4_clearance"}),
    ("guarded approach, 10 mm", "execution", "execute `close_on_contact_within_m:=0.01`", "ours",
     {HELDOUT: "heldout_v4_guarded_approach"}),  # procedural half not run: no effect held-out (levers.md)
    # screened on the decisive runs' 32 scenes (decisive_chain.sh SCREEN), not on 16
    ("Binary places, Ours ranks: Binary's grasps of validness ≥ 0.9 by Ours' score", "selection",
     "Binary's model, Ours' score as rank key, validness ≥ 0.9 (`detection_levers`)",
     "binary_scored",
     {HELDOUT: "heldout_v4_decisive", PROCEDURAL: "procedural_v4_decisive"}),
)
# The decisive runs (sim_bridge/chains/decisive_chain.sh) of the lever the rule in levers.md chose and
# of the product that ships (the shipped Ours: the lever was not adopted), each
# (method, objects, run, tuning scenes left out: the first 16 are the ones the lever was chosen on).
LEVER, PRODUCT = "ours_precision_sure", "ours"
DECISIVE = tuple((method, objects, run, after) for method in (LEVER, PRODUCT) for objects, run, after in (
    ("held-out meshes, 32 scenes", "heldout_v4_decisive", 0),
    ("held-out meshes, the 16 new scenes", "heldout_v4_decisive", 16),
    ("procedural seed 1000, 32 scenes", "procedural_v4_decisive", 0),
    ("procedural seed 1000, the 16 new scenes", "procedural_v4_decisive", 16),
    ("procedural seed 2000, which no choice saw, 32 scenes", "procedural_s2000_confirm", 0)))
WEIGHTS_KG = (0.1, 1.5)
RESULTS = "sim_bridge/results"
REPO_ROOT = Path(__file__).resolve().parents[3]
# The targets: SR at 0.1 kg >= Binary's - 3 points; at 1.5 kg >= +15 points with
# paired p < 0.05; losses before the lift <= 1.5 x Binary's.
LIGHT_MIN, HEAVY_MIN, HEAVY_P, LOSS_RATIO_MAX = -0.03, 0.15, 0.05, 1.5


def measure(run_dir: Path, method: str, after: int = 0) -> dict | None:
    """{diff: {kg: (mean per-scene SR diff, p, scenes)}, losses: (method's, Binary's), cr: {kg:
    (method's CR, Binary's)}, ran: {kg: scenes both ran, with or without an attempt}} of
    `method` against Binary in the run, the losses before the lift over the scenes both ran;
    with `after`, over the scenes past the run's first `after` only (fresh_scenes.py).
    None if the run or either method's report is not there."""
    try:
        comparisons = json.loads((run_dir / "comparisons.json").read_text())
        rounds = load_rounds(run_dir)
    except (OSError, ValueError):
        return None
    if after:  # the run's comparisons cover every scene: pair again over the fresh ones
        rounds = fresh_rounds(rounds, after)
        comparisons = [{"method": c["method"], "mass_kg": c["mass_kg"], "paired": c} for c in compare_paired(rounds)]
    diff = {}
    for c in comparisons:
        p = c.get("paired")
        if c["method"] == method and c["mass_kg"] in WEIGHTS_KG and p and not math.isnan(p["diff"]):
            diff[c["mass_kg"]] = (p["diff"], p["p_value"], p["scenes"])
    if not diff:
        return None
    # the losses over the scenes both ran at each weight, as the paired difference is
    scenes = {}
    for r in rounds:
        scenes.setdefault((r["method"], r["mass_kg"]), set()).add(r["scene_id"])
    both = {kg: scenes.get((method, kg), set()) & scenes.get(("binary", kg), set()) for kg in diff}
    paired = [r for r in rounds if r["method"] in (method, "binary") and r["scene_id"] in both.get(r["mass_kg"], ())]
    losses = before_lift_losses(paired)
    # CR beside SR: a floor that leaves views without a grasp raises SR by attempting less
    rows = {(r["method"], r["mass_kg"]): r for r in summarize(paired, {method: list(both), "binary": list(both)})}
    cr = {kg: (rows[(method, kg)]["CR"], rows[("binary", kg)]["CR"]) for kg in both}
    return {"diff": diff, "cr": cr, "ran": {kg: len(ids) for kg, ids in both.items()},
            "losses": tuple(sum(losses.get((m, kg), {"total": 0})["total"] for kg in both) for m in (method, "binary"))}


def binary_drops(run_dir: Path, kg: float = 1.5) -> tuple | None:
    """(Binary's attempts lost after the lift, its attempts) at `kg` in the run: the most a
    method that places as Binary does could gain by holding better, as a share of attempts."""
    try:
        rounds = [r for r in load_rounds(run_dir) if r["method"] == "binary" and r["mass_kg"] == kg]
    except (OSError, ValueError):
        return None
    attempts = [a for r in rounds for a in r["attempts"]]
    return (sum(a["outcome"] in AFTER_LIFT for a in attempts), len(attempts)) if attempts else None


def losses_met(m: dict) -> bool:
    """The before-the-lift target (the screen's too): the method's losses ≤ 1.5 × Binary's."""
    own, binary = m["losses"]
    return own <= LOSS_RATIO_MAX * binary


def targets_met(m: dict) -> str:
    """Which of the three targets the measurement meets (0.1 kg, 1.5 kg, before the lift)."""
    met = []
    if 0.1 in m["diff"] and m["diff"][0.1][0] >= LIGHT_MIN:
        met.append("0.1 kg")
    if 1.5 in m["diff"] and m["diff"][1.5][0] >= HEAVY_MIN and m["diff"][1.5][1] < HEAVY_P:
        met.append("1.5 kg")
    if losses_met(m):
        met.append("before the lift")
    return ", ".join(met) or "none"


# The screen (levers.md, "What its 32 scenes decide", written before binary_scored's rounds were
# read): the direction of each target, per scene against Binary on both decisive runs' 32 scenes.
SCREEN_RUNS = ((HELDOUT, "heldout_v4_decisive"), (PROCEDURAL, "procedural_v4_decisive"))
SCREEN_SCENES = 32


def screen(method: str, root: Path = REPO_ROOT) -> tuple:
    """(lines, verdict) of the screen rule for `method`: per decisive run, SR − Binary's per
    scene ≥ −3 points at 0.1 kg, > 0 at 1.5 kg, losses before the lift ≤ 1.5 × Binary's.
    verdict: "passed" (all six), "failed" (a direction missed on a run both methods finished:
    SCREEN_SCENES scenes at each weight), else "incomplete" (a report missing or a run
    unfinished; what is there is still printed). A round without an attempt (no grasp in its
    first view) has no SR, so fewer scenes may pair than ran."""
    lines, missed, complete = [], False, True
    for objects, run in SCREEN_RUNS:
        m = measure(root / RESULTS / run, method)
        if m is None or any(kg not in m["diff"] for kg in WEIGHTS_KG):
            lines.append(f"{objects}: no report of {method} against binary at {' and '.join(map(str, WEIGHTS_KG))} kg "
                         f"in {run} yet")
            complete = False
            continue
        finished = all(m["ran"][kg] >= SCREEN_SCENES for kg in WEIGHTS_KG)
        complete &= finished
        checks = []
        for kg, bound, passes in ((0.1, "≥ −3 pts", lambda d: d >= LIGHT_MIN), (1.5, "> 0 pts", lambda d: d > 0)):
            d, p, scenes = m["diff"][kg]
            checks.append(passes(d))
            lines.append(f"{objects}, {kg:g} kg: {f'{100 * d:+.1f}'.replace('-', '−')} pts per scene "
                         f"(p = {p:.2g}, {scenes} of {m['ran'][kg]} scenes pair), "
                         f"needs {bound}: {'met' if checks[-1] else 'missed'}")
        own, binary = m["losses"]
        checks.append(losses_met(m))
        lines.append(f"{objects}, before the lift: {own} lost against Binary's {binary}, needs ≤ "
                     f"{LOSS_RATIO_MAX:g} × Binary's: {'met' if checks[-1] else 'missed'}")
        missed |= finished and not all(checks)
    verdict = "failed" if missed else "passed" if complete else "incomplete"
    return lines, verdict


def _diff_cell(m: dict, kg: float) -> str:
    if kg not in m["diff"]:
        return "—"
    d, p, scenes = m["diff"][kg]
    return f"{100 * d:+.1f} pts, p = {p:.2g} ({scenes})".replace("-", "−")


def _cr_cell(m: dict) -> str:
    return " · ".join(f"{100 * m['cr'][kg][0]:.0f} / {100 * m['cr'][kg][1]:.0f} %" if kg in m["cr"] else "—"
                      for kg in WEIGHTS_KG)


MEASURED = ("Ours − Binary 0.1 kg", "Ours − Binary 1.5 kg", "lost before the lift, Ours / Binary",
            "CR 0.1 kg · 1.5 kg, Ours / Binary", "targets met")


def _header(*first: str) -> list:
    columns = first + MEASURED
    return ["| " + " | ".join(columns) + " |", "|" + " --- |" * len(columns)]


def _row(head: str, run: str | None, m: dict | None) -> str:
    if m is None:
        why = f"not run yet (`{run}`)" if run else "not run"
        return f"{head} {why} | | | | |"
    own, binary = m["losses"]
    ratio = f" (× {own / binary:.1f})" if binary else ""
    return (f"{head} {_diff_cell(m, 0.1)} | {_diff_cell(m, 1.5)} | {own} / {binary}{ratio} "
            f"| {_cr_cell(m)} | {targets_met(m)} |")


def decisive_lines(root: Path = REPO_ROOT) -> list:
    """The decisive runs, in the lever table's columns."""
    names = {LEVER: next(lever for lever, *_, method, _ in LEVERS if method == LEVER), PRODUCT: "the shipped Ours"}
    return _header("method", "objects") + [
        _row(f"| {names[method]} | {objects} |", run, measure(root / RESULTS / run, method, after))
        for method, objects, run, after in DECISIVE]


def table_lines(root: Path = REPO_ROOT) -> list:
    lines = _header("lever", "kind", "switch", "objects")
    for lever, kind, switch, method, runs in LEVERS:
        for objects in (HELDOUT, PROCEDURAL):
            run = runs.get(objects)
            lines.append(_row(f"| {lever} | {kind} | {switch} | {objects} |", run,
                              measure(root / RESULTS / run, method) if run else None))
    ceilings = []
    for objects, run in LEVERS[0][4].items():
        drops = binary_drops(root / RESULTS / run)
        if drops:
            ceilings.append(f"{objects} {drops[0]} of {drops[1]} ({100 * drops[0] / drops[1]:.1f} %)")
    if ceilings:
        lines += ["", "Binary's attempts lost after the lift at 1.5 kg (dropped in the lift, the hold or the shake), "
                  "the most a method that places as Binary does could gain by holding better: "
                  + "; ".join(ceilings) + "."]
    return lines


DOC = "sim_bridge/doc/levers.md"
# the page's generated blocks: <!-- TAG: command -->, the lines, <!-- /TAG -->
BLOCKS = (("lever-table", table_lines), ("decisive-table", decisive_lines))


def write_doc(root: Path = REPO_ROOT) -> list:
    """Rewrite levers.md's generated blocks from the committed runs; -> the tags changed.
    ValueError if the page lacks a block."""
    path = root / DOC
    text = original = path.read_text()
    changed = []
    for tag, lines in BLOCKS:
        block = re.compile(rf"(<!-- {tag}: [^>]*-->\n)(.*?)(\n<!-- /{tag} -->)", re.S)
        m = block.search(text)
        if not m:
            raise ValueError(f"{path} has no <!-- {tag}: ... --> ... <!-- /{tag} --> block")
        new = "\n".join(lines(root))
        if m.group(2) != new:
            changed.append(tag)
            text = text[:m.start(2)] + new + text[m.end(2):]
    if text != original:
        path.write_text(text)
    return changed


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--decisive", action="store_true", help="the decisive runs (the chosen lever, the shipped Ours) instead")
    p.add_argument("--write", action="store_true", help=f"rewrite both tables in {DOC} instead of printing one")
    p.add_argument("--screen", metavar="METHOD", help="apply levers.md's screen rule to METHOD on the decisive runs")
    args = p.parse_args(argv)
    if args.screen:
        lines, verdict = screen(args.screen)
        print("\n".join(lines + [f"screen_{args.screen}={verdict}"]))
        return 0
    if args.write:
        try:
            changed = write_doc()
        except ValueError as e:
            print(f"lever_table: {e}", file=sys.stderr)
            return 2
        print(f"lever_table: {DOC}: " + (", ".join(changed) + " rewritten" if changed else "up to date"))
        return 0
    print("\n".join(decisive_lines() if args.decisive else table_lines()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
