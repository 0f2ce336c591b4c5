"""Does the self-locking drive hold as the real 2F-85 does, without inflating what
friction alone holds? `python -m sim_bridge.studies.transmission_study`.

Calibration of `physics.transmission` at the label settings (dt 1 ms, 400 N/s, 200 N cap),
against the back-drivable drive it replaces:

1. the squeeze table (a free box 10-80 mm wide closed on, locked, held 0.3 s);
2. four cylinder grasps of doc/grasp-simulation.md's "Mode vs depth" table (Ø65 mm power
   at -20 mm and pinch at 0; Ø40 mm power at -15 mm and precision at +10 mm), all six
   scores and the CPU per evaluation, for the back-drivable drive and the lock at 1/2, 1
   and 2 x its stiffness: the friction-limited pinch along the Ø65 axis (+x) and the
   pull-out (+z) of an enclosing grasp against its pinch;
3. stability: held grasps sampled from the committed grasp tables' objects, evaluated with
   the lock, then held locked 0.2 s without load; a non-finite score or state, or an
   object that moves > 1 mm in that idle hold (a snap-out), is a failure.

Writes --out (JSON), prints the tables; the last line is `lock_pinch_inflation=` (the
locked pinch's +x score over the back-drivable one, minus 1). `--compare-tables LOCKED
BACKDRIVABLE` instead compares the same table rows rescored with each drive
(`datagen rescore --sim-setting drive=... --max-held-rows N --names FILE`).
"""

from __future__ import annotations

import argparse
import dataclasses
import pathlib
import sys
import time

import numpy as np
from gravgrasp_detector import atomic_files

from ..datagen.object_grasps import MODE_NAMES, load_table
from ..datagen.perturbed_grasps import load_labelling_table
from ..datagen.object_sources import object_from_table
from ..parallel import make_executor, run_tasks, task_seed
from ..physics.contact import SimSettings
from ..physics.grasp_simulation import GraspSimulator, measure_squeeze_force_n
from ..physics.objects import procedural_object
from ..physics.transmission import LOCK_STIFFNESS_NM_PER_RAD

SQUEEZE_WIDTHS_M = (0.01, 0.02, 0.035, 0.05, 0.065, 0.08)
# (name, cylinder diameter m, depth of its axis on the TCP z axis m)
CYLINDER_CASES = (("Ø65 power -20 mm", 0.065, -0.020), ("Ø65 pinch 0 mm", 0.065, 0.0),
                  ("Ø40 power -15 mm", 0.040, -0.015), ("Ø40 precision +10 mm", 0.040, 0.010))
STIFFNESS_FACTORS = (0.5, 1.0, 2.0)
IDLE_HOLD_S = 0.2
SNAP_OUT_M = 5e-3  # the settle criterion (5 mm/s) allows 1 mm of creep in the idle hold
PINCH_AXIS = ("Ø65 pinch 0 mm", 0)  # case, score index (+x: along the cylinder axis)
PULL_OUT = (("Ø65 power -20 mm", "Ø65 pinch 0 mm"), ("Ø40 power -15 mm", "Ø40 precision +10 mm"))
Z_PLUS = 4


def cylinder_pose(depth_m) -> np.ndarray:
    """TCP pose in a z-axis cylinder's frame: approach along -x_O, closing along y_O, the
    cylinder axis along TCP x at `depth_m` on the TCP z axis (as the simulation tests)."""
    X = np.eye(4)
    X[:3, :3] = [[0, 0, -1], [0, 1, 0], [1, 0, 0]]
    X[:3, 3] = [depth_m, 0, 0]
    return X


def drives(stiffness=LOCK_STIFFNESS_NM_PER_RAD) -> dict:
    """{label: SimSettings} of the comparison: the back-drivable drive and the lock at
    STIFFNESS_FACTORS x `stiffness`."""
    out = {"backdrivable": SimSettings.for_labels(drive="backdrivable")}
    for f in STIFFNESS_FACTORS:
        out[f"locked {f:g}x ({f * stiffness:g} N m/rad)"] = SimSettings.for_labels(
            drive="self_locking", lock_stiffness_nm_per_rad=f * stiffness)
    return out


def run_cases(label_settings) -> dict:
    """Worker: the squeeze table and the cylinder cases for one drive."""
    label, settings = label_settings
    squeeze = [measure_squeeze_force_n(w, settings) for w in SQUEEZE_WIDTHS_M]
    cases = {}
    for name, diameter, depth in CYLINDER_CASES:
        sim = GraspSimulator(procedural_object("cylinder", (diameter, 0.2), mass_kg=0.5), settings)
        t0 = time.process_time()
        o = sim.evaluate(cylinder_pose(depth))
        cases[name] = dict(mode=o.mode, scores_n=[round(float(s), 2) for s in o.scores_n],
                           cpu_s=round(time.process_time() - t0, 2))
    return label, dict(squeeze_n=[round(s, 2) for s in squeeze], cases=cases)


@dataclasses.dataclass(frozen=True)
class StabilityTask:
    table_path: str
    rows: tuple
    mesh_dirs: tuple


