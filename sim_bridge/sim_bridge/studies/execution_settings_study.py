"""Do cheaper execution settings change what the benchmark decides? (benchmark speed)

A round's CPU is almost all Drake stepping every object at 1 ms (sim_bridge/doc/
benchmark-speed.md). `protocol.EXECUTION_SETTINGS` names cheaper ways to simulate the same
protocol (objects at rest frozen, a faster lift). This study checks them attempt by
attempt, paired, on committed benchmark rounds:

1. each round is replayed under the settings it was run with (the committed config.json;
   rounds are deterministic, so the replay's grasps are the round's);
2. before each attempt, the whole simulation state is saved (Drake context, the world's
   and executor's own state); the attempt's grasp is executed under each new setting from
   that state, and the state is restored;
3. then the attempt runs under the old settings, and the round goes on from there.

So every new-settings attempt starts from exactly the scene and grasp the old one did,
and its outcome (success, dropped, no_object, ...) is compared with the old one's. CPU
and simulated time are measured for each, side by side, on the same machine.

The arm `NUDGED` is the noise floor: the old settings, the grasp moved 30 um across the
pads (a UR5e's rated repeatability). An outcome that flips under it is not decided by the
method nor by the settings, so a setting is judged against how often the old settings
disagree with themselves.

    python -m sim_bridge.studies.execution_settings_study --out sim_bridge/results/execution_settings_study

One JSON per round under --out/rounds (a rerun resumes), the summary in
--out/../execution_settings_study.json; the last line printed is `outcome_agreement=`
(the lowest over the settings studied).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import sys
import time

import numpy as np
import torch

from gravgrasp_detector import atomic_files
from gravgrasp_detector.perception.model_file import file_sha256

from ..benchmark import run_files
from ..benchmark.clearing import Refused, clear_table
from ..benchmark.methods import method_named
from ..benchmark.protocol import EXECUTION_SETTINGS, Protocol, weight_key, with_execution
from ..benchmark.rounds import RoundTask, make_cell
from ..parallel import make_executor, run_tasks
from . import detection_levers  # noqa: F401  (registers the lever methods: rounds name them)

# The committed rounds the study replays: (results dir, method, weight kg, scenes). The
# held-out tuning meshes (models/vgn_heldout_meshes.txt), both methods, both ends of the
# weight range; ~120 attempts.
DEFAULT_ROUNDS = (
    ("sim_bridge/results/heldout_v4_a47ba91", "ours", 1.5, ("packed_000", "pile_000", "packed_001", "pile_001",
                                                           "packed_002", "pile_002", "packed_003")),
    ("sim_bridge/results/heldout_v4_a47ba91", "binary", 1.5, ("packed_000", "pile_000", "packed_001", "pile_001",
                                                             "packed_002", "pile_002", "packed_003", "pile_003")),
    ("sim_bridge/results/heldout_v4", "ours", 0.1, ("packed_000", "pile_000", "packed_001", "pile_001",
                                                    "packed_002", "pile_002", "packed_003", "pile_003")),
    ("sim_bridge/results/heldout_v4", "binary", 0.1, ("packed_000", "pile_000", "packed_001", "pile_001",
                                                      "packed_002", "pile_002", "packed_003", "pile_003")),
)
STUDIED = ("fast",)
NUDGED = "v4_nudged"  # the old settings, the grasp moved NUDGE_M along its x axis
NUDGE_M = 30e-6


def nudged(grasp):
    """`grasp` moved NUDGE_M along its own x (across the pads: the closing is along y)."""
    pose = np.array(grasp.pose, dtype=float)
    pose[:3, 3] += NUDGE_M * pose[:3, 0]
    return dataclasses.replace(grasp, pose=pose)


def settings_of(name: str) -> dict:
    return EXECUTION_SETTINGS["v4"] if name == NUDGED else EXECUTION_SETTINGS[name]


@dataclasses.dataclass(frozen=True)
class StudyRound:
    results_dir: str
    task: RoundTask
    recorded_outcomes: tuple
    settings: tuple  # names in EXECUTION_SETTINGS


def round_protocol(config: dict) -> Protocol:
    """The Protocol a committed run's config.json describes."""
    return Protocol(**config["protocol"])


def _switch(cell, protocol: Protocol):
    """Run the cell's next attempt under `protocol`'s execution settings."""
    w = cell.world
    cell.protocol = protocol
    cell.limits = dataclasses.replace(cell.limits, lift_speed_mps=protocol.lift_speed_mps,
                                      approach_fast_speed_mps=protocol.approach_fast_speed_mps)
    cell.executor.limits = cell.limits
    w.freeze_resting_objects(protocol.freeze_resting_objects)


def _timed(cell, fn):
    t0, s0 = time.process_time(), cell.world.time_s
    result = fn()
    return result, round(time.process_time() - t0, 2), round(cell.world.time_s - s0, 3)


