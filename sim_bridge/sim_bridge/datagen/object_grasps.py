"""Per-object stage: antipodal candidates -> grasp simulation -> grasp table.

One table per object, `<out>/objects/<name>.npz` (all arrays, no pickles):

  name, source_kind ("mesh" | "procedural"), source (URDF/OBJ file name, or
  "<seed>:<count>:<index>" for `objects.random_procedural_objects`), mass_kg, com_m,
  shape_sha256 (collision shape + mass fingerprint), master_seed, block_size, n_blocks,
  sim_settings (JSON of SimSettings), sampling_settings (JSON),
  X_object_tcp_candidate (N,4,4) float32   sampled pose (object frame, m)
  X_object_tcp           (N,4,4) float32   pose after the object settled in the hand
  scores_n               (N,6)   float32   disturbance rejection [N], +x -x +y -y +z -z (TCP)
  departed               (N,6)   bool      False: held up to SimSettings.max_force_n
  rest_pose              (N,)    int16     resting pose the candidate was sampled for (-1: free sampler)
  rest_X_table_object    (P,4,4) float64   resting poses on a table (resting_poses; P = 0: free sampler)
  rest_probability       (P,)    float64   how often the object comes to rest in each
  mode                   (N,)    uint8     index into mode_names ("power", "precision", "none")
  grasped                (N,)    bool
  contacts               (N,)    uint16    bit k set = hand link contact_link_names[k] touched
  finger_joint_names, finger_joint_angles (N,k) float32 [rad]
  reason                 (N,)    str       why a grasp failed ("" if grasped)
  wall_time_s            (N,)    float32   simulation wall time (the only non-reproducible field)

Grasps come in blocks of `block_size` candidates, each sampled with its own seed
(master seed, object, block): block k is the same whatever the total, so a table
can be grown later (`--grasps-per-object` larger, same output directory) and a
killed run loses at most one block per worker.  Block results live in
`<out>/objects/.parts/<name>/` until all requested blocks exist, then are appended
to the table (atomically) and removed.  An object that cannot be
used gets `<name>.skip.json` with one reason; unexpected errors are reported and
retried on the next run.  Each object is an `object_sources.ObjectSource` (a mesh file or
a procedural index), so any worker can rebuild it.
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
from ..physics.grasp_simulation import MODES, GraspSimulator
from ..physics.hand_model import LEFT_LINKS, PALM_LINKS, RIGHT_LINKS, WRAP_MIN_RAD
from ..physics.objects import ObjectError
from .antipodal_sampling import SamplingSettings, sample_grasp_candidates, sample_grasp_candidates_at_rest
from .object_sources import ObjectSource, shape_sha256
from .resting_poses import RestingPoses, find_resting_poses

MODE_NAMES = MODES  # the tables' `mode` indexes these (grasp_simulation's order)
CONTACT_LINK_NAMES = PALM_LINKS + LEFT_LINKS + RIGHT_LINKS


@dataclass(frozen=True)
class ObjectChunk:
    """Block `chunk` of an object's grasps: `size` candidates sampled with their own
    seed (master seed, object, block), so block k is the same whatever the total and
    a finished table can later be grown by more blocks."""

    source: ObjectSource
    chunk: int
    size: int
    master_seed: int
    sim_settings: object = None          # SimSettings; None = defaults
    sampling: SamplingSettings = SamplingSettings()
    simulator_factory: object = None     # callable(obj, settings) -> .evaluate(X); None = Drake
    rest: RestingPoses = None            # sampler "resting": the object's resting poses


@dataclass(frozen=True)
class RestTask:
    """Find an object's resting poses (sampler "resting"), once, before its blocks."""

    source: ObjectSource
    sampling: SamplingSettings = SamplingSettings()


def run_rest_task(task: RestTask):
    """Worker: ("ok", RestingPoses) | ("skip", reason) | ("error", message)."""
    try:
        obj = task.source.load()
    except ObjectError as e:
        return "skip", str(e)
    except Exception as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        return "skip", f"{task.source.name}: mesh cannot be loaded ({type(e).__name__}: {first})"
    try:
        return "ok", find_resting_poses(obj, min_probability=task.sampling.rest_min_probability)
    except Exception as e:  # qhull on a degenerate hull: the object cannot lie on a table
        return "skip", f"{task.source.name}: no resting pose found ({type(e).__name__}: {e})"


