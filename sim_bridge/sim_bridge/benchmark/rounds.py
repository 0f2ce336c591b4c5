"""One benchmark round as a worker task (the method's detector and hand, `run_round`) and
the run over methods x weights x scenes (`run_benchmark`): resumable, its rounds and scenes
kept in rounds.jsonl and scenes.jsonl (run_files). The methods are benchmark.methods.METHODS."""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import dataclasses
import json
import os
import pathlib
import time
from concurrent.futures.process import BrokenProcessPool

import torch

from gravgrasp_detector.perception.model_file import file_sha256

from gravgrasp_detector import atomic_files
from ..parallel import make_executor, run_tasks, task_seed
from ..world import WorldSettings
from . import failed_rounds, run_files
from .clearing import clear_table
from .machine import machine_name
from .methods import PROVIDERS, MethodFileMissing, method_named, method_of
from .protocol import (ABLATION_METHODS, LEGACY_EXECUTION, MAX_POOLS, OBJECTS_PER_SCENE, PROCEDURAL_SEED,
                       SCHEMA_VERSION, Protocol, execution_name, execution_of,
                       SceneDrawTask, make_scene, object_pool, scene_ids, weight_key)
from .report import write_outputs
from .sim_cell import SimCell

# one round (a worker task)


@dataclasses.dataclass(frozen=True)
class RoundTask:
    method: str  # a methods.METHODS name, or one given by --model NAME=PATH
    model_path: str  # the method's file (methods.Method.locate)
    model_sha256: str
    mass_kg: float
    scene: dict
    protocol: Protocol
    baselines_dir: str = ""  # the Panda hand's files ("": physics.baseline_files' default)
    provider: str = ""  # the module that registers a study's method (methods.PROVIDERS), "" for the registry's


def make_cell(task: RoundTask) -> tuple:
    """(SimCell of the round's scene and weight with its method's detector and hand,
    the methods.Detector)."""
    method = method_of(task.method, task.model_path, task.provider)
    told = {"payload_kg": task.mass_kg} if method.told_payload else {}
    detector = method.make(task.model_path, task.protocol, **told)
    cell = SimCell(task.scene, task.mass_kg, task.protocol, detector.volume, detector.detect, method.hand,
                   task.baselines_dir)
    return cell, detector


def run_round(task: RoundTask) -> dict:
    torch.set_num_threads(1)  # one core per round: the pool gives the parallelism
    t0 = time.process_time()
    cell, detector = make_cell(task)
    settle_s = cell.settle()
    left_before_start = cell.remove_fallen()  # not counted: no method could have grasped them
    names = cell.objects_on_table()
    n_objects = len(names)
    record = clear_table(cell, n_objects, task.protocol.attempts_per_object)
    return {"schema_version": SCHEMA_VERSION, "method": task.method, "hand": cell.hand,
            "model_sha256": task.model_sha256, "target": detector.target, "mass_kg": task.mass_kg, "scene_id": task.scene["scene_id"],
            "objects": names, "n_objects": n_objects, "left_before_start": left_before_start,
            "settle_s": round(settle_s, 2), **record,
            "successes": sum(a["success"] for a in record["attempts"]),
            "sim_time_s": round(cell.world.time_s, 3), "cpu_s": round(time.process_time() - t0, 1),
            "machine": machine_name(),
            "execution": {k: getattr(task.protocol, k) for k in LEGACY_EXECUTION}, "drive": task.protocol.drive}


# the run




