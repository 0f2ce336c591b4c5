"""Clutter-removal benchmark against object weight (paper Sec. V-B/V-C):
`ros2 run sim_bridge benchmark`. No rclpy: the Drake world, the TSDF, the detector and
the grasp executor run in-process, in simulated time.

Protocol (one *round* = one method, one object weight, one scene):
- Scenes: 5 objects, `packed` and `pile` in turn, drawn and arranged once per scene
  from a seed derived from the master seed (scenes.jsonl), so every method and
  weight clears the same scenes. Every object of a round gets the round's weight.
- Objects: procedural primitives with procedural seed 1000 by default (training uses
  seed 0: disjoint; `--procedural-seed N` draws others, e.g. 2000 for a confirmation run on
  objects no choice was tuned on), or `--meshes DIR` (URDF/OBJ; `--only FILE` keeps the meshes it
  names, e.g. the held-out list models/vgn_heldout_meshes.txt). Objects wider than the 85 mm stroke
  in every direction (minimum width of the collision hull) are removed before the run
  and listed (excluded_objects.json, results.md), as the paper did.
- Start: the scene settles at the round's weight (a heavier pile shifts; objects that
  leave the cube then are `left_before_start`, not counted).
- Attempt: the hand goes home (open, out of the cube) -> one depth image from the
  fixed camera (CameraSettings: 0.55 m from the table centre, 60 deg elevation) -> a
  fresh TSDF -> detection -> the best-ranked grasp that passes the executor's own
  checks (workspace box, approach cone, open hand vs TSDF; the hand floats as in the
  paper, no arm IK) -> GraspExecutor (open, pre-grasp, approach, close at 40 N, lift
  0.15 m, gOBJ check) -> hold 1.0 s, then shake (3 cm up/down, then 3 cm along x and
  back, min-jerk at 0.25 m/s: peak 3.4 m/s², up to 1.35 g on the grip vertically) ->
  success iff an object is still between both fingers and >= 5 cm above the table.
  Lifted objects are removed; objects that leave the cube are `fell_off` (not cleared);
  removed objects and those gone past the table are taken out of the physics
  (world.out_of_play: left to fall, they once made Drake's poses non-finite).
- A round ends when the table is clear, after 2 consecutive failures, when nothing is
  detected or no detected grasp passes the checks, or at 3 x objects attempts.
- SR = successes / attempts, CR = successes / objects, pooled over rounds, with 95 %
  Wilson intervals; each method's SR against Binary's at the same weight, per scene and
  paired (which decides: a sign-flip permutation test over the scenes' SR differences,
  benchmark/paired.py, printed `p_paired_<method>_vs_binary_<kg>=`) and pooled (a
  two-proportion z test over attempts, `p_<method>_vs_binary_<kg>=`); Ours against
  Ours-Precision the same way, the paper's power-grasp effect
  (`p_paired_ours_vs_ours_precision_<kg>=`, power_grasp_effect.json); results.md. For
  planning: the scenes a paired run would need to find a 10-point difference at p < 0.05
  with 80 % power, from the spread of this run's per-scene differences
  (`scenes_for_10pts_<method>_vs_binary_<kg>=`).
- Attempts lost before the lift (closed on nothing, contact stops, rounds that ended with
  every grasp refused), per method and weight and against Binary's: results.md,
  `before_lift_<method>_<kg>=`.

Methods are detectors with the hand that executes them (benchmark.methods.METHODS): the
project's model files on the 2F-85 and `vgn`, VGN's published weights on the Panda hand
(from the baselines directory, `--baselines DIR`); a method whose file is missing is
skipped with a note saying where to get it. `ours_expected` (named in --methods only)
runs Ours' model ranked by validness x score. The rotation ablation's extra models run at
`ABLATION_*WEIGHTS_KG` only. A model trained with `--target binary` ranks by validness (a
success probability) and no min-score-in-N threshold applies to it. Each round record
names its method's hand, as config.json does ("hands").

Engineering: one task per round through parallel.run_tasks (process pool or Dask);
each round's result goes into the run's rounds.jsonl (benchmark.run_files, rewritten
atomically) with the model file's sha256, so a rerun skips finished rounds (and redoes those of a
retrained model); everything runs in simulated time, so a seed gives the same attempts.
A round Drake cannot simulate (a RuntimeError) fails the same way every time: it is
recorded once in failed_rounds.json, listed in results.md and not rerun
(`--retry-failed` runs it again).
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys
import time
from concurrent.futures.process import BrokenProcessPool

from ..datagen.object_sources import read_name_list
from ..physics import baseline_files
from ..physics.objects import ObjectError
from ..physics.transmission import DRIVES
from . import failed_rounds
from .methods import DEFAULT_METHODS, METHODS
from .protocol import (ABLATION_METHODS, FULL_ABLATION_WEIGHTS_KG, FULL_WEIGHTS_KG, QUICK_ABLATION_WEIGHTS_KG,
                       QUICK_WEIGHTS_KG, DEFAULT_EXECUTION, EXECUTION_SETTINGS, PROCEDURAL_SEED,
                       TRAINING_PROCEDURAL_SEED, Protocol, drive_of_run, execution_of_run, weight_in_name)
from .rounds import DEFAULT_MODELS_DIR, models_dir_of_run, resolve_methods, run_benchmark

# CLI


def parse_weights(text) -> list:
    try:
        weights = [float(w) for w in text.split(",")]
    except ValueError:
        weights = []
    if not weights or not all(math.isfinite(w) and w > 0 for w in weights):
        raise ValueError(f"weights {text!r}: give positive kg values separated by commas, e.g. 0.1,1.5")
    return weights


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="Clutter-removal benchmark against object weight (paper Sec. V-B/V-C).")
    p.add_argument("--out", default=None, help="output directory (resumes there); default out/benchmark[_quick]")
    p.add_argument("--quick", action="store_true", help=f"2 scenes (1 packed, 1 pile), weights "
                   f"{', '.join(map(str, QUICK_WEIGHTS_KG))} kg: CI minutes")
    p.add_argument("--scenes", type=int, default=None, help="scenes (packed and pile alternate); default 10, quick 2")
    p.add_argument("--weights", default=None, help="comma-separated kg; default 0.1,0.3,0.5,0.8,1.0,1.5")
    p.add_argument("--ablation-weights", default=None,
                   help=f"weights of {', '.join(ABLATION_METHODS)}; default 0.5 (quick 0.1), or --weights when given")
    p.add_argument("--methods", default=",".join(DEFAULT_METHODS),
                   help=f"comma-separated, of {', '.join(METHODS)}; default {','.join(DEFAULT_METHODS)} "
                        "(benchmark.methods)")
    p.add_argument("--models-dir", default=None, metavar="DIR",
                   help="where the project's model files are (default: the run's own, recorded in its config.json "
                        f"when not {DEFAULT_MODELS_DIR!r}, else {DEFAULT_MODELS_DIR!r}); e.g. a directory of models "
                        "trained on other labels, benchmarked under the same method names")
    p.add_argument("--baselines", default=None, metavar="DIR",
                   help="the baselines' files (VGN's weights, the Panda hand); default: GRAVGRASP_BASELINES, "
                        f"else {baseline_files.baselines_dir()}")
    p.add_argument("--model", action="append", default=[], metavar="NAME=PATH",
                   help="a model file for a method (also a new method name)")
    p.add_argument("--meshes", default=None, help="URDF/OBJ directory instead of procedural objects")
    p.add_argument("--only", default=None, metavar="FILE",
                   help="with --meshes: use only the meshes named in FILE (one name per line, e.g. "
                        "models/vgn_heldout_meshes.txt)")
    p.add_argument("--procedural-seed", type=int, default=None, metavar="N",
                   help=f"the procedural objects' seed (not with --meshes); default {PROCEDURAL_SEED}, the one the "
                        "protocol was tuned on; recorded in config.json")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=None, help="local processes (default: CPU count; 0 = this process)")
    p.add_argument("--scheduler", default=None, help="Dask scheduler address, e.g. tcp://host:8786")
    p.add_argument("--validness-threshold", type=float, default=Protocol.validness_threshold)
    p.add_argument("--min-score-n", type=float, default=Protocol.min_score_n,
                   help="ignore grasps scored below this [N] (not applied to binary models)")
    p.add_argument("--clear-hand", action="store_true",
                   help="detection's step 6: only grasps whose open hand clears the observed scene "
                        "(the detect node's clear_hand); default: the paper's selection")
    p.add_argument("--close-on-contact-within-m", type=float, default=Protocol.close_on_contact_within_m,
                   help="the executor's guarded approach: an approach the arm's contact stop halts at most this "
                        "far short of the grasp closes there instead of backing out [m]; default 0: off, as the "
                        "execute node")
    p.add_argument("--hold-s", type=float, default=Protocol.hold_s)
    p.add_argument("--shake-m", type=float, default=Protocol.shake_m, help="0 = no shake")
    p.add_argument("--time-step-s", type=float, default=Protocol.time_step_s)
    p.add_argument("--relaxation-time-s", type=float, default=Protocol.relaxation_time_s,
                   help="SAP relaxation time of every contact; default: SimSettings' choice for the time step")
    p.add_argument("--execution", default=None, choices=sorted(EXECUTION_SETTINGS),
                   help="how rounds are simulated (protocol.EXECUTION_SETTINGS; v4: every run up to benchmark v4); "
                        f"default: the settings of the run already in --out, else {DEFAULT_EXECUTION}")
    p.add_argument("--drive", default=None, choices=DRIVES,
                   help="the 2F-85's transmission in the cell (physics.transmission): self_locking holds what it "
                        "gripped as the real one does; backdrivable opens at the grip force (every run before the "
                        "lock); default: the drive of the run already in --out, else self_locking")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--report", action="store_true",
                   help="run nothing: write results.md etc. from the rounds finished so far in --out (same "
                        "options as the run; safe while that run goes on, which rewrites them at its end)")
    p.add_argument("--retry-failed", action="store_true",
                   help="run again the rounds Drake could not simulate (failed_rounds.json; not rerun otherwise)")
    args = p.parse_args(argv)

    n_scenes = args.scenes or (2 if args.quick else 10)
    try:
        weights = parse_weights(args.weights) if args.weights else list(
            QUICK_WEIGHTS_KG if args.quick else FULL_WEIGHTS_KG)
        ablation = (parse_weights(args.ablation_weights) if args.ablation_weights else weights if args.weights
                    else list(QUICK_ABLATION_WEIGHTS_KG if args.quick else FULL_ABLATION_WEIGHTS_KG))
    except ValueError as e:
        print(f"benchmark: {e}", file=sys.stderr)
        return 2
    only = None
    if args.only:
        if not args.meshes:
            print("benchmark: --only selects among --meshes: give the mesh directory too", file=sys.stderr)
            return 2
        try:
            only = read_name_list(args.only)
        except ObjectError as e:
            print(f"benchmark: --only: {e}", file=sys.stderr)
            return 2
    if args.procedural_seed is not None and args.meshes:
        print("benchmark: --procedural-seed draws the procedural objects, which --meshes replaces: give one "
              "of them", file=sys.stderr)
        return 2
    procedural_seed = PROCEDURAL_SEED if args.procedural_seed is None else args.procedural_seed
    if procedural_seed == TRAINING_PROCEDURAL_SEED:
        print(f"benchmark: --procedural-seed {procedural_seed} draws the objects the models were trained on: "
              f"give another seed (default {PROCEDURAL_SEED}, the tuning seed)", file=sys.stderr)
        return 2
    if procedural_seed < 0:
        print(f"benchmark: --procedural-seed {procedural_seed}: give a seed >= 1", file=sys.stderr)
        return 2
    overrides = {}
    for item in args.model:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            print(f"benchmark: --model {item!r}: use NAME=PATH", file=sys.stderr)
            return 2
        overrides[name] = path
    names = [m for m in args.methods.split(",") if m] + [m for m in overrides if m not in args.methods.split(",")]
    out = args.out or ("out/benchmark_quick" if args.quick else "out/benchmark")
    models_dir = args.models_dir or models_dir_of_run(out) or DEFAULT_MODELS_DIR
    try:
        methods = resolve_methods(names, models_dir, overrides, baselines_dir=args.baselines)
    except ValueError as e:
        print(f"benchmark: {e}", file=sys.stderr)
        return 2
    if not methods:
        print("benchmark: no method has its files (see the notes above): train the models (models/), pass "
              "--model NAME=PATH, or --baselines DIR for the baselines", file=sys.stderr)
        return 2
    if not (math.isfinite(args.close_on_contact_within_m) and args.close_on_contact_within_m >= 0):
        print(f"benchmark: --close-on-contact-within-m {args.close_on_contact_within_m}: give a distance >= 0 [m] "
              "(0 = off)", file=sys.stderr)
        return 2
    execution = args.execution or execution_of_run(out) or DEFAULT_EXECUTION
    drive = args.drive or drive_of_run(out) or "self_locking"
    protocol = Protocol(validness_threshold=args.validness_threshold, min_score_n=args.min_score_n,
                        hold_s=args.hold_s, shake_m=args.shake_m, time_step_s=args.time_step_s,
                        relaxation_time_s=args.relaxation_time_s, clear_hand=args.clear_hand,
                        close_on_contact_within_m=args.close_on_contact_within_m, drive=drive,
                        **EXECUTION_SETTINGS[execution])
    t0 = time.monotonic()
    try:
        rows = run_benchmark(out, methods, weights, n_scenes, args.seed, args.meshes, protocol,
                             args.workers, args.scheduler, progress=not args.no_progress,
                             ablation_weights_kg=ablation, only_meshes=only, report_only=args.report,
                             baselines_dir=args.baselines, retry_failed=args.retry_failed,
                             procedural_seed=procedural_seed, models_dir=models_dir)
    except (ObjectError, ValueError) as e:
        print(f"benchmark: {e}", file=sys.stderr)
        return 2
    except BrokenProcessPool as e:
        print(f"benchmark: worker processes keep dying ({e}); finished rounds are kept: rerun the same "
              "command to resume", file=sys.stderr)
        return 3
    missing = sum(n_scenes - r["rounds"] for r in rows)
    gave_up = sum(1 for method, *_ in failed_rounds.load(out) if method in methods)
    print(f"benchmark: {out}/results.md, attempts.json, sr_cr_vs_weight.png ({time.monotonic() - t0:.0f} s)"
          + (f"; {gave_up} rounds Drake could not simulate, listed in results.md (--retry-failed reruns them)"
             if gave_up else "")
          + (("; rounds not finished yet: an interim report" if args.report else
              "; some rounds failed: rerun to retry them") if missing > gave_up else ""), flush=True)
    effect_file = pathlib.Path(out) / "power_grasp_effect.json"
    print("\n".join(figure_lines(rows, json.loads((pathlib.Path(out) / "comparisons.json").read_text()),
                                 json.loads(effect_file.read_text()) if effect_file.exists() else [])))
    return 1 if missing and not args.report else 0


def figure_lines(rows: list, comparisons: list, power_effect: list) -> list:
    """The run's figures, one `name=value` a line, SR last: the results.json rows,
    comparisons.json (against Binary) and power_grasp_effect.json (Ours against Ours-Precision)."""
    kg = weight_in_name
    lines = [f"CR_{r['method']}_{kg(r['mass_kg'])}={r['CR']:.2f}" for r in rows]
    lines += [f"before_lift_{r['method']}_{kg(r['mass_kg'])}={r['before_lift']['total']}" for r in rows]
    for c in comparisons:
        lines.append(f"p_{c['method']}_vs_binary_{kg(c['mass_kg'])}={c['p_value']:.3f}")
        if c.get("paired"):
            lines.append(f"p_paired_{c['method']}_vs_binary_{kg(c['mass_kg'])}={c['paired']['p_value']:.3f}")
            if not math.isnan(c["paired"].get("scenes_for_10pts", math.nan)):  # older comparisons.json lack it
                lines.append(f"scenes_for_10pts_{c['method']}_vs_binary_{kg(c['mass_kg'])}="
                             f"{c['paired']['scenes_for_10pts']:.0f}")
    for c in power_effect:
        if not math.isnan(c["diff"]):
            lines.append(f"diff_ours_vs_ours_precision_{kg(c['mass_kg'])}={c['diff']:+.3f}")
            lines.append(f"p_paired_ours_vs_ours_precision_{kg(c['mass_kg'])}={c['p_value']:.3f}")
    return lines + [f"SR_{r['method']}_{kg(r['mass_kg'])}={r['SR']:.2f}" for r in rows]


if __name__ == "__main__":
    sys.exit(main())
