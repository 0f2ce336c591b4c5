"""Would the grasps the executor refuses for collision have held? (execution truthfulness)

Before any motion the executor checks the open hand, at the pre-grasp pose and swept along
the approach to the grasp pose, against the occupied voxels of the TSDF
(gravgrasp_detector.perception.hand_clearance); the benchmark then tries the next-ranked grasp. On
the held-out meshes one attempt of Ours in six started below a refused grasp (Binary's:
one in seventy), and the soak's top grasp was refused for 3 voxels in a fingertip. Too
strict a check throws away the network's best grasps; too loose a one lets the hand jam.
This study measures which, on a benchmark run's scenes:

1. each scene's first view as the benchmark's round saw it: the scene at the weight,
   settled, and the method's ranked grasps;
2. each of the top --top grasps that the executor refuses for collision alone (the
   workspace, cone and reach checks pass) is executed anyway, in a fresh copy of the
   settled scene, without the TSDF check, and judged as the benchmark judges
   (`report.outcome_class`: `jammed_on_approach` is the arm's 60 N contact stop);
3. the comparison is the grasp the benchmark did execute first (the best-ranked one
   that passes): its outcome is read from the benchmark's round of the same model, or
   executed here when there is none.

    python -m sim_bridge.studies.refusal_study --bench sim_bridge/results/heldout_v4 \\
        --method ours --model models/gravgrasp.pt --weights 1.5,0.1 --out sim_bridge/results/refusal_study/heldout_v4

One JSON per scene and weight under --out/scenes (a rerun resumes), summary.json beside
it; the last line printed is `refused_success_fraction=` (successes among the executed
refused grasps).
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
from gravgrasp_detector.execution.executor import plan_poses
from gravgrasp_detector.perception.hand_clearance import collisions
from gravgrasp_detector.perception.model_file import file_sha256

from ..benchmark import run_files
from ..benchmark.clearing import Refused, grasp_fields
from ..benchmark.clutter_benchmark import parse_weights
from ..benchmark.methods import METHODS
from ..benchmark.protocol import Protocol, weight_key
from ..benchmark.report import outcome_class
from ..benchmark.rounds import RoundTask, make_cell
from ..parallel import make_executor, run_tasks
from . import detection_levers  # noqa: F401  (registers the lever methods: rounds name them)

COLLISION = "the open hand collides"  # hand_clearance.first_collision's refusals start so
# voxel counts of a refused hand, binned for the summary: a hand grazing a surface's
# truncation band has a few, a hand driven through an object dozens
VOXEL_BINS = ((1, 3), (4, 10), (11, None))


@dataclasses.dataclass(frozen=True)
class SceneTask:
    round: RoundTask
    top: int
    baseline: dict | None  # the benchmark round's first attempt (same model), if any


def bin_name(lo, hi) -> str:
    return f"{lo}-{hi}" if hi else f">={lo}"


def voxel_bin(n: int) -> str:
    return next(bin_name(lo, hi) for lo, hi in VOXEL_BINS if n >= lo and (hi is None or n <= hi))


def settled_view(task: RoundTask):
    """(SimCell, tsdf, ranked grasps) of the round's first view."""
    cell, _ = make_cell(task)
    cell.settle()
    cell.remove_fallen()
    tsdf, grasps = cell.detect()
    return cell, tsdf, grasps


def judged(cell, grasp, tsdf) -> dict:
    """Execute `grasp` in `cell` (tsdf None: without the collision check) -> its outcome."""
    try:
        attempt = cell.execute(grasp, tsdf)
    except Refused as e:
        return {"outcome": "refused", "reason": str(e)}
    return {"outcome": outcome_class(attempt), "reason": attempt["reason"], "mode": attempt["mode"]}