def resolve_methods(names, models_dir, overrides=None, note=print, baselines_dir=None):
    """{method: its file's path} of the methods whose files (and hand's files) are there;
    a note per missing one. ValueError for a name that is neither registered
    (methods.METHODS) nor given a file in `overrides` ({name: path}, --model NAME=PATH)."""
    overrides = overrides or {}
    found = {}
    for name in names:
        if name not in overrides:
            method_named(name)  # one error naming the known methods
        method = method_of(name, overrides.get(name, ""))
        try:
            path = method.locate(models_dir, baselines_dir, overrides.get(name) or overrides.get(method.file_of))
            WorldSettings(hand=method.hand, baselines_dir=baselines_dir or "").validate()  # the hand's files
        except MethodFileMissing as e:
            note(f"benchmark: skipping {name}: {e}")
            continue
        except FileNotFoundError as e:  # the hand's files (physics.baseline_files)
            note(f"benchmark: skipping {name}: its {method.hand} hand: {e}")
            continue
        found[name] = str(path)
    return found


def method_weights(method, weights_kg, ablation_weights_kg=None) -> list:
    if method in ABLATION_METHODS and ablation_weights_kg is not None:
        return [float(w) for w in ablation_weights_kg]
    return [float(w) for w in weights_kg]


def unreported_rounds(out, plan: dict) -> list:
    """'method at W kg' for each method and weight with rounds in the run `out` that `plan`
    ({method: [kg]}) does not name: a report for the plan rewrites the run's summaries without them."""
    ran = sorted({(r["method"], float(r["mass_kg"])) for r in run_files.rounds_file(out).records()})
    return [f"{method} at {weight_key(kg)} kg" for method, kg in ran
            if not (method in plan and kg in {float(w) for w in plan[method]})]


DEFAULT_MODELS_DIR = "models"  # the shipped models


def models_dir_of_run(out_dir) -> str | None:
    """Where the run in `out_dir` found its model files (its config.json; DEFAULT_MODELS_DIR
    when it recorded none), or None where no run is. The CLI's --models-dir defaults to it,
    so that resuming or reporting a run of other models (e.g. models/v6) keeps them."""
    path = pathlib.Path(out_dir) / "config.json"
    return json.loads(path.read_text()).get("models_dir", DEFAULT_MODELS_DIR) if path.is_file() else None


def _same_dir(a, b) -> bool:
    return os.path.realpath(a) == os.path.realpath(b)


