"""The benchmark's outputs: SR/CR with Wilson intervals per method and weight, each
method's SR against Binary (two-proportion test), Ours against Ours-Precision (the paper's
power-grasp effect), results.md, the summaries and the SR/CR-vs-weight plot."""

from __future__ import annotations

import dataclasses
import io
import math
import os

import numpy as np

from gravgrasp_detector import atomic_files
from gravgrasp_detector.execution.executor import GraspExecutor
from ..physics.scenes import ARRANGEMENTS
from . import failed_rounds, run_files
from .clearing import success_rates
from .paired import compare_paired, power_grasp_effect
from .protocol import OBJECTS_PER_SCENE, PROCEDURAL_SEED, SCHEMA_VERSION, drive_of, execution_name, execution_of

# statistics


def wilson_interval(successes: int, n: int, z: float = 1.959964) -> tuple:
    """95 % Wilson score interval of a binomial proportion; (nan, nan) for n = 0."""
    if n <= 0:
        return (math.nan, math.nan)
    p = successes / n
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    # exact bounds at 0 and n (the formula gives them up to rounding)
    return (0.0 if successes == 0 else max(0.0, centre - half), 1.0 if successes == n else min(1.0, centre + half))


def two_proportion_test(s1: int, n1: int, s2: int, n2: int, z: float = 1.959964) -> dict:
    """Is p1 = s1/n1 different from p2 = s2/n2? Pooled two-proportion z test, two-sided
    p value; `ci95` is Newcombe's hybrid score interval of p1 - p2 (from the two Wilson
    intervals; unlike the Wald interval it behaves at 0 % and 100 %). nan without attempts."""
    if n1 <= 0 or n2 <= 0:
        return {"diff": math.nan, "ci95": (math.nan, math.nan), "z": math.nan, "p_value": math.nan}
    p1, p2 = s1 / n1, s2 / n2
    pooled = (s1 + s2) / (n1 + n2)
    se = math.sqrt(pooled * (1 - pooled) * (1 / n1 + 1 / n2))
    z_stat = 0.0 if se == 0 else (p1 - p2) / se
    (l1, u1), (l2, u2) = wilson_interval(s1, n1, z), wilson_interval(s2, n2, z)
    d = p1 - p2
    ci = (d - math.sqrt((p1 - l1) ** 2 + (u2 - p2) ** 2), d + math.sqrt((u1 - p1) ** 2 + (p2 - l2) ** 2))
    return {"diff": d, "ci95": ci, "z": z_stat, "p_value": math.erfc(abs(z_stat) / math.sqrt(2))}


def compare_to(rows: list, reference: str = "binary") -> list:
    """SR of every other method against `reference` at each weight both ran:
    [{method, reference, mass_kg, diff, ci95, z, p_value}]."""
    ref = {r["mass_kg"]: r for r in rows if r["method"] == reference}
    out = []
    for r in rows:
        b = ref.get(r["mass_kg"])
        if r["method"] == reference or b is None:
            continue
        out.append({"method": r["method"], "reference": reference, "mass_kg": r["mass_kg"],
                    **two_proportion_test(r["successes"], r["attempts"], b["successes"], b["attempts"])})
    return out


# outputs


def summarize(rounds: list, plan: dict) -> list:
    """plan: {method: [weights]} -> one row per method and weight."""
    rows = []
    for method, weights_kg in plan.items():
        for w in weights_kg:
            rs = [r for r in rounds if r["method"] == method and r["mass_kg"] == float(w)]
            s = sum(r["successes"] for r in rs)
            a = sum(len(r["attempts"]) for r in rs)
            o = sum(r["n_objects"] for r in rs)
            sr, cr = success_rates(s, a, o)
            rows.append({"method": method, "mass_kg": float(w), "rounds": len(rs), "objects": o, "attempts": a,
                         "left_before_start": sum(len(r.get("left_before_start", [])) for r in rs),
                         "fell_off": sum(len(r["fell_off"]) for r in rs),
                         "successes": s, "SR": sr, "SR_ci95": wilson_interval(s, a),
                         "CR": cr, "CR_ci95": wilson_interval(s, o)})
    return rows