def block_seed(master_seed, name, block):
    return task_seed(master_seed, "object", name, "block", block)


def run_chunk(task: ObjectChunk):
    """Worker: sample the object's candidates (deterministic per object), simulate
    this chunk.  Returns ("ok", arrays) | ("skip", reason) | ("error", message)."""
    try:
        obj = task.source.load()
    except ObjectError as e:
        return "skip", str(e)
    except Exception as e:  # e.g. qhull on a flat mesh: still bad input, not a bug of ours
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        return "skip", f"{task.source.name}: mesh cannot be loaded ({type(e).__name__}: {first})"
    try:
        return _run_chunk(task, obj)
    except ObjectError as e:
        return "skip", str(e)
    except Exception as e:  # report and retry on the next run, never kill the whole run
        return "error", f"{type(e).__name__}: {e}"


def _run_chunk(task, obj):
    settings = task.sim_settings or SimSettings()
    seed = block_seed(task.master_seed, task.source.name, task.chunk)
    if task.sampling.sampler == "resting":
        X, rest_pose = sample_grasp_candidates_at_rest(obj.collision_mesh(), task.rest, task.size, seed, task.sampling)
    else:
        X = sample_grasp_candidates(obj.collision_mesh(), task.size, seed, task.sampling)
        rest_pose = np.full(len(X), -1)
    factory = task.simulator_factory or GraspSimulator
    sim = factory(obj, settings) if len(X) else None
    rows = [dict(evaluate_candidate(sim, x), rest_pose=np.int16(k)) for x, k in zip(X, rest_pose)]
    rest = task.rest
    meta = dict(mass_kg=obj.mass_kg, com_m=np.asarray(obj.com_m, float),
                shape_sha256=shape_sha256(obj),
                sim_settings=json.dumps(dataclasses.asdict(settings), sort_keys=True),
                rest_X_table_object=rest.X_table_object if rest is not None else np.zeros((0, 4, 4)),
                rest_probability=rest.probability if rest is not None else np.zeros(0))
    return "ok", (rows, meta)


def evaluate_candidate(sim, X):
    """One grasp; a simulation that raises is a failed grasp with the error as its
    reason (deterministic, so retrying would fail again and block the object)."""
    try:
        return _outcome_row(sim.evaluate(X), X)
    except Exception as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        return dict(X_object_tcp_candidate=np.asarray(X, np.float32), X_object_tcp=np.asarray(X, np.float32),
                    scores_n=np.zeros(6, np.float32), departed=np.zeros(6, bool),
                    mode=np.uint8(MODE_NAMES.index("none")), grasped=False, contacts=np.uint16(0),
                    finger_joint_angles={}, reason=f"simulation error: {type(e).__name__}: {first}",
                    wall_time_s=np.float32(0.0))


def _outcome_row(outcome, X_candidate):
    contacts = 0
    for link in outcome.contact_links:
        if link in CONTACT_LINK_NAMES:
            contacts |= 1 << CONTACT_LINK_NAMES.index(link)
    return dict(
        X_object_tcp_candidate=np.asarray(X_candidate, np.float32),
        X_object_tcp=np.asarray(outcome.X_object_tcp_settled, np.float32),
        scores_n=np.asarray(outcome.scores_n, np.float32),
        departed=np.asarray(getattr(outcome, "departed", np.ones(6, bool)), bool),
        mode=np.uint8(MODE_NAMES.index(outcome.mode)),
        grasped=bool(outcome.grasped),
        contacts=np.uint16(contacts),
        finger_joint_angles=dict(outcome.finger_joint_angles),
        reason=str(getattr(outcome, "reason", "")),
        wall_time_s=np.float32(outcome.wall_time_s),
    )


# --- writing (client side) ------------------------------------------------------------