def study_round(sr: StudyRound) -> dict:
    torch.set_num_threads(1)
    t_start = time.process_time()
    cell, _ = make_cell(sr.task)
    old = sr.task.protocol
    execute, attempts = cell.execute, []

    def paired_execute(grasp, tsdf):
        checkpoint = cell.checkpoint()
        new = {}
        for name in sr.settings:
            _switch(cell, old if name == NUDGED else with_execution(old, name))
            g = nudged(grasp) if name == NUDGED else grasp
            try:
                result, cpu_s, sim_s = _timed(cell, lambda: execute(g, tsdf))
            except Refused:  # the same checks refuse under every setting
                cell.rewind(checkpoint)
                raise
            except Exception as e:
                result, cpu_s, sim_s = {"outcome": f"error: {type(e).__name__}: {e}"[:200]}, None, None
            new[name] = {"outcome": result["outcome"], "cpu_s": cpu_s, "sim_s": sim_s,
                         "reason": result.get("reason", "")[:200]}
            cell.rewind(checkpoint)
        _switch(cell, old)
        result, cpu_s, sim_s = _timed(cell, lambda: execute(grasp, tsdf))
        n = len(attempts)
        attempts.append({"attempt": n + 1, "recorded": sr.recorded_outcomes[n] if n < len(sr.recorded_outcomes) else None,
                         "old": {"outcome": result["outcome"], "cpu_s": cpu_s, "sim_s": sim_s,
                                 "reason": result["reason"][:200]},
                         "new": new, **{k: result[k] for k in ("score_n", "validness", "rank_key")}})
        return result

    cell.execute = paired_execute
    cell.settle()
    cell.remove_fallen()
    clear_table(cell, len(cell.objects_on_table()), old.attempts_per_object)
    return {"results_dir": sr.results_dir, "method": sr.task.method, "mass_kg": sr.task.mass_kg,
            "scene_id": sr.task.scene["scene_id"], "settings": {n: settings_of(n) for n in sr.settings},
            "old_settings": {k: getattr(old, k) for k in EXECUTION_SETTINGS["v4"]},
            "attempts": attempts, "cpu_s": round(time.process_time() - t_start, 1)}


def _guarded(sr):
    try:
        return study_round(sr)
    except Exception as e:
        return {"error": f"{type(e).__name__}: {str(e)[:300]}"}


def plan(rounds=DEFAULT_ROUNDS, settings=STUDIED, models_dir="models", methods=None) -> list:
    """StudyRounds of the committed rounds; ValueError (one line) for a missing round or model."""
    out = []
    # Interleaved (the first scene of every group, then the second, ...): a study cut
    # short has every method and weight.
    order = sorted(((k, g) for g, (*_, scenes) in enumerate(rounds) for k in range(len(scenes))))
    for k, g in order:
        results_dir, method, mass_kg, scenes = rounds[g]
        if methods is not None and method not in methods:
            continue
        sid = scenes[k]
        d = pathlib.Path(results_dir)
        config = json.loads((d / "config.json").read_text())
        model = method_named(method).default_path(models_dir)
        sha = file_sha256(model)
        rec = run_files.rounds_file(d).get(method, mass_kg, sid)
        rf = f"{d}'s round of {method} at {weight_key(mass_kg)} kg on {sid}"
        if rec is None:
            raise ValueError(f"no committed round: {rf}")
        if rec["model_sha256"] != sha:
            raise ValueError(f"{model} is not the model of {rf} (sha256 {rec['model_sha256'][:12]}…)")
        scene = run_files.scenes_file(d).get(sid)
        task = RoundTask(method, str(model), sha, float(mass_kg), scene, round_protocol(config))
        out.append(StudyRound(str(d), task, tuple(a["outcome"] for a in rec["attempts"]), tuple(settings)))
    return out