def run_scene(task: SceneTask) -> dict:
    """Worker: one scene at one weight -> a JSON-able record."""
    torch.set_num_threads(1)
    t0 = time.process_time()
    cell, tsdf, grasps = settled_view(task.round)
    candidates, first_accepted = [], None
    for rank, g in enumerate(grasps):
        if rank >= task.top and first_accepted is not None:
            break
        why = cell.feasible(g, tsdf)
        if not why and first_accepted is None:
            first_accepted = rank
        if rank >= task.top:
            continue
        poses = plan_poses(g.pose, cell.limits.pregrasp_distance_m, cell.limits.lift_height_m)
        hits = collisions(poses, tsdf)
        swept = hits.get("approach and grasp pose", hits.get("pre-grasp pose", {}))  # the sweep holds the pre-grasp
        verdict = "accepted" if not why else "collision" if why.startswith(COLLISION) else "other"
        candidates.append({"rank": rank, "verdict": verdict, "refusal": why, "voxels": sum(swept.values()),
                           "parts": swept, **grasp_fields(g),
                           "pose": np.asarray(g.pose).round(6).tolist()})
    for c in candidates:
        if c["verdict"] == "collision":
            fresh, fresh_tsdf, fresh_grasps = settled_view(task.round)
            c["same_view"] = bool(np.array_equal(fresh_tsdf[0], tsdf[0]))
            c.update(judged(fresh, fresh_grasps[c["rank"]] if c["same_view"] else grasps[c["rank"]], None))
    record = {"scene_id": task.round.scene["scene_id"], "mass_kg": task.round.mass_kg, "method": task.round.method,
              "grasps_detected": len(grasps), "candidates": candidates, "first_accepted_rank": first_accepted}
    if first_accepted is None:
        record["baseline"] = None
    elif task.baseline is not None:
        same = task.baseline["rank"] == first_accepted and np.allclose(
            task.baseline["pose"], np.asarray(grasps[first_accepted].pose).round(6), atol=1e-5)
        record["baseline"] = {"rank": task.baseline["rank"], "outcome": outcome_class(task.baseline),
                              "from": "benchmark round", "same_grasp_as_here": bool(same)}
    else:
        fresh, fresh_tsdf, fresh_grasps = settled_view(task.round)
        record["baseline"] = {"rank": first_accepted, **judged(fresh, fresh_grasps[first_accepted], fresh_tsdf),
                              "from": "executed here"}
    record["cpu_s"] = round(time.process_time() - t0, 1)
    return record


def _guarded(task):
    try:
        return run_scene(task)
    except Exception as e:  # Drake, a bad object: reported, retried by a rerun
        return {"error": f"{type(e).__name__}: {str(e).strip()[:300]}"}


def summarize(records: list) -> dict:
    """{weight key: {"refused": {voxel bin: {outcome: count}}, "baseline": {outcome: count},
    "scenes": n, "scenes_with_refusal": n}}"""
    out = {}
    for r in records:
        cell = out.setdefault(weight_key(r["mass_kg"]), {"refused": {}, "baseline": {}, "scenes": 0,
                                                         "scenes_with_refusal": 0})
        cell["scenes"] += 1
        refused = [c for c in r["candidates"] if c["verdict"] == "collision"]
        cell["scenes_with_refusal"] += bool(refused)
        for c in refused:
            counts = cell["refused"].setdefault(voxel_bin(c["voxels"]), {})
            counts[c["outcome"]] = counts.get(c["outcome"], 0) + 1
        if r["baseline"] is not None:
            o = r["baseline"]["outcome"]
            cell["baseline"][o] = cell["baseline"].get(o, 0) + 1
    return out


def summary_lines(summary: dict) -> list:
    outcomes = sorted({o for w in summary.values() for counts in [*w["refused"].values(), w["baseline"]]
                       for o in counts} - {"success"})
    head = ["success", *outcomes]
    lines = ["| weight [kg] | grasps | occupied voxels in the hand | n | " + " | ".join(head) + " |",
             "| --- | --- | --- | ---: |" + " ---: |" * len(head)]
    for w, cell in sorted(summary.items(), key=lambda kv: float(kv[0])):
        rows = [(f"refused for collision ({cell['scenes_with_refusal']} of {cell['scenes']} scenes)",
                 bin_name(lo, hi), cell["refused"].get(bin_name(lo, hi), {})) for lo, hi in VOXEL_BINS]
        rows.append(("first accepted (the benchmark's pick)", "0", cell["baseline"]))
        for what, bin_, counts in rows:
            lines.append(f"| {w} | {what} | {bin_} | {sum(counts.values())} | "
                         + " | ".join(str(counts.get(o, 0)) for o in head) + " |")
    return lines


