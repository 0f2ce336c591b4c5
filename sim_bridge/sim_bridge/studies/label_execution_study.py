"""Do the labels execute? (issue 16, item 2: labels and execution must agree.)

A label says "the grasp at this voxel holds, with gravity-rejection score f_g [N]". This
study executes a sample of a scene directory's labels the way the clutter benchmark
executes a detected grasp, and counts what happens, per grasp mode and object weight:

1. the label's scene is rebuilt in the benchmark's Drake cell (`SimCell`: its objects at
   their settled poses, every mass set to the weight) and settled at that weight;
2. one depth image from the benchmark's fixed camera gives the TSDF the executor checks;
3. the grasp is the pose detection would publish for the label: its voxel centre and
   rotation (a perfect network);
4. the executor's own checks (`Refused`: workspace, cone, open hand against the TSDF),
   then pre-grasp, approach at 5 cm/s, close at 40 N, lift 15 cm, hold 1 s and shake,
   judged by ground truth; `jammed_on_approach` and `lift_blocked` are the arm's 60 N
   contact stop (benchmark.report.outcome_class).

A label whose object moved more than MOVED_MM while the scene settled at the weight no
longer describes the scene (a pile shifts at 1.5 kg): it is counted as `moved`, apart.
Among labels with f_g >= m g the success rate says whether "holds this weight" is true.

    python -m sim_bridge.studies.label_execution_study --scenes out/scenes_v3 \
        --objects models/grasp_tables_v2 --meshes ../shared/meshes/vgn_train \
        --out out/label_execution/v3 [--per-mode 40] [--weights 0.1,1.5]

One JSON per executed label under --out/attempts (a rerun resumes), summary.json beside
it; the last line printed is `approach_failure_fraction=` (jammed on the approach or lift
blocked, over all executed labels that did not move).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import sys
import time

import numpy as np

from gravgrasp_detector import atomic_files
from gravgrasp_detector.perception.detection import Grasp
from gravgrasp_detector.training.scenes import G_MPS2  # the binary target's m g
from gravgrasp_detector.perception.tsdf import TSDFVolume

from ..benchmark.clearing import Refused
from ..benchmark.protocol import Protocol, weight_key
from ..benchmark.report import outcome_class
from ..benchmark.sim_cell import SimCell
from ..datagen.object_grasps import MODE_NAMES, load_table
from ..datagen.object_sources import source_from_table
from ..datagen.voxel_labels import RESOLUTION, label_poses
from ..parallel import make_executor, run_tasks
from ..physics.scenes import VOLUME_SIZE_M

MOVED_MM = 5.0  # the labelled object moved more than this in the settle: the label is stale
APPROACH_FAILURES = ("jammed_on_approach", "lift_blocked")


@dataclasses.dataclass(frozen=True)
class LabelTask:
    scene_path: str
    label: int          # row of the scene's labels
    mass_kg: float
    objects_dir: str    # <objects out>/objects
    mesh_dirs: tuple


def sample_labels(scene_dir, per_mode: int, seed: int, max_scenes: int = 0) -> list:
    """[(scene path, label row)]: up to `per_mode` labels of each grasp mode, drawn
    uniformly over all labels of the first `max_scenes` scenes (0: all), sorted."""
    files = sorted((pathlib.Path(scene_dir) / "scenes").glob("*.npz"))[:max_scenes or None]
    if not files:
        raise ValueError(f"no scenes in {pathlib.Path(scene_dir) / 'scenes'}: give a scene stage output directory")
    pool = {}
    for path in files:
        with np.load(path) as z:
            for row, mode in enumerate(z["label_mode"]):
                pool.setdefault(int(mode), []).append((str(path), row))
    rng = np.random.default_rng(seed)
    picked = []
    for mode in sorted(pool):
        items = pool[mode]
        for i in sorted(rng.choice(len(items), min(per_mode, len(items)), replace=False)):
            picked.append(items[i])
    return sorted(picked)


def run_label(task: LabelTask) -> dict:
    """Worker: execute one label at one weight -> a JSON-able record."""
    t0 = time.process_time()
    z = dict(np.load(task.scene_path))
    names = [str(n) for n in z["object_names"]][:len(z["X_task_object"])]
    tables = [load_table(pathlib.Path(task.objects_dir) / f"{n}.npz") for n in names]
    scene = {"arrangement": str(z["arrangement"]),
             "objects": [{"source": dataclasses.asdict(source_from_table(t, task.mesh_dirs)),
                          "X_task_object": np.asarray(X, float).tolist()}
                         for t, X in zip(tables, z["X_task_object"])]}
    k = int(z["label_object"][task.label])
    mode = MODE_NAMES[int(z["label_mode"][task.label])]
    score_n = float(z["label_score"][task.label])
    record = {"scene": pathlib.Path(task.scene_path).stem, "label": task.label, "mass_kg": task.mass_kg,
              "object": names[k], "label_mode": mode, "score_n": round(score_n, 3),
              "holds_weight_by_label": score_n >= task.mass_kg * G_MPS2}
    volume = TSDFVolume(size_m=VOLUME_SIZE_M, resolution=RESOLUTION)
    cell = SimCell(scene, task.mass_kg, Protocol(), volume, detect=lambda tsdf: [])
    cell.settle()
    X_before = np.asarray(z["X_task_object"][k], float)
    state = {s.name: s for s in cell.world.object_states()}[cell.world.names[k]]
    moved_mm = 1000 * float(np.linalg.norm(state.X_task_object[:3, 3] - X_before[:3, 3]))
    record["moved_mm"] = round(moved_mm, 2)
    if moved_mm > MOVED_MM or state.out_of_workspace:
        return {**record, "outcome": "moved", "reason": f"the object moved {moved_mm:.1f} mm while settling",
                "cpu_s": round(time.process_time() - t0, 1)}
    tsdf = cell.observe()
    one = {key: z[key][task.label:task.label + 1] for key in ("label_e_x", "label_e_z", "label_index")}
    grasp = Grasp(pose=label_poses(one)[0], score_n=score_n, validness=1.0,
                  voxel_index=tuple(int(v) for v in one["label_index"][0]))
    try:
        attempt = cell.execute(grasp, tsdf)
        outcome, reason, held_mode = outcome_class(attempt), attempt["reason"], attempt["mode"]
    except Refused as e:
        outcome, reason, held_mode = "refused", str(e), ""
    return {**record, "outcome": outcome, "reason": reason, "held_mode": held_mode,
            "cpu_s": round(time.process_time() - t0, 1)}


def _guarded(task):
    try:
        return run_label(task)
    except Exception as e:  # a bad object or a Drake error: reported, retried by a rerun
        return {"error": f"{type(e).__name__}: {str(e).strip()[:300]}"}


def summarize(records: list) -> dict:
    """{mode: {weight key: {n, moved, outcomes {name: count}, success_if_label_holds [s, n],
    success_if_label_drops [s, n]}}} over the executed records."""
    out = {}
    for r in records:
        cell = out.setdefault(r["label_mode"], {}).setdefault(weight_key(r["mass_kg"]), {
            "n": 0, "moved": 0, "outcomes": {}, "success_if_label_holds": [0, 0], "success_if_label_drops": [0, 0]})
        if r["outcome"] == "moved":
            cell["moved"] += 1
            continue
        cell["n"] += 1
        cell["outcomes"][r["outcome"]] = cell["outcomes"].get(r["outcome"], 0) + 1
        if r["outcome"] != "refused":
            pair = cell["success_if_label_holds" if r["holds_weight_by_label"] else "success_if_label_drops"]
            pair[0] += r["outcome"] == "success"
            pair[1] += 1
    return out


def summary_lines(summary: dict) -> list:
    outcomes = sorted({o for m in summary.values() for c in m.values() for o in c["outcomes"]} - {"success"})
    lines = ["| label mode | weight [kg] | labels | " + " | ".join(["success", *outcomes]) +
             " | success where f_g ≥ m g | success where f_g < m g | moved (apart) |",
             "| --- | --- | ---: |" + " ---: |" * (len(outcomes) + 4)]
    for mode in sorted(summary):
        for w, c in sorted(summary[mode].items(), key=lambda kv: float(kv[0])):
            counts = [c["outcomes"].get(o, 0) for o in ["success", *outcomes]]
            hold, drop = c["success_if_label_holds"], c["success_if_label_drops"]
            lines.append(f"| {mode} | {w} | {c['n']} | " + " | ".join(map(str, counts)) +
                         f" | {hold[0]} / {hold[1]} | {drop[0]} / {drop[1]} | {c['moved']} |")
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", required=True, help="scene stage output directory (holds scenes/)")
    p.add_argument("--objects", required=True, help="objects stage output directory (holds objects/)")
    p.add_argument("--meshes", action="append", default=[], help="mesh directory of the tables' meshes (repeatable)")
    p.add_argument("--out", required=True, help="output directory (resumes there)")
    p.add_argument("--per-mode", type=int, default=40, help="labels per grasp mode")
    p.add_argument("--weights", default="0.1,1.5", help="comma-separated object weights [kg]")
    p.add_argument("--max-scenes", type=int, default=0, help="draw from the first N scenes (0: all)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=None, help="local processes (default: CPU count)")
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    try:
        weights = [float(w) for w in args.weights.split(",")]
        if not all(np.isfinite(w) and w > 0 for w in weights):
            raise ValueError
    except ValueError:
        print(f"label_execution_study: --weights {args.weights!r}: give positive kg values separated by commas",
              file=sys.stderr)
        return 2
    try:
        picked = sample_labels(args.scenes, args.per_mode, args.seed, args.max_scenes)
    except ValueError as e:
        print(f"label_execution_study: {e}", file=sys.stderr)
        return 2
    out = pathlib.Path(args.out)
    (out / "attempts").mkdir(parents=True, exist_ok=True)
    atomic_files.remove_stale_temporaries(out / "attempts")
    objects_dir = str(pathlib.Path(args.objects) / "objects")

    def path_of(t):
        return out / "attempts" / f"{pathlib.Path(t.scene_path).stem}_{t.label:05d}_{weight_key(t.mass_kg)}.json"

    tasks = [LabelTask(s, row, w, objects_dir, tuple(args.meshes)) for w in weights for s, row in picked]
    pending = [t for t in tasks if not path_of(t).exists()]
    errors = []

    def on_result(task, result):
        if "error" in result:
            errors.append(f"{path_of(task).stem}: {result['error']}")
        else:
            atomic_files.save_json(path_of(task), result)

    if pending:
        with make_executor(args.workers) as ex:
            run_tasks(ex, _guarded, pending, on_result, desc="labels", progress=not args.no_progress)
    for e in errors:
        print(f"label_execution_study: {e}", file=sys.stderr)
    records = [json.loads(path_of(t).read_text()) for t in tasks if path_of(t).exists()]
    summary = summarize(records)
    atomic_files.save_json(out / "summary.json", {"scenes": str(args.scenes), "per_mode": args.per_mode,
                                                  "weights_kg": weights, "seed": args.seed, "summary": summary})
    print("\n".join(summary_lines(summary)))
    executed = [r for r in records if r["outcome"] != "moved"]
    failed = sum(r["outcome"] in APPROACH_FAILURES for r in executed)
    print(f"approach_failure_fraction={failed / max(len(executed), 1):.3f}")
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