def run_benchmark(out_dir, methods: dict, weights_kg, n_scenes: int, seed: int = 0, meshes_dir=None,
                  protocol: Protocol = Protocol(), workers=None, scheduler=None, progress=True, note=print,
                  ablation_weights_kg=None, only_meshes=None, report_only=False, baselines_dir=None,
                  retry_failed=False, procedural_seed=PROCEDURAL_SEED, models_dir=None) -> list:
    """Run (or resume) every round; write the outputs; return the summary rows.
    `methods`: {name: its file's path} (resolve_methods); `baselines_dir`: where the
    Panda hand's files are (None: physics.baseline_files' default); ABLATION_METHODS run at `ablation_weights_kg` if given;
    `only_meshes`: names of the meshes in `meshes_dir` to draw scenes from (None: all);
    `report_only`: run nothing, write the outputs of the rounds finished so far (an interim
    look at a run that is still going, in the same directory); `retry_failed`: run again the rounds
    Drake could not simulate before (failed_rounds; else they are not rerun); `procedural_seed`:
    the procedural objects' seed without `meshes_dir` (recorded in config.json: a resume with
    another seed is refused); `models_dir`: where `methods`' model files were found (recorded
    when not DEFAULT_MODELS_DIR: a run of other models keeps them, models_dir_of_run; another
    one for the same run is refused; None: not said, the run's own is kept)."""
    only = tuple(sorted(only_meshes)) if only_meshes is not None else None
    plan = {m: method_weights(m, weights_kg, ablation_weights_kg) for m in methods}
    out = pathlib.Path(out_dir)
    if not report_only:  # a report must not touch the temporaries of a run still writing there
        out.mkdir(parents=True, exist_ok=True)
        atomic_files.remove_stale_temporaries(out)
    config = {"seed": seed, "meshes": str(pathlib.Path(meshes_dir).resolve()) if meshes_dir else None,
              "procedural_seed": None if meshes_dir else int(procedural_seed), "objects_per_scene": OBJECTS_PER_SCENE,
              "protocol": dataclasses.asdict(protocol)}
    for off_by_default in ("clear_hand", "close_on_contact_within_m"):
        if not getattr(protocol, off_by_default):  # older runs' config.json has no such key: they stay resumable
            del config["protocol"][off_by_default]
    if protocol.drive == "backdrivable":  # likewise: every run before the lock
        del config["protocol"]["drive"]
    if only is not None:  # older runs' config.json has no such key: they stay resumable
        config["only_meshes"] = list(only)
    if models_dir is not None and not _same_dir(models_dir, DEFAULT_MODELS_DIR):  # likewise
        config["models_dir"] = os.path.normpath(models_dir)
    # The hand of each method run there: a method's, not the run's setting, so it is kept
    # apart from the comparison (methods may join a run later; runs from before it have none).
    hands = {m: method_of(m, p).hand for m, p in methods.items()}
    machines = [machine_name()]
    config_path = out / "config.json"
    if report_only and not config_path.exists():
        raise ValueError(f"{out} holds no benchmark run (no config.json): give the --out of a run")
    if config_path.exists():
        previous = json.loads(config_path.read_text())
        ran_on = previous.pop("hands", {})
        # Not a setting: a run resumed on another machine type keeps its rounds (each
        # round's record names its machine; the report lists them).
        machines = sorted(set(previous.pop("machines", [])) | set(machines))
        for m in hands:
            if ran_on.get(m, hands[m]) != hands[m]:
                raise ValueError(f"{out}: {m} ran there on the {ran_on[m]} hand, now it runs on the {hands[m]} "
                                 "hand: use another --out")
        hands = {**ran_on, **hands}
        previous["protocol"].update(execution_of(previous["protocol"]))  # written before they were recorded
        if previous != config and {**previous, "protocol": {**previous["protocol"], **execution_of(config["protocol"])}} == config:
            raise ValueError(f"{out} was run under execution settings {execution_name(previous['protocol'])}, not "
                             f"{execution_name(config['protocol'])}: rounds run under different settings are never "
                             f"pooled; pass --execution {execution_name(previous['protocol'])} or use another --out")
        ran_seed, seed_now = previous.get("procedural_seed"), config["procedural_seed"]
        if None not in (ran_seed, seed_now) and ran_seed != seed_now:
            raise ValueError(f"{out} was run on the procedural objects of seed {ran_seed}, not {seed_now}: pass "
                             f"--procedural-seed {ran_seed} or use another --out")
        ran_models = previous.get("models_dir", DEFAULT_MODELS_DIR)
        if models_dir is not None and not _same_dir(ran_models, models_dir):
            raise ValueError(f"{out} ran the model files of {ran_models}/, not {os.path.normpath(models_dir)}/: pass "
                             f"--models-dir {ran_models} or use another --out")
        if "models_dir" in previous:  # the same directory (checked above), as the run first wrote it
            config["models_dir"] = previous["models_dir"]
        if previous != config:
            raise ValueError(f"{out} holds a run with another configuration ({config_path}); "
                             "use another --out, or delete it to start over")
    shas = {m: file_sha256(p) for m, p in methods.items()}
    ids = scene_ids(n_scenes)
    failed = failed_rounds.load(out)
    if report_only:
        listed = out / "excluded_objects.json"  # absent only if the run was stopped within its first second
        excluded = json.loads(listed.read_text()) if listed.exists() else []
        left_out = unreported_rounds(out, plan)
        if left_out:  # its summaries (comparisons.json, attempts.json) are rewritten without them
            note(f"benchmark: this report leaves out the rounds in {out} of {', '.join(left_out)} (not named in "
                 "--methods/--weights); name them too to keep them in results.md, comparisons.json and attempts.json")
        return write_outputs(out, plan, shas, ids, excluded, protocol, meshes_dir, only, failed,
                             config["procedural_seed"])
    atomic_files.save_json(config_path, {**config, "hands": hands, "machines": machines})

    usable, excluded = object_pool(meshes_dir, only=only, procedural_seed=config["procedural_seed"])
    atomic_files.save_json(out / "excluded_objects.json", list(excluded))
    scene_file, round_file = run_files.scenes_file(out), run_files.rounds_file(out)
    scenes, pending = {}, []
    for sid in ids:
        scene = scene_file.get(sid)
        if scene is not None:
            scenes[sid] = scene
        else:
            pending.append(SceneDrawTask(sid, task_seed(seed, "scene", sid), tuple(usable)))

    def done(method, w, sid):
        r = round_file.get(method, w, sid)
        if r is not None and r.get("model_sha256") == shas[method]:
            return True
        gave_up = failed.get(failed_rounds.key(method, w, sid), {}).get("model_sha256") == shas[method]
        return gave_up and not retry_failed

    def on_scene(task, scene):
        scene_file.put(scene)
        scenes[task.scene_id] = scene

    def on_round(task, result):
        k = failed_rounds.key(task.method, task.mass_kg, task.scene["scene_id"])
        if "error" in result:
            errors.append((task, result["error"]))
            if result.get("simulation_failed"):  # fails the same way on every rerun: recorded once
                failed[k] = failed_rounds.record(*k, task.model_sha256, result["error"], machine_name())
                failed_rounds.save(out, failed)
        else:
            round_file.put(result)
            if failed.pop(k, None) is not None:  # retried, and it ran this time
                failed_rounds.save(out, failed)

    errors = []
    # A native crash (Drake) kills its worker and breaks the whole pool: finished rounds
    # are on disk, so start a new pool for the rest, a few times.
    for pool_generation in range(MAX_POOLS):
        try:
            with _executor(workers, scheduler) as ex:
                pending = [t for t in pending if t.scene_id not in scenes]
                if pending:
                    run_tasks(ex, make_scene, pending, on_scene, desc="scenes", progress=progress)
                # Scene-major order: a run cut short has every method on the same scenes.
                tasks = [RoundTask(m, path, shas[m], w, scenes[sid], protocol, baselines_dir or "", PROVIDERS.get(m, ""))
                         for sid in ids for w in sorted({w for ws in plan.values() for w in ws})
                         for m, path in methods.items() if w in plan[m] and not done(m, w, sid)]
                errors.clear()
                if tasks:
                    run_tasks(ex, _guarded_round, tasks, on_round, desc="rounds", progress=progress)
            break
        except BrokenProcessPool as e:
            if pool_generation == MAX_POOLS - 1:
                raise
            note(f"benchmark: a worker process died ({e}); continuing with a new pool")
    for task, message in errors:
        note(f"benchmark: round {task.method} {task.mass_kg} kg {task.scene['scene_id']} failed: {message}")
    return write_outputs(out, plan, shas, ids, excluded, protocol, meshes_dir, only, failed,
                         config["procedural_seed"])


def _guarded_round(task):
    """A round that raises is reported, not fatal to the others. A RuntimeError (Drake's:
    the simulation itself failed) is recorded once (failed_rounds); any other error is
    retried by the next run."""
    try:
        return run_round(task)
    except Exception as e:  # Drake, a bad object, a model that does not fit the volume
        return {"error": f"{type(e).__name__}: {str(e).strip().splitlines()[0][:300] if str(e).strip() else ''}",
                "simulation_failed": isinstance(e, RuntimeError)}


class _InProcess:
    """A sequential executor (workers=0): for tests and debugging."""
    def submit(self, fn, *args):
        f = cf.Future()
        try:
            f.set_result(fn(*args))
        except BaseException as e:
            f.set_exception(e)
        return f


def _executor(workers, scheduler):
    if workers == 0 and not scheduler:
        return contextlib.nullcontext(_InProcess())
    return make_executor(workers, scheduler)