def baseline_of(bench: pathlib.Path, method: str, sha: str, mass_kg: float, scene_id: str):
    """The benchmark round's first attempt if that round ran this model and made one."""
    r = run_files.rounds_file(bench).get(method, mass_kg, scene_id)
    if r is None:
        return None
    return r["attempts"][0] if r.get("model_sha256") == sha and r["attempts"] else None


def records_file(out) -> run_files.RecordFile:
    """The study's records in `out`, one per scene and weight: rounds.jsonl (older runs:
    scenes/<scene>_<kg>.json)."""
    out = pathlib.Path(out)
    return run_files.RecordFile(out / run_files.ROUNDS, ("scene_id", "mass_kg"), out / "scenes")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--bench", required=True, help="a benchmark's --out directory (its config.json, scenes and rounds)")
    p.add_argument("--method", default="ours", help="the benchmark method whose detection is studied")
    p.add_argument("--model", default=None, help="its model file (default: models/ by the benchmark's name)")
    p.add_argument("--weights", default="1.5", help="comma-separated object weights [kg]")
    p.add_argument("--top", type=int, default=5, help="ranked grasps looked at per scene")
    p.add_argument("--out", required=True, help="output directory (resumes there)")
    p.add_argument("--workers", type=int, default=None, help="local processes (default: CPU count)")
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    err = lambda m: print(f"refusal_study: {m}", file=sys.stderr) or 2  # noqa: E731
    bench = pathlib.Path(args.bench)
    try:
        weights = parse_weights(args.weights)
    except ValueError as e:
        return err(f"--{e}")
    if args.top < 1:
        return err(f"--top {args.top}: give at least 1")
    scenes = run_files.scenes_file(bench).records()
    if not (bench / "config.json").is_file() or not scenes:
        return err(f"{bench} holds no benchmark run (config.json and its scenes): give a benchmark's --out")
    if args.method not in METHODS:
        return err(f"unknown --method {args.method!r}: use {', '.join(METHODS)}")
    model = pathlib.Path(args.model or METHODS[args.method].default_path())
    if not model.is_file():
        return err(f"model file {model} not found: give --model")
    protocol = Protocol(**json.loads((bench / "config.json").read_text())["protocol"])
    sha = file_sha256(model)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_files.remove_stale_temporaries(out)
    studied = records_file(out)

    def record_of(t: SceneTask):
        return studied.get(t.round.scene["scene_id"], t.round.mass_kg)

    tasks = [SceneTask(RoundTask(args.method, str(model.resolve()), sha, w, s, protocol), args.top,
                       baseline_of(bench, args.method, sha, w, s["scene_id"])) for w in weights for s in scenes]
    def done(t):  # a record of another model or --top is redone
        return record_of(t) is not None and {k: record_of(t).get(k) for k in ("model_sha256", "top")} \
            == {"model_sha256": sha, "top": args.top}

    pending = [t for t in tasks if not done(t)]
    errors = []

    def on_result(task, result):
        if "error" in result:
            errors.append(f"{task.round.scene['scene_id']} at {weight_key(task.round.mass_kg)} kg: {result['error']}")
        else:
            studied.put({"model_sha256": sha, "top": args.top, **result})

    if pending:
        with make_executor(args.workers) as ex:
            run_tasks(ex, _guarded, pending, on_result, desc="scenes", progress=not args.no_progress)
    for e in errors:
        print(f"refusal_study: {e}", file=sys.stderr)
    records = [record_of(t) for t in tasks if done(t)]
    summary = summarize(records)
    atomic_files.save_json(out / "summary.json", {"bench": str(bench), "method": args.method, "model_sha256": sha,
                                                  "top": args.top, "weights_kg": weights, "summary": summary})
    print("\n".join(summary_lines(summary)))
    executed = [c for r in records for c in r["candidates"] if c["verdict"] == "collision"]
    held = sum(c["outcome"] == "success" for c in executed)
    print(f"refused_success_fraction={held / max(len(executed), 1):.3f}")
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