class ObjectStageStore:
    """Files of the per-object stage under `<out>/objects`."""

    def __init__(self, out_dir):
        self.dir = pathlib.Path(out_dir) / "objects"
        self.parts = self.dir / ".parts"

    def table_path(self, name):
        return self.dir / f"{name}.npz"

    def skip_path(self, name):
        return self.dir / f"{name}.skip.json"

    def part_path(self, name, chunk):
        return self.parts / name / f"{chunk:05d}.npz"

    def rest_path(self, name):
        return self.parts / name / "resting_poses.npz"

    def resting_poses(self, name):
        """The object's resting poses (from its table, else from the rest stage), or None."""
        for p in (self.table_path(name), self.rest_path(name)):
            if p.exists():
                with np.load(p) as z:
                    if "rest_probability" in z.files and len(z["rest_probability"]):
                        return RestingPoses(z["rest_X_table_object"], z["rest_probability"],
                                            z["rest_confirmed"] if "rest_confirmed" in z.files
                                            else np.ones(len(z["rest_probability"]), bool))
        return None

    def write_rest(self, name, rest: RestingPoses):
        atomic_files.save_npz(self.rest_path(name), rest_X_table_object=rest.X_table_object,
                              rest_probability=rest.probability, rest_confirmed=rest.confirmed)

    def blocks_done(self, name, block_size):
        """Blocks already merged into the object's table (0 if none)."""
        if not self.table_path(name).exists():
            return 0
        with np.load(self.table_path(name)) as t:
            if int(t["block_size"]) != block_size:
                raise ValueError(f"{self.table_path(name)} was made with --block-size {int(t['block_size'])}; "
                                 "use that (blocks define the candidates) or a new --out")
            return int(t["n_blocks"])

    def pending_chunks(self, name, n_chunks, block_size):
        if self.skip_path(name).exists():
            return []
        first = self.blocks_done(name, block_size)
        return [c for c in range(first, n_chunks) if not self.part_path(name, c).exists()]

    def has_rest_file(self, name):
        return self.rest_path(name).exists()

    def write_part(self, task: ObjectChunk, rows, meta):
        arrays = stack_rows(rows)
        arrays.update({f"meta_{k}": np.asarray(v) for k, v in meta.items()})
        atomic_files.save_npz(self.part_path(task.source.name, task.chunk), **arrays)

    def write_skip(self, source: ObjectSource, reason):
        atomic_files.save_json(self.skip_path(source.name), dict(name=source.name, source_kind=source.kind,
                                                                 source=source.source, reason=reason))
        shutil.rmtree(self.parts / source.name, ignore_errors=True)
        try:
            self.parts.rmdir()
        except OSError:
            pass

    def merge_if_complete(self, source: ObjectSource, n_chunks, block_size, master_seed, sampling):
        """Append the block files to the object's table once all blocks up to n_chunks exist."""
        if self.skip_path(source.name).exists():
            return False
        first = self.blocks_done(source.name, block_size)
        if first >= n_chunks:
            return False
        paths = [self.part_path(source.name, c) for c in range(first, n_chunks)]
        if not all(p.exists() for p in paths):
            return False
        parts = [dict(np.load(p)) for p in paths]
        meta = parts[-1]
        if first:
            parts.insert(0, load_table(self.table_path(source.name)))
            if str(parts[0]["shape_sha256"]) != str(meta["meta_shape_sha256"]):
                raise ValueError(f"{source.name}: the object changed since its table was made; "
                                 "remove its table or use a new --out")
        if sum(len(p["mode"]) for p in parts) == 0:
            self.write_skip(source, f"{source.name}: no antipodal grasp fits the {sampling.max_width_m * 1000:.0f} mm "
                                    "stroke with the open hand clear of the object (too large, or too thin/flat)")
            return True
        table = {}
        for key in ROW_KEYS:
            # tables made before the resting-pose sampler have no rest_pose column
            table[key] = np.concatenate([p[key] if key in p else np.full(len(p["mode"]), -1, np.int16)
                                         for p in parts])
        # chunks may have seen different joints (a failed closure reports none): align
        names = sorted({str(n) for p in parts for n in p["finger_joint_names"]})
        angles = np.full((len(table["mode"]), len(names)), np.nan, np.float32)
        row = 0
        for p in parts:
            for j, n in enumerate(p["finger_joint_names"]):
                angles[row:row + len(p["mode"]), names.index(str(n))] = p["finger_joint_angles"][:, j]
            row += len(p["mode"])
        table["finger_joint_names"] = np.asarray(names, dtype=str) if names else np.zeros(0, "<U1")
        table["finger_joint_angles"] = angles
        if first and str(parts[0]["sim_settings"]) != str(meta["meta_sim_settings"]):
            raise ValueError(f"{source.name}: its table was simulated with other SimSettings; "
                             "grow it with the same --sim-setting values or use a new --out")
        table.update(
            name=np.asarray(source.name), source_kind=np.asarray(source.kind), source=np.asarray(source.source),
            master_seed=np.asarray(master_seed, np.int64),
            block_size=np.asarray(block_size), n_blocks=np.asarray(n_chunks),
            mass_kg=meta["meta_mass_kg"], com_m=meta["meta_com_m"], sim_settings=meta["meta_sim_settings"],
            shape_sha256=meta["meta_shape_sha256"],
            rest_X_table_object=meta.get("meta_rest_X_table_object", np.zeros((0, 4, 4))),
            rest_probability=meta.get("meta_rest_probability", np.zeros(0)),
            sampling_settings=np.asarray(json.dumps(dataclasses.asdict(sampling), sort_keys=True)),
            mode_names=np.asarray(MODE_NAMES), contact_link_names=np.asarray(CONTACT_LINK_NAMES),
        )
        atomic_files.save_npz(self.table_path(source.name), **table)
        shutil.rmtree(self.parts / source.name, ignore_errors=True)
        try:
            self.parts.rmdir()  # only when empty: other objects may still be in progress
        except OSError:
            pass
        return True


