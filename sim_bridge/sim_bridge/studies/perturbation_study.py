"""How far from a held grasp does it stop holding? `python -m sim_bridge.studies.perturbation_study`.

The tables' candidates are antipodal pairs with a small lateral jitter, and ~88 % of them
hold, so the network sees few failed poses near a held one and its validness stays high
around objects. This study measures where holding stops: it takes held candidates of the
committed grasp tables, moves each one by d across the pads (TCP +x and -x: the pad width)
and shallower along the approach (TCP -z), closes on each in Drake with the table's own
simulation settings, and reports the fraction still held per direction and distance.
Objects are drawn at random (`--seed`) from the tables, leaving out `--exclude` (the
held-out meshes), or named with `--only`.

Writes `--out` (JSON: per object and shift, held / tried) and prints a table; last line
`held_fraction_across_<largest d>mm=`.
"""

import argparse
import json
import pathlib
import sys
from dataclasses import dataclass

import numpy as np
from gravgrasp_detector import atomic_files

from ..datagen.object_grasps import load_table
from ..datagen.object_sources import object_from_table
from ..datagen.perturbed_grasps import DIRECTIONS, shifted
from ..parallel import make_executor, run_tasks
from ..physics.contact import SimSettings
from ..physics.grasp_simulation import GraspSimulator


@dataclass(frozen=True)
class ObjectTask:
    name: str
    table_path: str
    mesh_dirs: tuple
    candidates: tuple  # indices of held candidates
    shifts_m: tuple


def run_object_task(task: ObjectTask):
    """Worker: ("ok", {"<direction> <d_mm>": [held, tried]}) or ("error", message)."""
    try:
        table = load_table(task.table_path)
        sim = GraspSimulator(object_from_table(table, task.mesh_dirs),
                             SimSettings.from_record(json.loads(str(table["sim_settings"]))))
        counts = {}
        for i in task.candidates:
            X = table["X_object_tcp_candidate"][i]
            for d in task.shifts_m:
                for name, direction in (DIRECTIONS.items() if d > 0 else [("unmoved", (0.0, 0.0, 0.0))]):
                    key = f"{name} {d * 1000:g}"
                    held, tried = counts.get(key, (0, 0))
                    counts[key] = (held + bool(sim.evaluate(shifted(X, direction, d)).grasped), tried + 1)
        return "ok", {k: list(v) for k, v in counts.items()}
    except Exception as e:  # reported; the other objects go on
        return "error", f"{task.name}: {type(e).__name__}: {e}"


def pick_tasks(tables_dir, mesh_dirs, n_objects, per_object, shifts_m, seed, exclude=frozenset(), only=frozenset()):
    """ObjectTasks for n_objects tables drawn at random (or those named in `only`), each
    with per_object of its held candidates drawn at random."""
    rng = np.random.default_rng(seed)
    files = sorted(pathlib.Path(tables_dir, "objects").glob("*.npz"))
    if not only:
        files = rng.permutation(files)
    tasks = []
    for f in files:
        table = load_table(f)
        name, held = str(table["name"]), np.flatnonzero(table["grasped"])
        if (only and name not in only) or name in exclude or len(held) < per_object:
            continue
        picked = tuple(int(i) for i in np.sort(rng.choice(held, per_object, replace=False)))
        tasks.append(ObjectTask(name, str(f), tuple(mesh_dirs), picked, tuple(shifts_m)))
        if not only and len(tasks) == n_objects:
            break
    if only and len(tasks) < len(set(only)):
        raise ValueError(f"{tables_dir}: no table for some of {', '.join(sorted(only))} (or fewer than {per_object} held candidates)")
    return tasks


def summarize(per_object: dict) -> dict:
    """{object: {key: [held, tried]}} -> {key: [held, tried]} over the objects."""
    total = {}
    for counts in per_object.values():
        for k, (held, tried) in counts.items():
            a, b = total.get(k, (0, 0))
            total[k] = [a + held, b + tried]
    return total


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="perturbation_study", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tables", default="models/grasp_tables_v3", help="objects-stage output (holds objects/)")
    p.add_argument("--meshes", action="append", default=[], help="where the tables' mesh files are")
    p.add_argument("--exclude", help="file of object names to leave out (e.g. models/vgn_heldout_meshes.txt)")
    p.add_argument("--only", help="comma-separated object names to study instead of a random draw")
    p.add_argument("--objects", type=int, default=8, help="objects drawn at random")
    p.add_argument("--per-object", type=int, default=10, help="held candidates per object")
    p.add_argument("--shifts-mm", default="7.5,15", help="distances to move each candidate (0: unmoved)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=None)
    p.add_argument("--out", default="out/perturbation_study.json")
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    try:
        shifts_m = tuple(sorted(float(s) / 1000 for s in args.shifts_mm.split(",")))
    except ValueError:
        p.error(f"--shifts-mm {args.shifts_mm!r}: give millimetres, e.g. 7.5,15")
    if not pathlib.Path(args.tables, "objects").is_dir():
        p.error(f"{args.tables} holds no grasp tables (no objects/ directory)")
    exclude = set(pathlib.Path(args.exclude).read_text().split()) if args.exclude else set()
    only = {n for n in (args.only or "").split(",") if n}
    try:
        tasks = pick_tasks(args.tables, args.meshes, args.objects, args.per_object, shifts_m, args.seed, exclude, only)
    except ValueError as e:
        p.error(str(e))
    per_object, errors = {}, []

    def on_result(task, result):
        status, payload = result
        if status == "ok":
            per_object[task.name] = payload
        else:
            errors.append(payload)

    with make_executor(args.workers) as ex:
        run_tasks(ex, run_object_task, tasks, on_result, desc="perturbation study", progress=not args.no_progress)
    total = summarize(per_object)
    atomic_files.save_json(pathlib.Path(args.out), dict(tables=str(args.tables), seed=args.seed,
                                                        per_object=per_object, total=total))
    for e in errors:
        print(e)
    print(f"{len(per_object)} objects x {args.per_object} held candidates of {args.tables}, moved in their TCP frame:")
    for key, (held, tried) in sorted(total.items(), key=lambda kv: (float(kv[0].split()[1]), kv[0])):
        print(f"  {key} mm: {held}/{tried} still held ({held / tried:.0%})")
    d = shifts_m[-1] * 1000
    across = [total.get(f"across{s} {d:g}", [0, 0]) for s in "+-"]
    held, tried = sum(a for a, _ in across), sum(b for _, b in across)
    print(f"held_fraction_across_{d:g}mm={held / tried:.3f}" if tried else "no candidate was studied")
    return 1 if errors or not tried else 0


if __name__ == "__main__":
    sys.exit(main())
