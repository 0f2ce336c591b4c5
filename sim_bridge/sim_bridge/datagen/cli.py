"""Dataset generation command (paper Sec. III): `ros2 run sim_bridge datagen objects|perturb|rescore|wrap|scenes|recipes`.

  objects  per-object grasp tables: antipodal candidates, closed on in the Drake
           grasp simulation, 6-direction disturbance-rejection scores.
  perturb  held candidates of those tables moved ~15 mm (across the pads or shallower)
           and closed on again: rows near the edge of holding, which the scene stage
           labels with the tables' own (perturbed_grasps).
  rescore  a directory of tables simulated again under other settings, e.g. the
           self-locking drive (rescored_tables).
  wrap     held precision candidates turned and moved toward the palm, closed again:
           power grasps made as the paper makes them (power_grasps).
  scenes   packed / pile scenes on a table from those tables: TSDF from rendered
           depth, grasps projected and collision-filtered, gravity projection,
           sparse voxel labels.
  recipes  pack scenes into recipes small enough to commit (objects, settled poses,
           views), or restore the scene files from them without the physics.

All are resumable (rerun the same command after a kill: finished outputs are
kept, partial ones never exist thanks to atomic writes), deterministic for a
seed (per-task seeds derive from --seed and the task id), and parallel: local
worker processes (--workers) or, for objects and scenes, a Dask cluster (--scheduler tcp://host:8786; the
workers need this package, the mesh directory and the output directory on a
shared path).
"""

import argparse
import dataclasses
import itertools
import json
import os
import sys
from concurrent.futures.process import BrokenProcessPool

import numpy as np

from gravgrasp_detector import atomic_files
from ..parallel import make_executor, run_tasks
from ..physics.contact import SimSettings
from ..physics.objects import ObjectError
from .antipodal_sampling import SamplingSettings
from .object_grasps import ObjectChunk, ObjectStageStore, RestTask, run_chunk, run_rest_task
from .object_sources import mesh_sources, procedural_sources, read_name_list
from . import perturbed_grasps, power_grasps, rescored_tables, scene_recipes
from .scene_dataset import OBJECT_COUNTS, run_scene_stage