def run_stability(task: StabilityTask) -> list:
    """Worker: evaluate the rows of one table with the lock, then hold them idle."""
    table = load_table(task.table_path)
    sim = GraspSimulator(object_from_table(table, task.mesh_dirs), SimSettings.for_labels(drive="self_locking"))
    out = []
    for r in task.rows:
        o = sim.evaluate(table["X_object_tcp_candidate"][r].astype(float))
        row = dict(table=pathlib.Path(task.table_path).stem, row=int(r), grasped=bool(o.grasped),
                   ramps=6 * int(o.grasped), finite=bool(np.all(np.isfinite(o.scores_n))))
        if o.grasped:  # evaluate leaves the settled, locked state: hold it without load
            root = sim.simulator.get_mutable_context()
            pc = sim.plant.GetMyContextFromRoot(root)
            p0 = sim.plant.EvalBodyPoseInWorld(pc, sim.object_body).translation().copy()
            sim.simulator.Initialize()
            sim.simulator.AdvanceTo(root.get_time() + IDLE_HOLD_S)
            moved = float(np.linalg.norm(sim.plant.EvalBodyPoseInWorld(pc, sim.object_body).translation() - p0))
            row.update(idle_moved_m=moved,
                       finite=row["finite"] and bool(np.all(np.isfinite(sim.plant.GetPositionsAndVelocities(pc)))))
        out.append(row)
    return out


