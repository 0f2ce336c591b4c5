"""Label yield of the object stage, old and new side by side: `ros2 run sim_bridge bench_datagen`.

For the same objects and seed, two ways to fill an object's grasp table:
  free     candidates all around the free object (approach at any angle about
           the closing axis), simulated at the v1 label settings;
  resting  candidates per resting pose on a table, approach inside the
           executor's cone (antipodal_sampling, resting_poses), simulated at
           the label settings of the v2 dataset (--new-setting).
Both are judged in the same resting poses, as a scene would use them:
  held grasps per CPU-hour          of the grasp simulation (process CPU time);
  table-only collision-free         share of held grasps whose open hand and
                                    approach clear the table (rest-probability weighted);
  labelled voxels per object/scene  distinct TCP voxels (7.5 mm) of the held,
                                    table-free grasps, the object placed in a
                                    drawn resting pose at a random yaw and place;
  labels per scene per CPU-hour     that, per CPU-hour of the object's simulation
                                    (last line: the resting sampler's figure; the
                                    gain over the free one is printed before it).
Objects are procedural (seed 1000, not the training set's) plus, with --meshes,
the first meshes of that directory that are not in --exclude.
"""

import argparse
import sys
import time
from dataclasses import dataclass

import numpy as np
from gravgrasp_detector import atomic_files

from ..parallel import make_executor, run_tasks, task_seed
from ..physics import hand_collision
from ..physics.grasp_simulation import GraspSimulator
from ..physics.scenes import TABLE_HEIGHT_M, VOLUME_SIZE_M
from .antipodal_sampling import SamplingSettings, sample_grasp_candidates, sample_grasp_candidates_at_rest
from .cli import sim_settings
from .object_sources import mesh_sources, procedural_sources, read_name_list
from .resting_poses import find_resting_poses
from .voxel_labels import RESOLUTION

VOXEL_M = VOLUME_SIZE_M / RESOLUTION
OLD_SETTINGS = ("time_step_s=0.001",)                      # the v1 tables
NEW_SETTINGS = ("time_step_s=0.001", "max_force_n=100", "force_ramp_rate_n_s=800")   # see label_settings_study


@dataclass(frozen=True)
class YieldTask:
    source: object        # ObjectSource
    sampler: str          # "free" | "resting"
    count: int
    seed: int
    overrides: tuple


def run_yield_task(task: YieldTask):
    """Worker: resting poses, candidates, their simulation; CPU seconds of each part."""
    obj = task.source.load()
    mesh = obj.collision_mesh()
    c0 = time.process_time()
    rest = find_resting_poses(obj)
    c1 = time.process_time()
    seed = task_seed(task.seed, "bench", task.source.name)
    if task.sampler == "free":
        X = sample_grasp_candidates(mesh, task.count, seed)
    else:
        X, _ = sample_grasp_candidates_at_rest(mesh, rest, task.count, seed, SamplingSettings(sampler="resting"))
    c2 = time.process_time()
    sim = GraspSimulator(obj, sim_settings(task.overrides))
    held = [sim.evaluate(x).grasped for x in X] if len(X) else []
    c3 = time.process_time()
    return dict(rest=rest, X=X, held=np.asarray(held, bool), rest_cpu_s=c1 - c0, sample_cpu_s=c2 - c1,
                sim_cpu_s=c3 - c2)


def table_free(X_object_tcp, rest):
    """(P, N) bool: does grasp n clear the table (open hand + approach) in resting pose p?"""
    out = np.zeros((len(rest), len(X_object_tcp)), bool)
    for p in range(len(rest)):
        X = rest.X_table_object[p][None] @ X_object_tcp
        out[p] = ~hand_collision.collides(X, None, table_z_m=0.0, approach_m=0.05)
    return out