def run_object_stage(out_dir, sources, grasps_per_object, seed, workers=None, scheduler=None,
                     block_size=8, sim_settings=None, simulator_factory=None, progress=True,
                     executor=None, sampling=None):
    """Simulate `grasps_per_object` candidates (rounded up to whole blocks) of every
    source; returns a summary dict.  Finished tables and skip notes are kept, so
    calling again resumes, and a larger `grasps_per_object` grows the tables.
    With sampling.sampler == "resting" each object's resting poses are found first
    (one task per object) and its candidates are drawn per resting pose."""
    sampling = sampling or SamplingSettings()
    store = ObjectStageStore(out_dir)
    store.dir.mkdir(parents=True, exist_ok=True)
    atomic_files.remove_stale_temporaries(store.dir)
    n_blocks = -(-grasps_per_object // block_size)
    if len({s.name for s in sources}) != len(sources):
        raise ValueError("object names must be unique")
    # blocks that all finished before a kill but were not merged yet
    for s in sources:
        store.merge_if_complete(s, n_blocks, block_size, seed, sampling)

    def run(fn, tasks, on_result, desc):
        if not tasks:
            return
        if executor is not None:
            run_tasks(executor, fn, tasks, on_result, desc=desc, progress=progress)
        else:
            with make_executor(workers, scheduler) as ex:
                run_tasks(ex, fn, tasks, on_result, desc=desc, progress=progress)

    errors = {}

    def on_rest(task, result):
        status, payload = result
        if status == "ok":
            store.write_rest(task.source.name, payload)
        elif status == "skip":
            store.write_skip(task.source, payload)
        else:
            errors[task.source.name] = payload

    def on_result(task, result):
        status, payload = result
        name = task.source.name
        if store.skip_path(name).exists():
            return  # another block already skipped this object
        if status == "skip":
            store.write_skip(task.source, payload)
        elif status == "error":
            errors[name] = payload
        else:
            rows, meta = payload
            store.write_part(task, rows, meta)
            store.merge_if_complete(task.source, n_blocks, block_size, seed, sampling)

    resting = sampling.sampler == "resting"
    # Resting poses, then grasps, a few objects at a time: finished tables appear early
    # and a run stopped after hours has whole tables, not just everyone's resting poses.
    step = 4 * (workers or os.cpu_count() or 1) if resting else len(sources)
    for first in range(0, len(sources), max(1, step)):
        group = sources[first:first + step]
        if resting:
            run(run_rest_task, [RestTask(s, sampling) for s in group
                                if store.pending_chunks(s.name, n_blocks, block_size)
                                and store.resting_poses(s.name) is None], on_rest, "resting poses")
        tasks = [ObjectChunk(s, c, block_size, seed, sim_settings, sampling, simulator_factory,
                             rest=store.resting_poses(s.name) if resting else None)
                 for s in group if s.name not in errors
                 for c in store.pending_chunks(s.name, n_blocks, block_size)]
        run(run_chunk, tasks, on_result, "object grasps")
    summary = write_object_report(store, sources, errors)
    return summary


def write_object_report(store, sources, errors=None):
    """`<out>/objects/report.json`: per object ok (grasps, power, failed) / skipped + reason."""
    errors = errors or {}
    entries = []
    for s in sources:
        if store.table_path(s.name).exists():
            with np.load(store.table_path(s.name)) as t:
                mode, grasped = t["mode"], t["grasped"]
                entries.append(dict(name=s.name, status="ok", grasps=int(len(mode)), grasped=int(grasped.sum()),
                                    power=int((grasped & (mode == 0)).sum()),
                                    sim_wall_time_s=float(t["wall_time_s"].sum())))
        elif store.skip_path(s.name).exists():
            reason = json.loads(store.skip_path(s.name).read_text())["reason"]
            entries.append(dict(name=s.name, status="skipped", reason=reason))
        elif s.name in errors:
            entries.append(dict(name=s.name, status="error", reason=errors[s.name]))
        else:
            entries.append(dict(name=s.name, status="pending"))
    summary = {k: sum(e["status"] == k for e in entries) for k in ("ok", "skipped", "error", "pending")}
    atomic_files.save_json(store.dir / "report.json", dict(summary=summary, objects=entries))
    return dict(summary, entries=entries)


def sim_settings(overrides=()):
    """SimSettings with "key=value" overrides (types from the field defaults)."""
    fields = {f.name: f for f in dataclasses.fields(SimSettings)}
    values = {}
    for item in overrides:
        key, sep, text = item.partition("=")
        if not sep or key not in fields:
            raise ValueError(f"--sim-setting {item!r}: use KEY=VALUE with KEY one of {', '.join(fields)}")
        default = fields[key].default
        try:
            if isinstance(default, bool):
                values[key] = text.lower() in ("1", "true", "yes")
            elif isinstance(default, (int, float)) or default is None:
                values[key] = float(text) if not isinstance(default, int) or "." in text else int(text)
            else:
                values[key] = type(default)(text)
        except ValueError:
            raise ValueError(f"--sim-setting {item!r}: {text!r} is not a valid {key}") from None
    settings = SimSettings(**values)
    settings.validate()
    return settings


def _object_sources(args):
    excluded = set().union(*[read_name_list(f) for f in args.exclude]) if args.exclude else set()
    groups = [[s for s in mesh_sources(d, args.density) if s.name not in excluded] for d in args.meshes or []]
    if args.procedural:
        groups.append(procedural_sources(args.procedural, args.procedural_seed))
    # Round-robin over the sets, so that a run stopped early (or --limit) already has
    # every kind of object; the order does not change any object's table.
    sources = [s for row in itertools.zip_longest(*groups) for s in row if s is not None]
    if args.limit:
        sources = sources[:args.limit]
    return sources


def main(argv=None):
    p = argparse.ArgumentParser(prog="datagen", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="stage", required=True)

    def common(sp):
        sp.add_argument("--out", required=True, help="output directory (resumes if it exists)")
        sp.add_argument("--seed", type=int, default=0, help="master seed")
        sp.add_argument("--workers", type=int, default=None, help="local worker processes (default: all cores)")
        sp.add_argument("--scheduler", default=None, help="Dask scheduler address, e.g. tcp://host:8786")
        sp.add_argument("--no-progress", action="store_true")

    o = sub.add_parser("objects", help="per-object grasp tables")
    common(o)
    o.add_argument("--meshes", action="append", help="directory of URDFs (VGN layout) or OBJs; repeatable")
    o.add_argument("--exclude", action="append", default=[], metavar="FILE",
                   help="leave out the meshes named in FILE (e.g. models/vgn_heldout_meshes.txt); repeatable")
    o.add_argument("--density", type=float, default=0.0,
                   help="kg/m^3 for bare OBJ files (URDFs carry their mass)")
    o.add_argument("--procedural", type=int, default=0, help="number of procedural objects")
    o.add_argument("--procedural-seed", type=int, default=0)
    o.add_argument("--grasps-per-object", type=int, default=64,
                   help="candidates simulated per object (rounded up to whole blocks); raise it later to grow tables")
    o.add_argument("--block-size", type=int, default=8,
                   help="grasps per task, each block with its own seed; fixed for an output directory")
    o.add_argument("--limit", type=int, default=0, help="only the first N objects (after sorting)")
    o.add_argument("--sim-setting", action="append", default=[], metavar="KEY=VALUE",
                   help="override a grasp_simulation.SimSettings field, e.g. max_close_time_s=4 (repeatable)")
    o.add_argument("--sampler", choices=("resting", "free"), default="resting",
                   help="resting: candidates per resting pose on a table, approach inside the executor's "
                        "cone (default); free: approach at any angle (the v1 dataset)")

    pt = sub.add_parser("perturb", help="held candidates moved to the edge of holding, simulated again")
    pt.add_argument("--objects", required=True, help="output directory of the objects stage (holds objects/); "
                                                     "the rows go to its objects/perturbed/")
    pt.add_argument("--meshes", action="append", default=[], help="where the tables' mesh files are")
    pt.add_argument("--exclude", action="append", default=[], metavar="FILE",
                    help="leave out the objects named in FILE (e.g. models/vgn_heldout_meshes.txt); repeatable")
    pt.add_argument("--per-object", type=int, default=64, help="held candidates moved per object")
    pt.add_argument("--shift-mm", type=float, default=15.0,
                    help="how far each is moved: across the pads (+x or -x) or shallower (-z), drawn per candidate")
    pt.add_argument("--seed", type=int, default=0, help="master seed")
    pt.add_argument("--workers", type=int, default=None, help="local worker processes (default: all cores)")
    pt.add_argument("--no-progress", action="store_true")

    rsc = sub.add_parser("rescore", help="a directory of grasp tables simulated again under other settings "
                                         "(e.g. the self-locking drive): same candidates, new scores")
    rsc.add_argument("--objects", required=True, help="output directory of the objects stage to rescore")
    rsc.add_argument("--out", required=True, help="new output directory (gets objects/; resumable)")
    rsc.add_argument("--meshes", action="append", default=[], help="where the tables' mesh files are")
    rsc.add_argument("--sim-setting", action="append", default=[], metavar="KEY=VALUE",
                     help="what changes, over each table's own SimSettings, e.g. drive=self_locking (repeatable)")
    rsc.add_argument("--names", default=None, metavar="FILE", help="only the objects named in FILE")
    rsc.add_argument("--max-held-rows", type=int, default=0,
                     help="a seeded sample of each table's held rows (a gated study; default 0: every row)")
    rsc.add_argument("--seed", type=int, default=0)
    rsc.add_argument("--workers", type=int, default=None, help="local worker processes (default: all cores)")
    rsc.add_argument("--no-progress", action="store_true")

    wr = sub.add_parser("wrap", help="held precision candidates turned and moved toward the palm, closed again with "
                                     "the table's own settings: power grasps made as the paper makes them (rows to "
                                     "objects/toward_palm/)")
    wr.add_argument("--objects", required=True, help="output directory of the objects (or rescore) stage")
    wr.add_argument("--meshes", action="append", default=[], help="where the tables' mesh files are")
    wr.add_argument("--names", default=None, metavar="FILE", help="only the objects named in FILE")
    wr.add_argument("--per-object", type=int, default=32, help="held precision candidates per object")
    wr.add_argument("--max-turn-deg", type=float, default=20.0, help="turn about the closing and approach axes, drawn in ±this")
    wr.add_argument("--max-depth-mm", type=float, default=40.0, help="deepest move toward the palm")
    wr.add_argument("--seed", type=int, default=0)
    wr.add_argument("--workers", type=int, default=None, help="local worker processes (default: all cores)")
    wr.add_argument("--no-progress", action="store_true")

    sc = sub.add_parser("scenes", help="scenes with TSDF and voxel labels from grasp tables")
    common(sc)
    sc.add_argument("--objects", required=True, help="output directory of the objects stage (holds objects/)")
    sc.add_argument("--meshes", action="append", default=[], help="where the tables' mesh files are")
    sc.add_argument("--scenes", type=int, required=True, help="number of scenes")
    sc.add_argument("--max-objects", type=int, default=5)
    sc.add_argument("--max-views", type=int, default=6)
    sc.add_argument("--object-count", choices=OBJECT_COUNTS, default="poisson",
                    help="objects per scene: 'poisson' (default) draws VGN's Poisson(4) + 1, capped at "
                         "--max-objects (mostly full tables, like the benchmark's 5-object scenes); "
                         "'uniform' draws 1..--max-objects alike (the v2 scenes)")
    sc.add_argument("--label-pose", choices=("commanded", "settled"), default="commanded",
                    help="hand pose a label carries: the one the robot commands (default) or the one after "
                         "the object settled in the hand (the v1 dataset)")
    sc.add_argument("--no-symmetry", action="store_true",
                    help="place only the simulated grasps (default: also their copies at each rotational "
                         "and mirror symmetry of the object, which hold alike; see object_symmetry)")
    sc.add_argument("--no-mirror-copies", action="store_true",
                    help="copies at rotational symmetries only (none at mirror symmetries)")
    sc.add_argument("--no-execution-check", action="store_true",
                    help="check a grasp only where it was simulated (the v2 scenes), not also where the "
                         "robot executes it: inside the executor's approach cone, at its voxel centre, with "
                         "the fingers closed above the table")

    rc = sub.add_parser("recipes", help="pack scenes into small committable recipes, or rebuild scenes from them")
    rsub = rc.add_subparsers(dest="action", required=True)
    pk = rsub.add_parser("pack", help="add the recipes of a scene directory to a recipe directory")
    pk.add_argument("scenes", help="--out directory of `datagen scenes` (or its scenes/)")
    pk.add_argument("recipes", help="recipe directory (e.g. models/scene_recipes_v3; grows, never drops)")
    rs = rsub.add_parser("restore", help="write the scene files a directory lacks, from recipes (no physics)")
    rs.add_argument("recipes", help="recipe directory made by `recipes pack`")
    rs.add_argument("out", help="scene output directory (as `datagen scenes --out`; resumable)")
    rs.add_argument("--objects", default=None,
                    help="output directory of the objects stage the scenes were made from (default: the one "
                         "recorded in the recipes)")
    rs.add_argument("--meshes", action="append", default=[], help="where the tables' mesh files are")
    rs.add_argument("--relabel", action="store_true",
                    help="label the scenes with --objects tables other than those that labelled them (grown "
                         "tables, the same objects): the settled scenes are kept, the labels are new")
    rs.add_argument("--workers", type=int, default=None, help="local worker processes (default: all cores)")
    rs.add_argument("--validation-of", metavar="MODEL", default=None,
                    help="only the scenes MODEL's training held out for validation (its seed and fraction; the "
                         "split is by file name): what score_calibration reads, ~1/10 of the CPU")
    rs.add_argument("--no-progress", action="store_true")

    args = p.parse_args(argv)
    try:
        return _run(p, args)
    except BrokenProcessPool as e:
        # a worker process died (out of memory, or a native crash): everything finished
        # so far is on disk, so the same command resumes
        print(f"datagen: a worker process died ({e}); rerun the same command to resume", file=sys.stderr)
        return 3


def _run(p, args):
    if args.stage == "recipes":
        return _run_recipes(args)
    if args.stage == "perturb":
        return _run_perturb(p, args)
    if args.stage in ("rescore", "wrap"):
        return _run_rescore_or_wrap(p, args)
    if args.stage == "objects":
        try:
            sources = _object_sources(args)
        except ObjectError as e:
            p.error(str(e))
        if not sources:
            p.error("no objects: give --meshes DIR (with .urdf or .obj files) and/or --procedural N")
        try:
            settings = sim_settings(args.sim_setting)
        except ValueError as e:
            p.error(str(e))
        s = run_object_stage(args.out, sources, args.grasps_per_object, args.seed, args.workers, args.scheduler,
                             block_size=args.block_size, sim_settings=settings, progress=not args.no_progress,
                             sampling=SamplingSettings(sampler=args.sampler))
        print(f"objects: ok={s['ok']} skipped={s['skipped']} error={s['error']} pending={s['pending']} "
              f"(report: {ObjectStageStore(args.out).dir / 'report.json'})")
        return 1 if s["error"] else 0
    s = run_scene_stage(args.out, args.objects, args.meshes, args.scenes, args.seed, args.workers, args.scheduler,
                        max_objects=args.max_objects, max_views=args.max_views, progress=not args.no_progress,
                        label_pose=args.label_pose, symmetry=not args.no_symmetry,
                        mirrors=not args.no_mirror_copies, execution_check=not args.no_execution_check,
                        object_count=args.object_count)
    print(f"scenes: done={s['done']} error={s['error']} labels={s['labels']}")
    return 1 if s["error"] else 0


def _run_perturb(p, args):
    if args.per_object < 1 or not args.shift_mm > 0:
        p.error(f"--per-object {args.per_object} / --shift-mm {args.shift_mm:g}: give a count >= 1 and a distance > 0")
    try:
        exclude = set().union(*(read_name_list(f) for f in args.exclude))
        s = perturbed_grasps.run_perturb_stage(args.objects, args.meshes, args.per_object, args.shift_mm / 1000,
                                               args.seed, args.workers, exclude, progress=not args.no_progress)
    except (FileNotFoundError, ObjectError) as e:
        p.error(str(e))
    for e in s["errors"]:
        print(e)
    held = f"{s['held'] / s['tried']:.3f}" if s["tried"] else "n/a"
    print(f"perturb: objects_done={s['done']} kept={s['kept']} error={len(s['errors'])} "
          f"candidates={s['tried']} held_fraction={held}")
    return 1 if s["errors"] else 0


def _run_rescore_or_wrap(p, args):
    try:
        names = read_name_list(args.names) if args.names else None
        if args.stage == "rescore":
            s = rescored_tables.run_rescore_stage(args.objects, args.out, args.meshes, args.sim_setting,
                                                  args.max_held_rows, args.seed, args.workers, names,
                                                  progress=not args.no_progress)
            line = f"rescore: objects_done={s['done']} kept={s['kept']} rows_simulated={s['simulated']} held={s['held']}"
        else:
            s = power_grasps.run_wrap_stage(args.objects, args.meshes, args.per_object, args.max_turn_deg,
                                            args.max_depth_mm / 1000, seed=args.seed, workers=args.workers,
                                            names=names, progress=not args.no_progress)
            line = (f"wrap: objects_done={s['done']} kept={s['kept']} closings={s['tried']} held={s['held']} "
                    f"power={s['power']}")
    except (FileNotFoundError, ObjectError, ValueError) as e:
        p.error(str(e))
    for e in s["errors"]:
        print(e)
    print(f"{line} error={len(s['errors'])}")
    return 1 if s["errors"] else 0


def validation_names_of(model_path):
    """file name -> whether the model file's training held that scene out for validation."""
    from gravgrasp_detector.perception import model_file  # lazy: torch, for this option only
    from gravgrasp_detector.training.config import TrainConfig
    from gravgrasp_detector.training.scenes import split_scenes
    try:
        _, metadata = model_file.load_model(model_path)
    except model_file.ModelFileError as e:
        raise scene_recipes.RecipeError(f"--validation-of: {e}") from None
    config = (metadata.get("training_data") or {}).get("config") or {}
    defaults = TrainConfig(data="", out="")
    fraction = config.get("validation_fraction", defaults.validation_fraction)
    seed = config.get("seed", defaults.seed)
    return lambda name: bool(split_scenes([name], fraction, seed)[1])  # one file: its own hash decides


def _run_recipes(args):
    try:
        if args.action == "pack":
            s = scene_recipes.pack(args.scenes, args.recipes)
            print(f"recipes: scenes={s['scenes']} blocks_written={s['written']} ({args.recipes})")
            return 0
        keep = validation_names_of(args.validation_of) if args.validation_of else None
        s = scene_recipes.restore(args.recipes, args.out, args.objects, args.meshes, args.workers,
                                  progress=not args.no_progress, relabel=args.relabel, keep=keep)
    except scene_recipes.RecipeError as e:
        print(f"datagen recipes: {e}", file=sys.stderr)
        return 2
    for e in s["errors"]:
        print(e)
    if s["differing"]:
        print(f"{len(s['differing'])} rebuilt scenes have labels unlike the recorded ones (rounding on another "
              f"CPU or library version; kept): {', '.join(map(str, s['differing'][:20]))}")
    if args.relabel and s["label_counts"]:
        before, after = np.array(list(s["label_counts"].values())).T
        print(f"relabelled {len(before)} scenes: labels per scene median {np.median(before):g} -> "
              f"{np.median(after):g}, mean {before.mean():.1f} -> {after.mean():.1f}")
    print(f"restore: scenes={s['scenes']} restored={s['restored']} differing={len(s['differing'])} "
          f"error={len(s['errors'])}")
    return 1 if s["errors"] else 0


if __name__ == "__main__":
    sys.exit(main())