def summarize(records: list, settings) -> dict:
    pairs = [a for r in records for a in r["attempts"]]
    summary = {"rounds": len(records), "attempts": len(pairs),
               "replay_matched_recorded": sum(a["old"]["outcome"] == a["recorded"] for a in pairs), "settings": {}}
    for name in settings:
        rows = [a for a in pairs if name in a["new"]]
        differ = [{"round": f"{r['method']} {r['mass_kg']} kg {r['scene_id']}", "attempt": a["attempt"],
                   "old": a["old"]["outcome"], "new": a["new"][name]["outcome"]}
                  for r in records for a in r["attempts"] if a["new"][name]["outcome"] != a["old"]["outcome"]]
        same_success = sum((a["new"][name]["outcome"] == "success") == (a["old"]["outcome"] == "success")
                           for a in rows)
        by_method = {}
        for r in records:
            m = by_method.setdefault(f"{r['method']}@{r['mass_kg']}", {"old_successes": 0, "new_successes": 0,
                                                                       "attempts": 0})
            for a in r["attempts"]:
                m["attempts"] += 1
                m["old_successes"] += a["old"]["outcome"] == "success"
                m["new_successes"] += a["new"][name]["outcome"] == "success"
        cpu_old = sum(a["old"]["cpu_s"] for a in rows)
        cpu_new = sum(a["new"][name]["cpu_s"] or 0.0 for a in rows)
        summary["settings"][name] = {
            **settings_of(name), "attempts": len(rows),
            "outcome_agreement": round((len(rows) - len(differ)) / len(rows), 4) if rows else None,
            "success_agreement": round(same_success / len(rows), 4) if rows else None,
            "attempt_cpu_ratio": round(cpu_new / cpu_old, 3) if cpu_old else None,
            "attempt_sim_s_old": round(sum(a["old"]["sim_s"] for a in rows), 1),
            "attempt_sim_s_new": round(sum(a["new"][name]["sim_s"] or 0.0 for a in rows), 1),
            "by_method_weight": by_method, "differing": differ}
    return summary


def markdown(summary: dict) -> str:
    """The summary as the tables of sim_bridge/doc/benchmark-speed.md."""
    lines = [f"{summary['rounds']} rounds, {summary['attempts']} attempts; the v4 replay gave the committed "
             f"outcome in {summary['replay_matched_recorded']} of them.", ""]
    for name, s in summary["settings"].items():
        what = (f"v4's settings, the grasp moved {NUDGE_M * 1e6:.0f} um: the noise floor" if name == NUDGED else
                ", ".join(f"{k} {v}" for k, v in EXECUTION_SETTINGS[name].items()))
        lines += [f"**{name}** ({what}): "
                  f"outcome agreement **{s['outcome_agreement']}**, success agreement {s['success_agreement']}, "
                  f"CPU {s['attempt_cpu_ratio']} of v4's on the same attempts, simulated time "
                  f"{s['attempt_sim_s_new']} s against {s['attempt_sim_s_old']} s.", "",
                  "| method @ kg | attempts | successes v4 | successes new |", "|---|---|---|---|"]
        for key, m in sorted(s["by_method_weight"].items()):
            lines.append(f"| {key} | {m['attempts']} | {m['old_successes']} | {m['new_successes']} |")
        lines += ["", "| round | attempt | v4 | new |", "|---|---|---|---|"]
        lines += [f"| {d['round']} | {d['attempt']} | {d['old']} | {d['new']} |" for d in s["differing"]] or ["| (none) | | | |"]
        lines.append("")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("--out", default="sim_bridge/results/execution_settings_study")
    p.add_argument("--settings", default=",".join(STUDIED),
                   help=f"execution settings to compare with the rounds' own ({', '.join(EXECUTION_SETTINGS)}), "
                        f"or {NUDGED}: the rounds' own with the grasp moved {NUDGE_M * 1e6:.0f} um (the noise floor)")
    p.add_argument("--methods", help="study only these methods' rounds (comma-separated; default: all of the plan's)")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--max-rounds", type=int, help="study only the first N rounds of the plan")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--report", action="store_true", help="run nothing: summarize the rounds finished so far")
    args = p.parse_args(argv)
    settings = tuple(s for s in args.settings.split(",") if s)
    try:
        for s in settings:
            if s != NUDGED:
                with_execution(Protocol(), s)
        methods = set(args.methods.split(",")) if args.methods else None
        rounds = plan(settings=settings, methods=methods)[:args.max_rounds]
    except (ValueError, OSError) as e:
        print(f"execution_settings_study: {e}", file=sys.stderr)
        return 2
    out = pathlib.Path(args.out)
    studied = run_files.study_rounds_file(out, run_files.ROUND_KEY)

    def record_of(sr):
        return studied.get(sr.task.method, sr.task.mass_kg, sr.task.scene["scene_id"])

    def on_result(sr, result):
        if "error" in result:
            print(f"execution_settings_study: {sr.task.method} {sr.task.mass_kg} kg "
                  f"{sr.task.scene['scene_id']} failed: {result['error']}", file=sys.stderr)
        else:
            studied.put(result)

    pending = [] if args.report else [sr for sr in rounds if record_of(sr) is None]
    if pending:
        with make_executor(args.workers) as ex:
            run_tasks(ex, _guarded, pending, on_result, desc="rounds", progress=not args.no_progress)
    records = [record_of(sr) for sr in rounds if record_of(sr) is not None]
    summary = summarize(records, settings)
    atomic_files.save_json(out.parent / f"{out.name}.json", summary)
    print(markdown(summary))
    agreements = [s["outcome_agreement"] for s in summary["settings"].values() if s["outcome_agreement"] is not None]
    print(f"outcome_agreement={min(agreements) if agreements else float('nan')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
