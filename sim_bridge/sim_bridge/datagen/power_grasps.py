"""Power grasps made as the paper makes them: `ros2 run sim_bridge datagen wrap`.

The antipodal sampler's candidates mostly close as precision grasps (power grasps were
11.5 % of held rows), and few of its "power" rows wrap the object: the search for the
deepest insertion stops where the open fingers first touch it, so the palm rarely gets
there. The paper (Sec. III-A) perturbs precision grasps "in translation and rotation"
and closes the hand again without gravity, keeping those that become power grasps.

This stage does that for each object: it draws `per_object` held precision rows of the
table (seeded by the object's name), turns each about its closing (y) and approach (z)
axes by up to `max_turn_deg`, moves it along its approach as deep as the open hand goes
without touching the object, nor the table with the object in the resting pose the parent
was sampled for (the hand and its 5 cm approach: a grasp a robot could execute; 2.5 mm
steps, up to `max_depth_m`, then `clearance_m` back)
and closes on it in Drake with the table's own settings (the rows are appended to it). Every closing is a row (held or not);
`wrap_rad` (grasp_simulation.wrap_angle_rad) records how far the distal links wrapped,
and the mode is "power" only for a wrap (grasp_simulation.classify_mode).

Rows go to `<objects>/toward_palm/<name>.npz` in the table's row format plus `parent`
and `offset_tcp` (4x4, the parent's candidate pose to the new one, TCP frame);
`perturbed_grasps.load_labelling_table` appends them. Resumable per object.
"""

import dataclasses
import json
import pathlib
from dataclasses import dataclass

import numpy as np
from gravgrasp_detector import atomic_files
from scipy.spatial.transform import Rotation

from ..parallel import task_seed
from ..physics import hand_collision
from ..physics.contact import SimSettings
from ..physics.grasp_simulation import GraspSimulator
from .object_grasps import MODE_NAMES, evaluate_candidate, load_table, stack_rows
from .object_sources import object_from_table
from .per_object_stage import appended_rows_dir, run_per_object

DIRECTORY = "toward_palm"
DEPTH_STEP_M = 0.0025
APPROACH_M = 0.05  # the executor's straight approach, kept clear of the table (scene_dataset.APPROACH_M)


@dataclass(frozen=True)
class WrapTask:
    name: str
    table_path: str
    out_path: str
    mesh_dirs: tuple
    per_object: int
    max_turn_deg: float
    max_depth_m: float
    clearance_m: float
    seed: int