def stability_tasks(tables_dir, mesh_dirs, grasps, seed=0) -> list:
    """About `grasps` held rows of the committed tables, a few per object, seeded."""
    files = sorted(pathlib.Path(tables_dir).glob("objects/*.npz"))
    rng = np.random.default_rng(task_seed(seed, "transmission_study"))
    files = [files[i] for i in sorted(rng.choice(len(files), min(len(files), max(1, grasps // 3)), replace=False))]
    per = int(np.ceil(grasps / max(1, len(files))))
    tasks = []
    for f in files:
        with np.load(f) as t:
            held = np.flatnonzero(t["grasped"])
        if held.size:
            tasks.append(StabilityTask(str(f), tuple(int(r) for r in rng.choice(held, min(per, held.size), replace=False)),
                                       tuple(mesh_dirs)))
    return tasks


def compare_tables(locked_dir, backdrivable_dir) -> dict:
    """The same rows of two `datagen rescore` (and `datagen wrap`) outputs, one per drive:
    do the closings agree, and how do the scores of rows held in both compare, for the
    wraps (power rows) and the rest?"""
    a, b, wrap, rows, mode_diff, held_diff = [], [], [], 0, 0, 0
    for f in sorted(pathlib.Path(locked_dir).glob("objects/*.npz")):
        if not (pathlib.Path(backdrivable_dir) / "objects" / f.name).exists():
            continue
        lk = load_labelling_table(f.parent, f.stem)
        bd = load_labelling_table(pathlib.Path(backdrivable_dir) / "objects", f.stem)
        if not np.allclose(lk["X_object_tcp_candidate"], bd["X_object_tcp_candidate"], atol=1e-6):
            raise ValueError(f"{f.name}: the two tables hold other candidates; rescore (and wrap) both with the "
                             "same --max-held-rows, --names, --per-object and --seed")
        rows += len(lk["grasped"])
        mode_diff += int((lk["mode"] != bd["mode"]).sum())
        held_diff += int((lk["grasped"] != bd["grasped"]).sum())
        both = lk["grasped"].astype(bool) & bd["grasped"].astype(bool)
        a.append(lk["scores_n"][both])
        b.append(bd["scores_n"][both])
        wrap.append(lk["mode"][both] == MODE_NAMES.index("power"))
    a, b = (np.concatenate(x) if x else np.zeros((0, 6)) for x in (a, b))
    wrap = np.concatenate(wrap) if wrap else np.zeros(0, bool)

    def medians(mask):
        if not mask.any():
            return None
        ratio = a[mask].min(1) / np.maximum(b[mask].min(1), 1e-3)
        return dict(rows=int(mask.sum()),
                    median_locked_n=[round(float(v), 1) for v in np.median(a[mask], 0)],
                    median_backdrivable_n=[round(float(v), 1) for v in np.median(b[mask], 0)],
                    min_score_ratio_p10_p50_p90=[round(float(v), 3) for v in np.percentile(ratio, [10, 50, 90])])
    return dict(rows=rows, mode_differs=mode_diff, held_differs=held_diff, held_in_both=len(a),
                not_wraps=medians(~wrap), wraps=medians(wrap))


def summary_lines(result: dict) -> list:
    lines = ["| drive | " + " | ".join(f"{w * 1000:g} mm" for w in SQUEEZE_WIDTHS_M) + " |",
             "| --- |" + " --- |" * len(SQUEEZE_WIDTHS_M)]
    for label, r in result["drives"].items():
        lines.append(f"| {label} | " + " | ".join(f"{s:.2f}" for s in r["squeeze_n"]) + " |")
    lines += ["", "| drive | case | mode | +x | -x | +y | -y | +z | -z | CPU s |", "| --- |" + " --- |" * 9]
    for label, r in result["drives"].items():
        for name, c in r["cases"].items():
            lines.append(f"| {label} | {name} | {c['mode']} | " + " | ".join(f"{s:.1f}" for s in c["scores_n"])
                         + f" | {c['cpu_s']:.1f} |")
    lines += ["", "| drive | pinch along the Ø65 axis vs back-drivable | " +
              " | ".join(f"{a} +z / {b} +z" for a, b in PULL_OUT) + " |", "| --- | --- |" + " --- |" * len(PULL_OUT)]
    base = result["drives"]["backdrivable"]["cases"][PINCH_AXIS[0]]["scores_n"][PINCH_AXIS[1]]
    for label, r in result["drives"].items():
        c = r["cases"]
        lines.append(f"| {label} | {c[PINCH_AXIS[0]]['scores_n'][PINCH_AXIS[1]] / base - 1:+.1%} | " + " | ".join(
            f"{c[a]['scores_n'][Z_PLUS] / c[b]['scores_n'][Z_PLUS]:.2f}x" for a, b in PULL_OUT) + " |")
    s = result.get("stability")
    if s:
        lines += ["", f"stability: {s['grasps']} grasps of {s['objects']} objects, {s['held']} held, {s['ramps']} ramps; "
                      f"non-finite {s['non_finite']}, snap-outs (moved > {SNAP_OUT_M * 1000:g} mm in a "
                      f"{IDLE_HOLD_S:g} s idle locked hold) {s['snap_outs']}, largest idle motion "
                      f"{s['max_idle_moved_m'] * 1000:.3f} mm"]
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("--tables", default="models/grasp_tables_v3", help="grasp tables for the stability sample")
    p.add_argument("--mesh-dir", action="append", default=None,
                   help="mesh directories of the tables' objects (default ../shared/meshes/vgn_train)")
    p.add_argument("--stability-grasps", type=int, default=170, help="held grasps to evaluate (6 ramps each)")
    p.add_argument("--workers", type=int, default=None)
    p.add_argument("--out", default="sim_bridge/results/transmission_study.json")
    p.add_argument("--compare-tables", nargs=2, metavar=("LOCKED", "BACKDRIVABLE"), default=None,
                   help="only compare two `datagen rescore` outputs of the same rows, one per drive (prints "
                        "the agreement of the closings and the score medians; writes nothing)")
    args = p.parse_args(argv)
    if args.compare_tables:
        try:
            c = compare_tables(*args.compare_tables)
        except ValueError as e:
            print(f"transmission_study: {e}", file=sys.stderr)
            return 2
        print(f"{c['rows']} rows: mode differs in {c['mode_differs']}, held/failed in {c['held_differs']}; "
              f"{c['held_in_both']} held in both")
        for kind in ("not_wraps", "wraps"):
            m = c[kind]
            if m:
                print(f"{kind} ({m['rows']}): median scores +x -x +y -y +z -z [N] locked {m['median_locked_n']}, "
                      f"back-drivable {m['median_backdrivable_n']}; min score ratio p10/p50/p90 "
                      f"{m['min_score_ratio_p10_p50_p90']}")
        print(f"min_score_ratio_p50={c['not_wraps']['min_score_ratio_p10_p50_p90'][1] if c['not_wraps'] else float('nan')}")
        return 0
    mesh_dirs = args.mesh_dir or [str(pathlib.Path("..") / "shared" / "meshes" / "vgn_train")]
    result = {"drives": {}, "label_settings": dataclasses.asdict(SimSettings.for_labels(drive="self_locking"))}
    stab = []
    with make_executor(args.workers) as ex:
        run_tasks(ex, run_cases, list(drives().items()),
                  lambda task, r: result["drives"].__setitem__(*r), desc="drives", progress=False)
        if args.stability_grasps > 0:
            tasks = stability_tasks(args.tables, mesh_dirs, args.stability_grasps)
            if not tasks:
                print(f"transmission_study: no held grasps under {args.tables}/objects", file=sys.stderr)
                return 2
            run_tasks(ex, run_stability, tasks, lambda task, r: stab.extend(r), desc="stability", progress=False)
    result["drives"] = {k: result["drives"][k] for k in drives()}  # the table's order
    if stab:
        held = [r for r in stab if r["grasped"]]
        result["stability"] = dict(
            grasps=len(stab), objects=len({r["table"] for r in stab}), held=len(held),
            ramps=sum(r["ramps"] for r in stab), non_finite=sum(not r["finite"] for r in stab),
            snap_outs=sum(r["idle_moved_m"] > SNAP_OUT_M for r in held),
            max_idle_moved_m=max((r["idle_moved_m"] for r in held), default=0.0), rows=stab)
    atomic_files.save_json(pathlib.Path(args.out), result)
    print("\n".join(summary_lines(result)))
    c = result["drives"]
    locked = next(k for k in c if k.startswith("locked 1x"))
    pinch = c[locked]["cases"][PINCH_AXIS[0]]["scores_n"][PINCH_AXIS[1]]
    print(f"lock_pinch_inflation={pinch / c['backdrivable']['cases'][PINCH_AXIS[0]]['scores_n'][PINCH_AXIS[1]] - 1:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