ROW_KEYS = ("X_object_tcp_candidate", "X_object_tcp", "scores_n", "departed", "mode", "grasped",
            "contacts", "reason", "wall_time_s", "rest_pose")


def stack_rows(rows):
    out = {k: np.asarray([r[k] for r in rows]) for k in ROW_KEYS}
    if not rows:
        out.update(X_object_tcp_candidate=np.zeros((0, 4, 4), np.float32), X_object_tcp=np.zeros((0, 4, 4), np.float32),
                   scores_n=np.zeros((0, 6), np.float32), departed=np.zeros((0, 6), bool),
                   mode=np.zeros(0, np.uint8), grasped=np.zeros(0, bool), contacts=np.zeros(0, np.uint16),
                   reason=np.zeros(0, "<U1"), wall_time_s=np.zeros(0, np.float32),
                   rest_pose=np.zeros(0, np.int16))
    names = sorted({k for r in rows for k in r["finger_joint_angles"]})
    out["finger_joint_names"] = np.asarray(names, dtype=str) if names else np.zeros(0, "<U1")
    out["finger_joint_angles"] = np.asarray(
        [[r["finger_joint_angles"].get(n, np.nan) for n in names] for r in rows], np.float32).reshape(len(rows), len(names))
    return out


def table_wrap_rad(table) -> np.ndarray:
    """(N,) how far each row's distal links wrapped past their stop [rad]
    (grasp_simulation.wrap_angle_rad, from the recorded coupler angles; 0 without them)."""
    names = [str(n) for n in table["finger_joint_names"]]
    if not {"left_coupler", "right_coupler"} <= set(names):
        return np.zeros(len(table["mode"]))
    a = table["finger_joint_angles"]
    wrap = np.minimum(-a[:, names.index("left_coupler")], -a[:, names.index("right_coupler")])
    return np.nan_to_num(np.maximum(wrap, 0.0)).astype(np.float64)


def wrapping_power(table) -> np.ndarray:
    """(N,) rows that are power grasps that wrap (grasp_simulation.classify_mode: palm or
    proximal contact and both distal links past their stop); a power row that does not
    wrap counts as a precision grasp. A table without recorded finger joints keeps its modes."""
    power = table["mode"] == MODE_NAMES.index("power")
    if "finger_joint_names" not in table:
        return power
    return power & (table_wrap_rad(table) >= WRAP_MIN_RAD)


def load_table(path):
    """A grasp table as a dict of numpy arrays (strings as str)."""
    with np.load(path) as z:
        return {k: (z[k].item() if z[k].dtype.kind == "U" and z[k].ndim == 0 else z[k]) for k in z.files}