def write_outputs(out, plan, shas, ids, excluded, protocol, meshes_dir, only=None, failed=None,
                  procedural_seed=PROCEDURAL_SEED) -> list:
    """results.md, results.json, comparisons.json, attempts.json and the plot from the rounds
    on disk; `failed`: failed_rounds.load's records (listed, not counted); `procedural_seed`:
    the run's (config.json), named in the header."""
    rounds = []
    ran = run_files.rounds_file(out)
    for method, weights_kg in plan.items():
        for w in weights_kg:
            for sid in ids:
                r = ran.get(method, w, sid)
                if r is not None and r.get("model_sha256") == shas[method]:
                    rounds.append(r)
    drifted = [r for r in rounds if drive_of(r) != protocol.drive]
    if drifted:
        r = drifted[0]
        raise ValueError(f"{len(drifted)} rounds in {out} ran with the {drive_of(r)} drive (e.g. {r['method']} "
                         f"{r['mass_kg']} kg {r['scene_id']}), the run's config.json says {protocol.drive}: rounds of "
                         "different drives are never pooled; move them to their own --out")
    own = execution_of(dataclasses.asdict(protocol))
    mixed = [r for r in rounds if execution_of(r.get("execution", {})) != own]
    if mixed:
        r = mixed[0]
        raise ValueError(f"{len(mixed)} rounds in {out} ran under execution settings "
                         f"{execution_name(r.get('execution', {}))} (e.g. {r['method']} {r['mass_kg']} kg "
                         f"{r['scene_id']}), the run's config.json says {execution_name(own)}: rounds run under "
                         "different settings are never pooled; move them to their own --out")
    attempts = []
    for r in rounds:
        for i, a in enumerate(r["attempts"]):
            attempts.append({"method": r["method"], "mass_kg": r["mass_kg"], "scene_id": r["scene_id"],
                             "attempt": i + 1, "object": a["lifted"], "pose": a["pose"],
                             **attempt_scores(a, r["target"]), "rank": a["rank"], "outcome": outcome_class(a),
                             "success": a["success"], "reason": a["reason"], "mode": a.get("mode", "")})
    atomic_files.save_json(out / "attempts.json", {
        "schema_version": SCHEMA_VERSION, "attempts": attempts,
        "rounds": [{k: r[k] for k in ("method", "mass_kg", "scene_id", "objects", "n_objects", "end",
                                      "successes", "fell_off", "left_before_start", "sim_time_s")} | {"attempts": len(r["attempts"])}
                   for r in rounds]})
    losses = before_lift_losses(rounds)
    rows = [{**r, "before_lift": losses.get((r["method"], r["mass_kg"]), dict.fromkeys((*BEFORE_LIFT, "total"), 0))}
            for r in summarize(rounds, plan)]
    atomic_files.save_json(out / "results.json", rows)
    comparisons = with_paired(compare_to(rows), compare_paired(rounds))
    atomic_files.save_json(out / "comparisons.json", comparisons)
    power_effect = power_grasp_effect(rounds)
    atomic_files.save_json(out / "power_grasp_effect.json", power_effect)
    objects = (f"procedural (seed {procedural_seed})" if not meshes_dir else f"meshes in {os.path.relpath(os.path.realpath(meshes_dir))}"
               + (f", only the {len(only)} listed in --only" if only is not None else ""))
    expected = len(ids)
    lines = ["# Clutter-removal benchmark against object weight", "",
             f"Scenes: {expected} ({', '.join(ARRANGEMENTS)} alternating), {OBJECTS_PER_SCENE} objects each, "
             f"objects: {objects}; "
             f"hold {protocol.hold_s:.1f} s, shake +-{protocol.shake_m * 100:.0f} cm, grip {protocol.grip_force_n:.0f} N, "
             f"dt {protocol.time_step_s * 1e3:g} ms. SR = successes / attempts, CR = successes / objects, "
             "[95 % Wilson interval].", "",
             "| method | weight [kg] | rounds | SR | SR 95 % CI | CR | CR 95 % CI | successes / attempts / objects "
             "| left before start / fell off |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    # a method and weight with no rounds yet (or never planned: a report over several runs'
    # methods) is one line under the table, not an empty row in every table
    no_rounds = {}  # method: its weights without rounds, in the rows' order
    for r in rows:
        if not r["rounds"]:
            no_rounds.setdefault(r["method"], []).append(r["mass_kg"])
            continue
        lines.append(f"| {r['method']} | {r['mass_kg']:g} | {r['rounds']}/{expected} | {_pct(r['SR'])} | "
                     f"{_ci(r['SR_ci95'])} | {_pct(r['CR'])} | {_ci(r['CR_ci95'])} | "
                     f"{r['successes']} / {r['attempts']} / {r['objects']} | "
                     f"{r['left_before_start']} / {r['fell_off']} |")
    if no_rounds:
        lines += ["", "No rounds (not run, or not yet): " + "; ".join(
            f"{m} at {', '.join(f'{w:g}' for w in ws)} kg" for m, ws in no_rounds.items()) + "."]
    lines += ["", *comparison_lines([c for c in comparisons if c["mass_kg"] not in no_rounds.get(c["method"], ())])]
    if power_effect:
        lines += ["", *power_effect_lines(power_effect)]
    lines += ["", *outcome_lines(rounds, plan)]
    lines += ["", *mode_lines(rounds, plan)]
    if protocol.close_on_contact_within_m > 0:
        lines += ["", *guarded_lines(rounds, plan, protocol.close_on_contact_within_m)]
    lines += ["", *end_lines(rounds, plan)]
    lines += ["", *before_lift_lines(rounds, plan), ""]
    gave_up = [r for r in (failed or {}).values() if r["method"] in plan and r["model_sha256"] == shas[r["method"]]
               and r["mass_kg"] in plan[r["method"]] and r["scene_id"] in ids]
    if gave_up:
        lines += [*failed_rounds.report_lines(gave_up), ""]
    lines.append(f"Excluded objects ({len(excluded)}): " + (", ".join(
        f"{e['name']} ({e.get('min_width_mm', '?')} mm)" if "min_width_mm" in e else f"{e['name']} ({e['reason']})"
        for e in excluded) or "none"))
    lines.append(machine_line(rounds))
    atomic_files.save_bytes(out / "results.md", ("\n".join(lines) + "\n").encode())
    plot(rows, plan, out / "sr_cr_vs_weight.png")
    return rows


def with_paired(comparisons: list, paired: list) -> list:
    """The pooled comparisons, each with its per-scene paired one under "paired" (None
    where no scene has both methods' SR)."""
    by_key = {(c["method"], c["mass_kg"]): c for c in paired}
    return [{**c, "paired": by_key.get((c["method"], c["mass_kg"]))} for c in comparisons]


def comparison_lines(comparisons) -> list:
    """Markdown table: SR difference to Binary, per scene paired (which decides) and pooled."""
    if not comparisons:
        return ["No comparison with binary (it did not run at these weights)."]
    lines = ["SR against binary at the same weight. **Per scene, paired** (this decides: attempts in a round "
             "are not independent, and both methods ran the same scenes): the mean over scenes of the SR "
             "difference, a paired bootstrap 95 % interval, and a sign-flip permutation test (benchmark/paired.py). "
             "Pooled, beside it: the two-proportion z test over attempts, with Newcombe's interval.", "",
             "| method | weight [kg] | scenes | per scene: SR − SR binary | 95 % CI | p | "
             "pooled: SR − SR binary | 95 % CI | p |", "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]

    def cells(c):
        if c is None or math.isnan(c["diff"]):
            return ["—", "—", "—"]
        return [f"{100 * c['diff']:+.1f} pts", f"{100 * c['ci95'][0]:+.1f} to {100 * c['ci95'][1]:+.1f}",
                f"{c['p_value']:.3f}"]
    for c in comparisons:
        pc = c.get("paired")
        lines.append(f"| {c['method']} | {c['mass_kg']:g} | {pc['scenes'] if pc else 0} | "
                     + " | ".join(cells(pc) + cells(c)) + " |")
    return lines


def power_effect_lines(effect) -> list:
    """Markdown table: Ours − Ours-Precision per scene, paired (paired.power_grasp_effect)."""
    lines = ["The power-grasp effect: Ours against the same network trained on precision grasps only "
             "(Ours-Precision), per scene, paired, over the scenes both ran (as above).", "",
             "| weight [kg] | scenes | per scene: SR ours − SR ours_precision | 95 % CI | p |",
             "| --- | --- | --- | --- | --- |"]
    for c in effect:
        if math.isnan(c["diff"]):
            lines.append(f"| {c['mass_kg']:g} | 0 | — | — | — |")
            continue
        lines.append(f"| {c['mass_kg']:g} | {c['scenes']} | {100 * c['diff']:+.1f} pts | "
                     f"{100 * c['ci95'][0]:+.1f} to {100 * c['ci95'][1]:+.1f} | {c['p_value']:.3f} |")
    return lines


def attempt_scores(attempt: dict, target: str) -> dict:
    """{score_n, validness, rank_key} of a round's attempt record (clearing.grasp_fields).
    A record from before those fields (schema 1) has one `score` in mixed units: newtons
    for a score model, the validness it was ranked by for a binary one (the round's
    `target` says which); its score_n is then None for a binary model, and its rank_key is
    the validness for a binary model and None (not recorded: score or validness x score)
    for a score model."""
    if "score" not in attempt:
        return {k: attempt.get(k) for k in ("score_n", "validness", "rank_key")}
    binary = target == "binary"
    return {"score_n": None if binary else attempt["score"], "validness": attempt["validness"],
            "rank_key": attempt["validness"] if binary else None}


def outcome_class(attempt: dict) -> str:
    """An attempt's outcome, with the executor's `unreachable` split by where the arm's
    contact limit stopped it: `jammed_on_approach` (on the way to the pre-grasp or grasp
    pose: the open hand ran into something) or `lift_blocked` (the closed hand could not
    rise: it holds something that is held down, or presses on the table). Other
    `unreachable` attempts (a target outside the arm's reach) keep the executor's word.
    A miss whose backing out then failed is a `no_object` (the miss is what the attempt
    did; the executor answers with the back-out's failure). A contact stop is the record's
    `stopped_by_contact` (the executor's flag); records from before it (schema 1) say so
    only in the reason's words."""
    outcome, reason = attempt["outcome"], attempt.get("reason", "")
    if reason.startswith("the grasp missed the object"):
        return "no_object"
    by_contact = attempt["stopped_by_contact"] if "stopped_by_contact" in attempt else "stopped by contact" in reason
    if outcome == "unreachable" and by_contact:
        if reason.startswith(("arm could not reach the pregrasp pose", "arm could not reach the grasp pose")):
            return "jammed_on_approach"
        if reason.startswith("arm could not reach the lift"):
            return "lift_blocked"
    return outcome


def outcome_lines(rounds, plan) -> list:
    """Markdown table: how every attempt ended, per method and weight (why SR is what it is)."""
    counts = _tally(rounds, lambda r: [outcome_class(a) for a in r["attempts"]])
    outcomes = ["success", *sorted({o for row in counts.values() for o in row} - {"success"})]
    return ["Outcomes of the attempts:", "", *_count_table(counts, outcomes, plan)]


def guarded_lines(rounds, plan, within_m) -> list:
    """Markdown table: the attempts whose approach the contact stop halted within
    `within_m` of the grasp, closed there by the guarded approach, by how they ended."""
    def closed_short(r):
        return [outcome_class(a) for a in r["attempts"] if GraspExecutor.CLOSED_SHORT in a.get("reason", "")]
    counts = _tally(rounds, closed_short)
    outcomes = ["success", *sorted({o for row in counts.values() for o in row} - {"success"})]
    return [f"Closed where the arm's contact stop halted the approach, at most {within_m * 1e3:g} mm short "
            "(the guarded approach), by how they ended:", "", *_count_table(counts, outcomes, plan)]


def end_lines(rounds, plan) -> list:
    """Markdown table: why each round ended, per method and weight (a round that ends
    with objects left lowers CR; no_feasible_grasp: every detected grasp failed the
    executor's own checks)."""
    counts = _tally(rounds, lambda r: [r["end"]])
    ends = sorted({e for row in counts.values() for e in row})
    return ["How the rounds ended:", "", *_count_table(counts, ends, plan)]


BEFORE_LIFT = ("closed_on_nothing", "contact_stops", "rounds_all_refused")
AFTER_LIFT = ("dropped", "dropped_in_hold", "dropped_in_shake")  # outcome classes: placed, lifted, then lost
# the outcome classes of an attempt lost before the lift, and the BEFORE_LIFT count each adds to
ATTEMPT_LOSSES = {"no_object": "closed_on_nothing", "jammed_on_approach": "contact_stops",
                  "lift_blocked": "contact_stops"}


def before_lift_losses(rounds) -> dict:
    """{(method, kg): {closed_on_nothing, contact_stops, rounds_all_refused, total}}: the
    attempts lost before the lift: closes on nothing (`no_object`), the
    arm's contact stop on the approach or at the lift (`jammed_on_approach`,
    `lift_blocked`), and rounds that ended with every detected grasp refused by the
    executor (`no_feasible_grasp`)."""
    def losses(r):
        return ([ATTEMPT_LOSSES[c] for c in map(outcome_class, r["attempts"]) if c in ATTEMPT_LOSSES]
                + ["rounds_all_refused"] * (r["end"] == "no_feasible_grasp"))
    counts = _tally(rounds, losses)
    for r in rounds:  # a method and weight with no loss still has its row
        counts.setdefault((r["method"], float(r["mass_kg"])), {})
    return {key: {**{c: row.get(c, 0) for c in BEFORE_LIFT}, "total": sum(row.values())}
            for key, row in counts.items()}


def before_lift_lines(rounds, plan, reference: str = "binary") -> list:
    """Markdown table: before_lift_losses per method and weight, and over each method's
    weights that `reference` ran too, with the ratio to the reference's."""
    losses = before_lift_losses(rounds)
    lines = ["Attempts lost before the lift: closed on nothing, stopped by the arm's contact limit on the approach "
             f"or at the lift, rounds ended with every detected grasp refused (× {reference}: the ratio to "
             f"{reference}'s at the same weights):", "",
             "| method | weight [kg] | closed on nothing | contact stops | rounds all refused | total | "
             f"× {reference} |", "| --- | --- | --- | --- | --- | --- | --- |"]

    def ratio(own, ref):
        return "—" if ref is None else (f"{own / ref['total']:.1f}" if ref["total"] else "∞" if own else "—")
    for method, weights_kg in plan.items():
        rows = [(w, losses[(method, float(w))]) for w in weights_kg if (method, float(w)) in losses]
        for w, row in rows:
            ref = losses.get((reference, float(w)))
            lines.append(f"| {method} | {w:g} | " + " | ".join(str(row[c]) for c in (*BEFORE_LIFT, "total"))
                         + f" | {ratio(row['total'], None if method == reference else ref)} |")
        shared = [(w, row) for w, row in rows if (reference, float(w)) in losses]
        if method != reference and len(shared) > 1:
            own = {c: sum(row[c] for _, row in shared) for c in (*BEFORE_LIFT, "total")}
            ref = {"total": sum(losses[(reference, float(w))]["total"] for w, _ in shared)}
            lines.append(f"| {method} | all ({', '.join(f'{w:g}' for w, _ in shared)}) | "
                         + " | ".join(str(own[c]) for c in (*BEFORE_LIFT, "total")) + f" | {ratio(own['total'], ref)} |")
    return lines


def machine_line(rounds) -> str:
    """Which machine types ran the rounds (a round replays exactly only on its own type)."""
    counts = _tally(rounds, lambda r: [r.get("machine", "not recorded")])
    total = {}
    for row in counts.values():
        for name, n in row.items():
            total[name] = total.get(name, 0) + n
    return "Rounds by machine: " + (", ".join(f"{name} ({n})" for name, n in sorted(total.items())) or "none")


def _tally(rounds, labels_of) -> dict:
    """{(method, kg): {label: count}} over the labels `labels_of(round)` lists."""
    counts = {}
    for r in rounds:
        row = counts.setdefault((r["method"], float(r["mass_kg"])), {})
        for label in labels_of(r):
            row[label] = row.get(label, 0) + 1
    return counts


def _count_table(counts, columns, plan) -> list:
    lines = ["| method | weight [kg] | " + " | ".join(columns) + " |", "| --- | --- |" + " --- |" * len(columns)]
    for method, weights_kg in plan.items():
        for w in weights_kg:
            row = counts.get((method, float(w)))
            if row:
                lines.append(f"| {method} | {w:g} | " + " | ".join(str(row.get(c, 0)) for c in columns) + " |")
    return lines


def mode_lines(rounds, plan) -> list:
    """Markdown table: the grasp mode of what was in the hand after the lift (from the
    contacts) and how often each mode then came through the hold and shake."""
    counts = {}
    for r in rounds:
        row = counts.setdefault((r["method"], float(r["mass_kg"])), {})
        for a in r["attempts"]:
            if a.get("mode"):
                held, ok = row.get(a["mode"], (0, 0))
                row[a["mode"]] = (held + 1, ok + bool(a["success"]))
    lines = ["Grasp mode of what the hand lifted, and how many of those then held (successes / lifted):", "",
             "| method | weight [kg] | power | precision |", "| --- | --- | --- | --- |"]
    for method, weights_kg in plan.items():
        for w in weights_kg:
            if (method, float(w)) not in counts:  # no rounds there (listed under the first table)
                continue
            row = counts[(method, float(w))]
            cells = [f"{row[m][1]} / {row[m][0]}" if m in row else "0 / 0" for m in ("power", "precision")]
            lines.append(f"| {method} | {w:g} | " + " | ".join(cells) + " |")
    return lines


def _pct(x):
    return "—" if math.isnan(x) else f"{100 * x:.1f} %"


def _ci(ci):
    return "—" if math.isnan(ci[0]) else f"{100 * ci[0]:.1f}–{100 * ci[1]:.1f} %"


def plot(rows, methods, path):
    # lazy: matplotlib; every round's worker process imports this module
    # (through rounds) and never plots; only the parent draws this one figure.
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for ax, key in zip(axes, ("SR", "CR")):
        for method in methods:
            rs = [r for r in rows if r["method"] == method and not math.isnan(r[key])]
            if not rs:
                continue
            x = np.array([r["mass_kg"] for r in rs])
            y = np.array([r[key] for r in rs])
            lo = y - np.array([r[f"{key}_ci95"][0] for r in rs])
            hi = np.array([r[f"{key}_ci95"][1] for r in rs]) - y
            ax.errorbar(x, 100 * y, yerr=100 * np.vstack([lo, hi]), marker="o", capsize=3, label=method)
        ax.set_xlabel("object weight [kg]")
        ax.set_ylabel(f"{key} [%]")
        ax.set_ylim(-2, 102)  # points at 0 % and 100 % stay visible
        ax.grid(alpha=0.3)
    axes[0].set_title("success ratio")
    axes[1].set_title("clear ratio")
    if axes[1].get_legend_handles_labels()[0]:  # a run with no attempts yet has nothing to name
        axes[1].legend(fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    atomic_files.save_bytes(path, buf.getvalue())