def offset(turn_y_rad, turn_z_rad, depth_m) -> np.ndarray:
    """TCP-frame offset: turned about y, then z (both through the TCP), then moved
    `depth_m` along the new approach."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("yz", [turn_y_rad, turn_z_rad]).as_matrix()
    T[:3, 3] = T[:3, :3] @ np.array([0.0, 0.0, depth_m])
    return T


def deepest_free_depth(sim, X_object_tcp, R_offset, max_depth_m, clearance_m, X_table_object=None) -> float:
    """The deepest insertion along the turned approach at which the open hand touches
    neither the object nor, with the object in its resting pose `X_table_object` (4x4), the
    table (the hand and its straight approach: where a robot could put it), less
    `clearance_m` (0 if even the turned pose touches something)."""
    free = None
    T = np.eye(4)
    T[:3, :3] = R_offset
    for depth in np.arange(0.0, max_depth_m + 1e-9, DEPTH_STEP_M):
        T[:3, 3] = R_offset @ np.array([0.0, 0.0, depth])
        X = X_object_tcp @ T
        if sim.collides(X) or (X_table_object is not None and hand_collision.collides(
                (X_table_object @ X)[None], None, table_z_m=0.0, approach_m=APPROACH_M)[0]):
            break
        free = depth
    return 0.0 if free is None else max(0.0, free - clearance_m)


def plan(table, per_object, max_turn_deg, seed):
    """(parent rows, turns about y and z [rad]) for one table: deterministic per name and seed."""
    rng = np.random.default_rng(task_seed(seed, "toward_palm", str(table["name"])))
    precision = np.flatnonzero(table["grasped"].astype(bool) & (table["mode"] == MODE_NAMES.index("precision")))
    parents = np.sort(rng.choice(precision, min(per_object, len(precision)), replace=False))
    turns = np.deg2rad(rng.uniform(-max_turn_deg, max_turn_deg, size=(len(parents), 2)))
    return parents, turns


def run_wrap_task(task: WrapTask):
    """Worker: one object's perturbed-toward-the-palm closings, written to its file.
    Returns ("ok", (tried, held, wrapped)) or ("error", message)."""
    try:
        table = load_table(task.table_path)
        parents, turns = plan(table, task.per_object, task.max_turn_deg, task.seed)
        settings = SimSettings.from_record(json.loads(str(table["sim_settings"])))  # the table's own: rows append
        sim = GraspSimulator(object_from_table(table, task.mesh_dirs), settings)
        rows, offsets = [], []
        for i, (ty, tz) in zip(parents, turns):
            X = table["X_object_tcp_candidate"][i].astype(float)
            R = offset(ty, tz, 0.0)[:3, :3]
            rest = int(table["rest_pose"][i])
            X_table_object = table["rest_X_table_object"][rest] if 0 <= rest < len(table["rest_X_table_object"]) else None
            T = offset(ty, tz, deepest_free_depth(sim, X, R, task.max_depth_m, task.clearance_m, X_table_object))
            rows.append(dict(evaluate_candidate(sim, X @ T), rest_pose=np.int16(table["rest_pose"][i])))
            offsets.append(T)
        arrays = stack_rows(rows)
        arrays.update(parent=parents.astype(np.int32), offset_tcp=np.asarray(offsets, np.float32).reshape(-1, 4, 4),
                      name=np.asarray(str(table["name"])), table_rows=np.asarray(len(table["grasped"])),
                      settings=np.asarray(json.dumps(dict(
                          per_object=task.per_object, max_turn_deg=task.max_turn_deg, max_depth_m=task.max_depth_m,
                          clearance_m=task.clearance_m, seed=task.seed, sim=dataclasses.asdict(settings)),
                          sort_keys=True)))
        atomic_files.save_npz(pathlib.Path(task.out_path), **arrays)
        power = arrays["grasped"] & (arrays["mode"] == MODE_NAMES.index("power"))
        return "ok", (len(rows), int(arrays["grasped"].sum()), int(power.sum()))
    except Exception as e:  # reported, retried on the next run; the other objects go on
        return "error", f"{task.name}: {type(e).__name__}: {e}"


def wrap_path(objects_dir, name) -> pathlib.Path:
    return pathlib.Path(objects_dir) / DIRECTORY / f"{name}.npz"


def run_wrap_stage(objects_out, mesh_dirs, per_object=32, max_turn_deg=20.0, max_depth_m=0.04, clearance_m=0.001,
                   seed=0, workers=None, names=None, progress=True):
    """Toward-the-palm rows for every table of `objects_out` (or those in `names`) with
    held precision rows and no such file yet, simulated with each table's own settings.
    Returns a summary dict."""
    objects_dir = appended_rows_dir(objects_out, DIRECTORY)
    tasks, kept = [], 0
    for path in sorted(objects_dir.glob("*.npz")):
        if names is not None and path.stem not in names:
            continue
        out = wrap_path(objects_dir, path.stem)
        if out.exists():
            kept += 1
            continue
        with np.load(path) as t:
            if not (t["grasped"] & (t["mode"] == MODE_NAMES.index("precision"))).any():
                continue
        tasks.append(WrapTask(path.stem, str(path), str(out), tuple(mesh_dirs), per_object, max_turn_deg,
                              max_depth_m, clearance_m, seed))
    return run_per_object(run_wrap_task, tasks, kept, ("tried", "held", "power"), "toward the palm", workers,
                          progress)
