"""Throughput of each data-generation stage on one core: `ros2 run sim_bridge bench_datagen`.

Measures, in this process (one core, nothing else of ours running):
  sampling   antipodal candidates per second (incl. the open-hand collision checks)
  simulation grasps per hour (close + 6 force ramps, real Drake)
  scenes     scenes per minute, split into arranging (Drake settling) and
             the rest (rendering, TSDF fusion, projection, collision filter, labels)
Each figure is given from wall time and from this process's CPU time (the machine
may be shared: wall/CPU > 1 means other jobs took the core). The last line is
machine-readable.
"""

import argparse
import pathlib
import sys
import tempfile
import time

import numpy as np


def main(argv=None):
    p = argparse.ArgumentParser(prog="bench_datagen", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--meshes", default=None, help="URDF directory (default: procedural objects only)")
    p.add_argument("--objects", type=int, default=4)
    p.add_argument("--grasps", type=int, default=4, help="grasps simulated per object")
    p.add_argument("--scenes", type=int, default=6)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--sim-setting", action="append", default=[], metavar="KEY=VALUE",
                   help="SimSettings override, as for datagen objects")
    args = p.parse_args(argv)

    from .antipodal_sampling import sample_grasp_candidates
    from .datagen import run_object_stage, sim_settings
    from .object_grasps import mesh_sources, procedural_sources
    from .scene_dataset import SceneTask, _run_scene, usable_tables
    from .scenes import arrange

    settings = sim_settings(args.sim_setting)
    sources = (mesh_sources(args.meshes)[:args.objects] if args.meshes
               else procedural_sources(args.objects, args.seed))
    objs = []
    for s in sources:
        try:
            objs.append(s.load())
        except Exception as e:
            print(f"skip {s.name}: {e}")
    t0, c0 = time.perf_counter(), time.process_time()
    n = sum(len(sample_grasp_candidates(o.collision_mesh(), 64, args.seed)) for o in objs)
    dt, dc = time.perf_counter() - t0, time.process_time() - c0
    print(f"sampling: {n} candidates in {dt:.1f} s wall / {dc:.1f} s CPU = {n / dt:.0f} (wall) / "
          f"{n / dc:.0f} (CPU) candidates/s")

    with tempfile.TemporaryDirectory() as tmp:
        from concurrent.futures import ThreadPoolExecutor

        # one thread: the simulation runs here, serially, like one worker process
        with ThreadPoolExecutor(1) as ex:
            t0, c0 = time.perf_counter(), time.process_time()
            run_object_stage(tmp, sources, args.grasps, args.seed, block_size=args.grasps,
                             sim_settings=settings, executor=ex, progress=False)
            dt, dc = time.perf_counter() - t0, time.process_time() - c0
        held_per_cpu_hour = None
        tables = [np.load(p) for p in sorted(pathlib.Path(tmp, "objects").glob("*.npz"))]
        sims = sum(len(t["mode"]) for t in tables)
        held = sum(int(t["grasped"].sum()) for t in tables)
        sim_time = sum(float(t["wall_time_s"].sum()) for t in tables)
        print(f"object stage: {sims} grasps ({held} held) in {dt:.1f} s wall / {dc:.1f} s CPU = "
              f"{3600 * sims / dt:.0f} (wall) / {3600 * sims / dc:.0f} (CPU) grasps/h per core; "
              f"held grasps/h per core {3600 * held / dt:.0f} (wall) / {3600 * held / dc:.0f} (CPU)")
        held_per_cpu_hour = 3600 * held / dc

        rng = np.random.default_rng(args.seed)
        for kind in ("packed", "pile"):
            t0, c0 = time.perf_counter(), time.process_time()
            for _ in range(3):
                pick = rng.choice(len(objs), size=min(len(objs), 5), replace=False)
                arrange([objs[i] for i in pick], kind, rng)
            print(f"arrange {kind}: {(time.perf_counter() - t0) / 3:.2f} s wall / "
                  f"{(time.process_time() - c0) / 3:.2f} s CPU per {min(len(objs), 5)}-object scene")

        names = tuple(usable_tables(pathlib.Path(tmp, "objects")))
        if not names:
            print("scenes: no held grasp to build scenes from; raise --grasps")
            return 0
        t0, c0 = time.perf_counter(), time.process_time()
        labels = 0
        mesh_dirs = (args.meshes,) if args.meshes else ()
        for i in range(args.scenes):
            out = _run_scene(SceneTask(i, args.seed, str(pathlib.Path(tmp, "objects")), names, mesh_dirs))
            labels += len(out["label_score"])
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        print(f"scene stage: {args.scenes} scenes in {dt:.1f} s wall / {dc:.1f} s CPU = "
              f"{60 * args.scenes / dt:.1f} (wall) / {60 * args.scenes / dc:.1f} (CPU) scenes/min per core "
              f"({labels} labels)")
        print(f"held_grasps_per_core_hour={held_per_cpu_hour:.0f} scenes_per_core_minute={60 * args.scenes / dc:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
