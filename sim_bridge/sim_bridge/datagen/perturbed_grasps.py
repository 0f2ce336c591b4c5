"""Grasps near the edge of holding: `ros2 run sim_bridge datagen perturb`.

A table's candidates are antipodal pairs with a few millimetres of lateral jitter, and
~88 % of them hold, so the labels show the network few poses where a grasp stops holding.
The benchmark's confident misses sit there: the pads over part of a round object, or
only the finger tips on it (sim_bridge README, *Why did an attempt fail?*), and
`perturbation_study` measured the edge: moved 15 mm across the pads ~71 % of held
candidates still hold, 15 mm shallower ~66 %.

This stage adds those poses as simulated rows. For each object it draws `per_object` held
candidates of the table (seeded by the object's name), moves each by `shift_m` along one
of +x / -x (across the pads) / -z (shallower) of its TCP frame, drawn per candidate, and
closes on it in Drake with the table's own settings, as the objects stage does. The rows
go to `<objects>/perturbed/<name>.npz`: the table's row format plus `parent` (the table
row moved) and `shift_tcp_m`. They are kept apart from the table so its block growth stays
exact; `load_labelling_table` appends them, and the scene stage and `recipes restore
--relabel` label with both (held rows are positives, failed ones explicit negatives).

Resumable per object: a finished file is kept, a kill loses at most the objects in flight.
"""

import dataclasses
import json
import pathlib
from dataclasses import dataclass

import numpy as np

from gravgrasp_detector import atomic_files
from ..parallel import task_seed
from ..physics.contact import SimSettings
from ..physics.grasp_simulation import GraspSimulator
from .object_grasps import ROW_KEYS, evaluate_candidate, load_table, stack_rows
from .object_sources import object_from_table
from .per_object_stage import appended_rows_dir, run_per_object

# The directions a held candidate is moved in, in its own TCP frame (x across the pads, z
# along the approach); the perturbation study measured how far along each a grasp holds.
DIRECTIONS = {"across+": (1.0, 0.0, 0.0), "across-": (-1.0, 0.0, 0.0), "shallower": (0.0, 0.0, -1.0)}
DIRECTIONS_TCP = np.array(list(DIRECTIONS.values()))
DIRECTORY = "perturbed"
# Rows appended after a table's own for labelling: these (the edge of holding) and
# power_grasps' (toward the palm), in this order.
EXTRA_ROW_DIRECTORIES = (DIRECTORY, "toward_palm")


@dataclass(frozen=True)
class PerturbTask:
    name: str
    table_path: str
    out_path: str
    mesh_dirs: tuple
    per_object: int
    shift_m: float
    seed: int


def shifted(X_object_tcp, direction_tcp, distance_m):
    """The pose moved by distance_m along a direction of its own TCP frame."""
    X = np.array(X_object_tcp, float)
    X[:3, 3] += X[:3, :3] @ (np.asarray(direction_tcp, float) * distance_m)
    return X


def perturbed_path(objects_dir, name) -> pathlib.Path:
    return pathlib.Path(objects_dir) / DIRECTORY / f"{name}.npz"


def held_rows(table) -> np.ndarray:
    """Rows that held (a simulation error is neither held nor failed)."""
    return np.flatnonzero(table["grasped"].astype(bool))


def plan(table, per_object, shift_m, seed):
    """(parent rows, TCP-frame shifts [m]) for one table: deterministic per name and seed."""
    rng = np.random.default_rng(task_seed(seed, "perturb", str(table["name"])))
    held = held_rows(table)
    parents = np.sort(rng.choice(held, min(per_object, len(held)), replace=False))
    shifts = DIRECTIONS_TCP[rng.integers(len(DIRECTIONS_TCP), size=len(parents))] * shift_m
    return parents, shifts


def run_perturb_task(task: PerturbTask):
    """Worker: simulate one object's perturbed candidates and write their file.
    Returns ("ok", (tried, held)) or ("error", message)."""
    try:
        table = load_table(task.table_path)
        parents, shifts = plan(table, task.per_object, task.shift_m, task.seed)
        settings = SimSettings.from_record(json.loads(str(table["sim_settings"])))
        sim = GraspSimulator(object_from_table(table, task.mesh_dirs), settings)
        rows = [dict(evaluate_candidate(sim, shifted(table["X_object_tcp_candidate"][i], d, 1.0)),
                     rest_pose=np.int16(table["rest_pose"][i])) for i, d in zip(parents, shifts)]
        arrays = stack_rows(rows)
        arrays.update(parent=parents.astype(np.int32), shift_tcp_m=shifts.astype(np.float32),
                      name=np.asarray(str(table["name"])), table_rows=np.asarray(len(table["grasped"])),
                      settings=np.asarray(json.dumps(dict(per_object=task.per_object, shift_m=task.shift_m,
                                                          seed=task.seed,
                                                          sim=dataclasses.asdict(settings)), sort_keys=True)))
        atomic_files.save_npz(pathlib.Path(task.out_path), **arrays)
        return "ok", (len(rows), int(arrays["grasped"].sum()))
    except Exception as e:  # reported, retried on the next run; the other objects go on
        return "error", f"{task.name}: {type(e).__name__}: {e}"


def run_perturb_stage(objects_out, mesh_dirs, per_object=64, shift_m=0.015, seed=0, workers=None,
                      exclude=frozenset(), progress=True):
    """Perturbed rows for every table of `objects_out` (the objects stage's --out) that
    has held candidates and no perturbed file yet. Returns a summary dict."""
    objects_dir = appended_rows_dir(objects_out, DIRECTORY)
    tasks, kept = [], 0
    for path in sorted(objects_dir.glob("*.npz")):
        if path.stem in exclude:
            continue
        out = perturbed_path(objects_dir, path.stem)
        if out.exists():
            kept += 1
            continue
        with np.load(path) as t:
            if not t["grasped"].any():
                continue
        tasks.append(PerturbTask(path.stem, str(path), str(out), tuple(mesh_dirs), per_object, shift_m, seed))
    return run_per_object(run_perturb_task, tasks, kept, ("tried", "held"), "perturbed grasps", workers, progress)


def load_labelling_table(objects_dir, name):
    """The grasp table `name` with its perturbed and toward-the-palm rows (if any)
    appended after its own: what the scene stage labels from. `table_rows` says where
    the table's own rows end (a scene's `label_grasp` past it names an appended row)."""
    table = load_table(pathlib.Path(objects_dir) / f"{name}.npz")
    table["table_rows"] = len(table["grasped"])
    for directory in EXTRA_ROW_DIRECTORIES:
        path = pathlib.Path(objects_dir) / directory / f"{name}.npz"
        if path.exists():
            _append_rows(table, load_table(path))
    return table


def _append_rows(table, extra):
    for key in (k for k in ROW_KEYS if k in table):  # strings (reasons) keep the wider width of the two
        cast = extra[key] if table[key].dtype.kind == "U" else extra[key].astype(table[key].dtype)
        table[key] = np.concatenate([table[key], cast])
    # finger joints: the same names in both (the same hand model); none in a file without rows
    if list(extra["finger_joint_names"]) == list(table["finger_joint_names"]):
        table["finger_joint_angles"] = np.concatenate([table["finger_joint_angles"], extra["finger_joint_angles"]])
    else:
        pad = np.full((len(extra["grasped"]), table["finger_joint_angles"].shape[1]), np.nan, np.float32)
        table["finger_joint_angles"] = np.concatenate([table["finger_joint_angles"], pad])
    return table
