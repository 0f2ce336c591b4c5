"""Grasp tables simulated again under other settings: `ros2 run sim_bridge datagen rescore`.

A new hand model (the self-locking drive) changes what a grasp holds, not where it is
sampled: the same candidates are closed again and scored with each table's own
`SimSettings` and the overrides given (e.g. drive=self_locking).
Rows that did not hold are copied as they are when the closing itself is unchanged
(`closing_unchanged`: only the drive and the ramps differ; the drive engages after the
hand has settled), and simulated again otherwise. Toward-the-palm rows
(`power_grasps`) of the source are not copied: the wrap stage makes them anew.

One output table per source table, `<out>/objects/<name>.npz`, in the source's format with
the new `sim_settings`; `rescored_from` names the source table. Resumable per object (a
finished table is kept); `max_held_rows` takes a seeded sample of the held rows (a gated
study's subset; 0 = all).
"""

import dataclasses
import json
import pathlib
import shutil
from dataclasses import dataclass

import numpy as np
from gravgrasp_detector import atomic_files

from ..parallel import task_seed
from ..physics.contact import SimSettings
from ..physics.grasp_simulation import GraspSimulator
from .object_grasps import ROW_KEYS, evaluate_candidate, load_table, stack_rows
from .object_sources import object_from_table
from .per_object_stage import run_per_object

# Settings that act only after the hand has settled (the drive engages then) or on the
# ramps: changing only these leaves every closing, and so every failed row, as it was.
AFTER_SETTLING = frozenset({"drive", "lock_stiffness_nm_per_rad", "lock_damping_nm_s_per_rad",
                            "force_ramp_rate_n_s", "max_force_n", "departure_travel_m", "resistance_window_s"})


def closing_unchanged(old: SimSettings, new: SimSettings) -> bool:
    a, b = dataclasses.asdict(old), dataclasses.asdict(new)
    return all(a[k] == b[k] for k in a if k not in AFTER_SETTLING)


@dataclass(frozen=True)
class RescoreTask:
    name: str
    table_path: str
    out_path: str
    mesh_dirs: tuple
    overrides: tuple  # ("key=value", ...) over the table's own settings
    max_held_rows: int
    seed: int


def rows_to_simulate(table, old, new, max_held_rows, seed) -> np.ndarray:
    """Indices of the rows to simulate again (the rest are copied)."""
    held = np.flatnonzero(table["grasped"].astype(bool))
    if max_held_rows and len(held) > max_held_rows:
        rng = np.random.default_rng(task_seed(seed, "rescore", str(table["name"])))
        held = np.sort(rng.choice(held, max_held_rows, replace=False))
    if closing_unchanged(old, new):
        return held
    return np.arange(len(table["grasped"])) if not max_held_rows else held


def rescored_rows(table):
    """For a table of `datagen rescore` (it names its source in `rescored_from`): (mask of the
    rows it simulated again, mask of the rows held in the source), or None where the source
    table cannot be read (its path is as the rescore was given it, e.g. relative to the project)."""
    if "rescored_from" not in table.files or not pathlib.Path(str(table["rescored_from"])).is_file():
        return None
    with np.load(str(table["rescored_from"])) as source:
        n = len(table["grasped"])
        if len(source["grasped"]) != n:  # a sample of held rows (--max-held-rows): each was simulated
            return np.ones(n, bool), np.ones(n, bool)
        settings = (SimSettings.from_record(json.loads(str(t["sim_settings"]))) for t in (source, table))
        again = np.zeros(n, bool)
        again[rows_to_simulate(source, *settings, 0, 0)] = True
        return again, source["grasped"].astype(bool)


def run_rescore_task(task: RescoreTask):
    """Worker: one table simulated again. Returns ("ok", (rows simulated, held)) or ("error", msg)."""
    try:
        table = load_table(task.table_path)
        old = SimSettings.from_record(json.loads(str(table["sim_settings"])))
        new = with_overrides(old, task.overrides)
        rows = rows_to_simulate(table, old, new, task.max_held_rows, task.seed)
        if task.max_held_rows:  # a sample: the table is just those rows
            keep = rows
        else:
            keep = np.arange(len(table["grasped"]))
        sim = GraspSimulator(object_from_table(table, task.mesh_dirs), new)
        fresh = {int(i): dict(evaluate_candidate(sim, table["X_object_tcp_candidate"][i].astype(float)),
                              rest_pose=np.int16(table["rest_pose"][i])) for i in rows}
        new_rows = stack_rows([fresh[int(i)] for i in keep if int(i) in fresh])
        out = dict(table)
        names = [str(n) for n in table["finger_joint_names"]]
        angles = table["finger_joint_angles"][keep].copy()
        for key in ROW_KEYS:
            out[key] = table[key][keep].copy()
        at = np.flatnonzero(np.isin(keep, rows))
        for key in ROW_KEYS:
            out[key][at] = new_rows[key].astype(out[key].dtype)
        for j, n in enumerate(new_rows["finger_joint_names"]):
            if str(n) in names:
                angles[at, names.index(str(n))] = new_rows["finger_joint_angles"][:, j]
        out.update(finger_joint_angles=angles, sim_settings=np.asarray(json.dumps(dataclasses.asdict(new), sort_keys=True)),
                   rescored_from=np.asarray(str(task.table_path)))
        atomic_files.save_npz(pathlib.Path(task.out_path), **out)
        return "ok", (len(rows), int(out["grasped"].sum()))
    except Exception as e:  # reported, retried on the next run; the other objects go on
        return "error", f"{task.name}: {type(e).__name__}: {e}"


def with_overrides(settings: SimSettings, overrides) -> SimSettings:
    """`settings` with "key=value" overrides (types from the fields' defaults); ValueError
    for an unknown key or a bad value."""
    from .cli import sim_settings  # lazy: cli imports this module (the one parser of "key=value" settings)
    base = [f"{k}={v}" for k, v in dataclasses.asdict(settings).items() if v is not None]
    return sim_settings(base + list(overrides))


def run_rescore_stage(source_out, out, mesh_dirs, overrides=(), max_held_rows=0, seed=0, workers=None,
                      names=None, progress=True):
    """Every table of `source_out`/objects (or those in `names`) simulated again into
    `out`/objects with its own settings and `overrides` ("key=value", e.g.
    "drive=self_locking"). Returns a summary dict."""
    src = pathlib.Path(source_out) / "objects"
    if not src.is_dir():
        raise FileNotFoundError(f"{source_out} holds no grasp tables (no objects/ directory)")
    with_overrides(SimSettings(), overrides).validate()  # a bad override: one message before any work
    dst = pathlib.Path(out) / "objects"
    dst.mkdir(parents=True, exist_ok=True)
    atomic_files.remove_stale_temporaries(dst)
    for skip in src.glob("*.skip.json"):  # objects the source could not use stay unused
        if not (dst / skip.name).exists():
            shutil.copy(skip, dst / skip.name)
    tasks, kept = [], 0
    for path in sorted(src.glob("*.npz")):
        if names is not None and path.stem not in names:
            continue
        target = dst / path.name
        if target.exists():
            kept += 1
            continue
        tasks.append(RescoreTask(path.stem, str(path), str(target), tuple(mesh_dirs), tuple(overrides),
                                 max_held_rows, seed))
    return run_per_object(run_rescore_task, tasks, kept, ("simulated", "held"), "rescore", workers, progress)