def voxels_per_scene(X_object_tcp, rest, rng, placements=20):
    """Mean distinct labelled voxels of the table-free grasps over random placements
    of the object (drawn resting pose, yaw, position) in the workspace."""
    counts = []
    for _ in range(placements):
        p = rest.sample(rng, 1)[0]
        a = rng.uniform(0, 2 * np.pi)
        Y = np.eye(4)
        Y[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
        Y[:3, 3] = [*rng.uniform(0.08, VOLUME_SIZE_M - 0.08, 2), TABLE_HEIGHT_M]
        X = (Y @ rest.X_table_object[p])[None] @ X_object_tcp
        free = ~hand_collision.collides(X, None, table_z_m=TABLE_HEIGHT_M, approach_m=0.05)
        idx = np.floor(X[free, :3, 3] / VOXEL_M).astype(int)
        idx = idx[((idx >= 0) & (idx < RESOLUTION)).all(1)]
        counts.append(len({tuple(i) for i in idx}))
    return float(np.mean(counts)) if counts else 0.0


def main(argv=None):
    p = argparse.ArgumentParser(prog="bench_datagen", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--meshes", default=None, help="URDF directory (default: procedural objects only)")
    p.add_argument("--exclude", default=None, help="file of mesh names to leave out (the held-out test list)")
    p.add_argument("--procedural", type=int, default=4, help="procedural objects")
    p.add_argument("--mesh-objects", type=int, default=4, help="mesh objects (with --meshes)")
    p.add_argument("--grasps", type=int, default=16, help="candidates simulated per object and sampler")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=None)
    p.add_argument("--new-setting", action="append", default=None, metavar="KEY=VALUE",
                   help=f"SimSettings of the resting column (default: {' '.join(NEW_SETTINGS)})")
    p.add_argument("--json", default=None, help="also write the figures here")
    args = p.parse_args(argv)

    sources = procedural_sources(args.procedural, 1000) if args.procedural else []
    if args.meshes:
        excluded = read_name_list(args.exclude) if args.exclude else set()
        sources += [s for s in mesh_sources(args.meshes) if s.name not in excluded][:args.mesh_objects]
    if not sources:
        p.error("no objects: give --procedural N and/or --meshes DIR")
    columns = {"free": tuple(OLD_SETTINGS), "resting": tuple(args.new_setting or NEW_SETTINGS)}
    tasks = [YieldTask(s, sampler, args.grasps, args.seed, overrides)
             for s in sources for sampler, overrides in columns.items()]
    results = {}

    def on_result(task, result):
        results[(task.source.name, task.sampler)] = result

    t0 = time.perf_counter()
    with make_executor(args.workers) as ex:
        run_tasks(ex, run_yield_task, tasks, on_result, desc="bench_datagen")
    wall = time.perf_counter() - t0

    figures = {}
    for sampler, overrides in columns.items():
        rng = np.random.default_rng(args.seed)
        held = sim_cpu = n = 0
        free_frac, vox, per_obj = [], [], []
        for s in sources:
            r = results.get((s.name, sampler))
            if r is None:
                continue
            X = r["X"][r["held"]] if len(r["X"]) else np.zeros((0, 4, 4))
            n += len(r["X"])
            held += len(X)
            sim_cpu += r["sim_cpu_s"]
            rest = r["rest"]
            if len(X):
                free_frac.append(float(rest.probability @ table_free(X, rest).mean(1)))
            v = voxels_per_scene(X, rest, rng) if len(X) else 0.0
            vox.append(v)
            per_obj.append(v / max(r["sim_cpu_s"] / 3600, 1e-9))
        figures[sampler] = dict(
            settings=list(overrides), candidates=n, held=held,
            held_per_cpu_hour=3600 * held / max(sim_cpu, 1e-9),
            table_free_fraction=float(np.mean(free_frac)) if free_frac else 0.0,
            voxels_per_object_per_scene=float(np.mean(vox)) if vox else 0.0,
            labels_per_scene_per_cpu_hour=float(np.mean(per_obj)) if per_obj else 0.0,
            sim_cpu_s=sim_cpu)
    rest_cpu = np.mean([r["rest_cpu_s"] for (_, smp), r in results.items() if smp == "resting"])
    print(f"{len(sources)} objects ({sum(s.kind == 'mesh' for s in sources)} meshes), {args.grasps} candidates "
          f"per object and sampler, {wall:.0f} s wall; resting poses {rest_cpu:.1f} CPU s per object")
    print(f"{'':34s} {'free (v1)':>14s} {'resting (v2)':>14s}")
    rows = [("candidates simulated", "candidates", "{:.0f}"), ("held", "held", "{:.0f}"),
            ("held grasps per CPU-hour", "held_per_cpu_hour", "{:.0f}"),
            ("table-only collision-free", "table_free_fraction", "{:.1%}"),
            ("labelled voxels per object/scene", "voxels_per_object_per_scene", "{:.1f}"),
            ("labels per scene per CPU-hour", "labels_per_scene_per_cpu_hour", "{:.0f}")]
    for label, key, fmt in rows:
        print(f"{label:34s} {fmt.format(figures['free'][key]):>14s} {fmt.format(figures['resting'][key]):>14s}")
    gain = figures["resting"]["labels_per_scene_per_cpu_hour"] / max(figures["free"]["labels_per_scene_per_cpu_hour"], 1e-9)
    if args.json:
        atomic_files.save_json(args.json, dict(figures=figures, gain=gain, objects=[s.name for s in sources],
                                               grasps=args.grasps, seed=args.seed))
    print(f"labels_per_scene_per_cpu_hour_free={figures['free']['labels_per_scene_per_cpu_hour']:.0f}")
    print(f"yield_gain={gain:.2f}")
    print(f"labels_per_scene_per_cpu_hour={figures['resting']['labels_per_scene_per_cpu_hour']:.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
