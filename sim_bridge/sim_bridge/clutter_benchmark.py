"""Clutter-removal benchmark against object weight (paper Sec. V-B/V-C, issue 8):
`ros2 run sim_bridge benchmark`. No rclpy: the Drake world, the TSDF, the detector and
the grasp executor run in-process, in simulated time.

Protocol (one *round* = one method, one object weight, one scene):
- Scenes: 5 objects, `packed` and `pile` in turn, drawn and arranged once per scene
  from a seed derived from the master seed (scenes/<id>.json), so every method and
  weight clears the same scenes. Every object of a round gets the round's weight.
- Objects: procedural primitives with procedural seed 1000 by default (training uses
  seed 0: disjoint), or `--meshes DIR` (URDF/OBJ). Objects wider than the 85 mm stroke
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
  Lifted objects are removed; objects that leave the cube are `fell_off` (not cleared)
  and stay in the world (removing a falling body made Drake segfault later).
- A round ends when the table is clear, after 2 consecutive failures, when nothing is
  detected or no detected grasp passes the checks, or at 3 x objects attempts.
- SR = successes / attempts, CR = successes / objects, pooled over rounds, with 95 %
  Wilson intervals.

Methods are model files (`METHODS`); a missing one is skipped with a note. The rotation
ablation's extra models run at `ABLATION_*WEIGHTS_KG` only. A model
trained with `--target binary` ranks by validness (a success probability) and no
min-score-in-N threshold applies to it.

Engineering: one task per round through parallel.run_tasks (process pool or Dask);
each round's result is written atomically to rounds/<method>/<weight>/<scene>.json
with the model file's sha256, so a rerun skips finished rounds (and redoes those of a
retrained model); everything runs in simulated time, so a seed gives the same attempts.
"""
from __future__ import annotations

import argparse
import dataclasses
import functools
import hashlib
import json
import math
import pathlib
import sys
import time
from concurrent.futures.process import BrokenProcessPool

import numpy as np

from . import atomic_files
from .parallel import make_executor, run_tasks, task_seed

# method -> model file name in --models-dir (the lead's training runs write these)
METHODS = {
    "ours": "gravgrasp.pt",
    "ours_precision": "gravgrasp_precision_only.pt",
    "binary": "gravgrasp_binary.pt",
    "ours_ey_ez": "gravgrasp_ey_ez.pt",
    "ours_quat": "gravgrasp_quat.pt",
}
FULL_WEIGHTS_KG = (0.1, 0.3, 0.5, 0.8, 1.0, 1.5)
QUICK_WEIGHTS_KG = (0.1, 1.5)
# The rotation ablation is one table in the paper (Sec. V-C), not a weight sweep: its two
# extra models run at these weights only (`ours` is its e_x-e_z arm), which keeps the
# full run at 20 rounds per scene instead of 30.
ABLATION_METHODS = ("ours_ey_ez", "ours_quat")
FULL_ABLATION_WEIGHTS_KG = (0.5,)
QUICK_ABLATION_WEIGHTS_KG = (0.1,)
PROCEDURAL_SEED = 1000  # training objects use procedural seed 0
PROCEDURAL_POOL = 100
OBJECTS_PER_SCENE = 5
ARRANGEMENTS = ("packed", "pile")
CONSECUTIVE_FAILURES_END = 2
LIFTED_MIN_HEIGHT_M = 0.05
SCHEMA_VERSION = 1
MAX_POOLS = 3  # worker pools started before a run gives up on repeated native crashes


@dataclasses.dataclass(frozen=True)
class Protocol:
    """Everything that changes a round's result besides the method, weight and scene
    (stored in config.json; a rerun with other values needs another --out)."""
    validness_threshold: float = 0.5
    min_score_n: float = 0.0       # score methods only
    max_grasps: int = 20
    hold_s: float = 1.0            # still, after the executor's lift
    shake_m: float = 0.03          # 0 = no shake
    shake_speed_mps: float = 0.25
    # home <-> pre-grasp in free space (VGN teleports the hand there); approach and lift
    # keep the executor's 5 cm/s
    free_space_speed_mps: float = 0.5
    time_step_s: float = 1e-3      # label settings: dt 2 ms over-reads friction (SimSettings)
    # SAP relaxation time; None = SimSettings' choice (0 at dt 1 ms)
    relaxation_time_s: float | None = None
    grip_force_n: float = 40.0     # the paper's
    attempts_per_object: int = 3


# ----------------------------------------------------------------------------------
# statistics


def wilson_interval(successes: int, n: int, z: float = 1.959964) -> tuple:
    """95 % Wilson score interval of a binomial proportion; (nan, nan) for n = 0."""
    if n <= 0:
        return (math.nan, math.nan)
    p = successes / n
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    # exact bounds at 0 and n (the formula gives them up to rounding)
    return (0.0 if successes == 0 else max(0.0, centre - half), 1.0 if successes == n else min(1.0, centre + half))


# ----------------------------------------------------------------------------------
# objects and scenes


def min_width_m(mesh) -> float:
    """Smallest distance between two parallel planes enclosing the mesh: over the face
    normals of its convex hull (exact for a convex polytope). What the fingers must span."""
    hull = mesh.convex_hull
    v = np.asarray(hull.vertices)
    widths = np.ptp(v @ np.asarray(hull.face_normals).T, axis=0)
    return float(widths.min())


@functools.lru_cache(maxsize=4)
def object_pool(meshes_dir: str | None, stroke_m: float | None = None):
    """(usable ObjectSources, excluded [{name, min_width_mm, reason}]) (tuples). Raises ObjectError with
    one clear message for a bad mesh directory."""
    from .object_grasps import mesh_sources, procedural_sources
    from .objects import ObjectError
    from .sim_world import BARE_MESH_DENSITY_KG_M3, STROKE_M

    stroke_m = STROKE_M if stroke_m is None else stroke_m
    if meshes_dir:
        sources = mesh_sources(meshes_dir, density_kg_m3=BARE_MESH_DENSITY_KG_M3)
        if not sources:
            raise ObjectError(f"--meshes {meshes_dir}: no .urdf or .obj files there")
    else:
        sources = procedural_sources(PROCEDURAL_POOL, PROCEDURAL_SEED)
    usable, excluded = [], []
    for s in sources:
        try:
            spec = s.load()
        except (ObjectError, ValueError, OSError) as e:
            excluded.append({"name": s.name, "reason": f"cannot be loaded: {e}"})
            continue
        width = min_width_m(spec.collision_mesh())
        if width > stroke_m:
            excluded.append({"name": spec.name, "source": s.source, "min_width_mm": round(width * 1e3, 1),
                             "reason": f"wider than the {stroke_m * 1e3:.0f} mm stroke in every direction"})
        else:
            usable.append(s)
    if len(usable) < OBJECTS_PER_SCENE:
        raise ObjectError(f"only {len(usable)} usable objects ({len(excluded)} excluded): a scene needs "
                          f"{OBJECTS_PER_SCENE}; give a --meshes directory with more objects that fit the hand")
    return tuple(usable), tuple(excluded)


def scene_ids(n_scenes: int) -> list:
    """packed_000, pile_000, packed_001, ...: the arrangements alternate."""
    return [f"{ARRANGEMENTS[i % 2]}_{i // 2:03d}" for i in range(n_scenes)]


@dataclasses.dataclass(frozen=True)
class SceneTask:
    scene_id: str
    seed: int
    sources: tuple  # usable ObjectSources


def make_scene(task: SceneTask) -> dict:
    """Draw OBJECTS_PER_SCENE objects and arrange them (their own masses: the layout
    does not depend on the benchmark weight). -> JSON-able scene."""
    from .scenes import arrange

    rng = np.random.default_rng(task.seed)
    arrangement = task.scene_id.split("_")[0]
    best = None
    # A draw whose objects do not all fit (packed: no room; pile: one rolled off) is
    # redrawn, so that scenes have OBJECTS_PER_SCENE objects; after 20 draws the
    # fullest one is kept (its dropped objects are listed).
    for _ in range(20):
        pick = rng.choice(len(task.sources), OBJECTS_PER_SCENE, replace=False)
        sources = [task.sources[i] for i in sorted(pick)]
        specs = [s.load() for s in sources]
        keep, poses = arrange(specs, arrangement, rng)
        if best is None or len(keep) > len(best[2]):
            best = (sources, specs, keep, poses)
        if len(keep) == OBJECTS_PER_SCENE:
            break
    sources, specs, keep, poses = best
    return {"scene_id": task.scene_id, "seed": task.seed, "arrangement": arrangement,
            "objects": [{"source": dataclasses.asdict(sources[i]), "name": specs[i].name,
                         "X_task_object": np.asarray(X).round(9).tolist()} for i, X in zip(keep, poses)],
            "dropped_by_arrangement": [specs[i].name for i in range(len(specs)) if i not in keep]}


# ----------------------------------------------------------------------------------
# the simulated cell: executor adapters in simulated time


class SimArm:
    """grasp_execution.Arm on a SimWorld: straight-line TCP motions stepped here."""

    def __init__(self, world):
        self.world = world

    def move_to(self, X_task_tcp, speed_mps, timeout_s):
        return self.world.move_tcp(X_task_tcp, speed_mps, timeout_s)


class SimGripper:
    """The executor's gripper client (Robotiq2F85's read_state / activate /
    move_and_wait / wait / width_m / stop) on a SimWorld's finger servo, in simulated time,
    without the Modbus emulator: deterministic, and no wall-clock polling."""

    STEP_S = 0.01

    def __init__(self, world):
        from robotiq_driver.gripper_registers import GripperScale

        self.world, self.scale, self._closing = world, GripperScale(), True

    def read_state(self):
        from robotiq_driver.gripper_registers import ActivationStatus, GripperState, ObjectStatus

        width, state = self.world.finger_status()
        if state == "blocked":
            obj = ObjectStatus.CONTACT_CLOSING if self._closing else ObjectStatus.CONTACT_OPENING
        else:
            obj = ObjectStatus.AT_POSITION if state == "at_target" else ObjectStatus.MOVING
        return GripperState(activated=True, go=True, activation_status=ActivationStatus.ACTIVATED,
                            object_status=obj, position=self.scale.width_to_counts(min(width, self.scale.stroke_m)))

    def activate(self, timeout_s=5.0, force=False):
        return self.read_state()

    def width_m(self, state):
        return self.scale.counts_to_width(state.position)

    def move_and_wait(self, width_m, speed_mps, force_n, timeout_s):
        self._closing = width_m < self.world.finger_width_m()
        self.world.command_fingers(width_m, speed_mps, force_n)
        return self.wait(timeout_s)

    def wait(self, timeout_s, requested=None):
        from robotiq_driver.gripper_client import GripperTimeout

        t_end = self.world.time_s + timeout_s
        while self.world.time_s < t_end:
            self.world.advance(self.STEP_S)
            if self.world.finger_status()[1] != "moving":
                return self.read_state()
        raise GripperTimeout(f"fingers still moving after {timeout_s} s of simulated time")

    def stop(self):
        self.world.hold_fingers()


class SimCell:
    """One scene in Drake with the executor; what `clear_table` drives."""

    def __init__(self, scene: dict, mass_kg: float, protocol: Protocol, volume):
        from gravgrasp_detector.grasp_execution import ExecutionLimits, GraspExecutor

        from .grasp_simulation import SimSettings
        from .object_grasps import ObjectSource
        from .sim_world import SceneConfig, SimWorld, WorldSettings

        objects = tuple((ObjectSource(**o["source"]).load(), np.asarray(o["X_task_object"]))
                        for o in scene["objects"])
        settings = WorldSettings(contact=SimSettings(time_step_s=protocol.time_step_s,
                                                     grip_force_n=protocol.grip_force_n,
                                                     relaxation_time_s=protocol.relaxation_time_s),
                                 max_speed_mps=protocol.free_space_speed_mps)
        self.world = SimWorld(SceneConfig(objects=objects, object_mass_kg=mass_kg,
                                          arrangement=scene["arrangement"]), settings)
        self.protocol, self.volume = protocol, volume
        # The executor's limits are the ROS node's defaults but the free-space speed;
        # grip force per the paper.
        self.limits = ExecutionLimits(grip_force_n=protocol.grip_force_n, arm_timeout_s=30.0,
                                      max_speed_mps=protocol.free_space_speed_mps)
        self.executor = GraspExecutor(SimArm(self.world), lambda: SimGripper(self.world), self.limits,
                                      reachability=None, log=lambda *_: None)
        self.home = self.world.tcp_pose()
        self._fallen = set()

    def settle(self, max_s: float = 2.0, speed_mps: float = 5e-3) -> float:
        """Let the scene come to rest at the round's weight before the first view: the
        layout was settled with the objects' own masses, and a heavier pile shifts (a
        1.5 kg cylinder slid off a sphere, which rolled off the table). Returns the
        simulated settling time."""
        t0 = self.world.time_s
        before = {s.name: s.X_task_object[:3, 3] for s in self.world.object_states()}
        while self.world.time_s < t0 + max_s:
            self.world.advance(0.1)
            now = {s.name: s.X_task_object[:3, 3] for s in self.world.object_states() if not s.out_of_workspace}
            speed = max((np.linalg.norm(p - before.get(n, p)) / 0.1 for n, p in now.items()), default=0.0)
            before = now
            if speed < speed_mps:
                break
        return self.world.time_s - t0

    def objects_on_table(self) -> list:
        return [s.name for s in self.world.object_states() if not s.out_of_workspace]

    def remove_fallen(self) -> list:
        """Objects that left the cube since the last call. They are not removed from the
        world: SimWorld.remove_object on a body still falling (a sphere that rolled off
        the table, at 14 m/s) made a later Drake step segfault; off the table they touch
        nothing, and objects_on_table leaves them out."""
        fallen = [s.name for s in self.world.object_states() if s.out_of_workspace and s.name not in self._fallen]
        self._fallen.update(fallen)
        return fallen

    def observe(self):
        """One depth image from the fixed camera -> a fresh TSDF: (grid, voxel_size_m, origin)."""
        depth, intrinsics, T_task_camera = self.world.render_depth()
        self.volume.reset()
        self.volume.integrate(depth, intrinsics, T_task_camera)
        return self.volume.grid(), self.volume.voxel_size_m, self.volume.origin.copy()

    def feasible(self, grasp, tsdf) -> str:
        """'' if the executor would start this grasp, else why not (its own checks)."""
        from gravgrasp_detector import hand_clearance
        from gravgrasp_detector.grasp_execution import Abort, check_limits, plan_poses

        poses = plan_poses(grasp.pose, self.limits.pregrasp_distance_m, self.limits.lift_height_m)
        try:
            check_limits(poses, self.limits)
        except Abort as e:
            return str(e)
        for X in poses.values():
            ok, message = self.world.check_reachable(X)
            if not ok:
                return message
        return hand_clearance.first_collision(poses, tsdf)

    def execute(self, grasp, tsdf) -> dict:
        """Run the grasp, hold, shake, judge by ground truth, remove what was lifted,
        open and go home. -> {outcome, reason, lifted}."""
        from .sim_world import STROKE_M

        p = self.protocol
        self.executor.arm_motion(True)  # a fault disarms it; each attempt starts armed
        result = self.executor.execute(grasp.pose, tsdf=tsdf)
        if result.success:
            outcome, reason = self._hold_and_shake()
        else:
            outcome, reason = result.code.name.lower(), result.message
        lifted = [s.name for s in self.world.object_states()
                  if s.in_hand and s.height_above_table_m >= LIFTED_MIN_HEIGHT_M]
        if outcome == "success" and not lifted:
            outcome, reason = "not_lifted", "the gripper reports a held object, but none is between the fingers above the table"
        for name in lifted if outcome == "success" else []:
            self.world.remove_object(name)
        # Open where the hand is (anything still held drops back), then home.
        self.world.command_fingers(STROKE_M, 0.1, p.grip_force_n)
        self.world.advance(0.6)
        if not self.world.move_tcp(self.home, self.limits.max_speed_mps, 30.0)[0]:
            up = self.world.tcp_pose()
            up[2, 3] = self.home[2, 3]  # straight up first if the direct path is blocked
            self.world.move_tcp(up, self.limits.max_speed_mps, 30.0)
            self.world.move_tcp(self.home, self.limits.max_speed_mps, 30.0)
        return {"outcome": outcome, "reason": reason, "lifted": lifted if outcome == "success" else []}

    def _hold_and_shake(self) -> tuple:
        p = self.protocol
        self.world.advance(p.hold_s)
        if not self._held():
            return "dropped_in_hold", f"the object fell out during the {p.hold_s:.1f} s hold"
        X0 = self.world.tcp_pose()
        for axis in (2, 0):  # vertical first: that is where the weight pulls
            if p.shake_m <= 0:
                break
            for offset in (p.shake_m, -p.shake_m, 0.0):
                X = X0.copy()
                X[axis, 3] += offset
                ok, message = self.world.move_tcp(X, p.shake_speed_mps, 10.0)
                if not ok:
                    return "shake_stopped", f"the shake motion stopped: {message}"
        if not self._held():
            return "dropped_in_shake", f"the object fell out during the +-{p.shake_m * 100:.0f} cm shake"
        return "success", f"held {p.hold_s:.1f} s and through a +-{p.shake_m * 100:.0f} cm shake"

    def _held(self) -> bool:
        return any(s.in_hand and s.height_above_table_m >= LIFTED_MIN_HEIGHT_M for s in self.world.object_states())


# ----------------------------------------------------------------------------------
# the round's rules


def clear_table(cell, detect, n_objects: int, attempts_per_object: int = 3) -> dict:
    """Clear a table (paper/VGN protocol). `cell`: objects_on_table(), observe(),
    feasible(grasp, tsdf), execute(grasp, tsdf), remove_fallen(); `detect(tsdf)` ->
    ranked grasps (best first). -> {end, attempts, fell_off}."""
    attempts, fell_off, failures = [], [], 0
    max_attempts = attempts_per_object * n_objects
    while True:
        if not cell.objects_on_table():
            end = "table_clear"
            break
        if failures >= CONSECUTIVE_FAILURES_END:
            end = "consecutive_failures"
            break
        if len(attempts) >= max_attempts:
            end = "attempt_limit"
            break
        tsdf = cell.observe()
        grasps = detect(tsdf)
        if not grasps:
            end = "no_grasp_detected"
            break
        chosen, rejected = None, []
        for rank, g in enumerate(grasps):
            why = cell.feasible(g, tsdf)
            if not why:
                chosen = (rank, g)
                break
            rejected.append(why)
        if chosen is None:
            end = "no_feasible_grasp"
            break
        rank, g = chosen
        result = cell.execute(g, tsdf)
        fell_off += cell.remove_fallen()
        success = result["outcome"] == "success"
        attempts.append({"rank": rank, "grasps_detected": len(grasps), "skipped_infeasible": len(rejected),
                         "pose": np.asarray(g.pose).round(6).tolist(), "score": round(float(g.score_n), 4),
                         "validness": round(float(g.validness), 4), "success": success, **result})
        failures = 0 if success else failures + 1
    return {"end": end, "attempts": attempts, "fell_off": fell_off}


# ----------------------------------------------------------------------------------
# detection per method


def model_target(metadata: dict) -> str:
    """'gravity-score' or 'binary' (training.py records it in training_data.target)."""
    return str((metadata.get("training_data") or {}).get("target", "gravity-score"))


def make_detector(model, metadata, protocol: Protocol):
    """tsdf tuple -> ranked grasps. Score methods rank by the gravity-rejection score [N]
    with min_score_n; binary methods rank by validness (their success probability)."""
    import torch

    from gravgrasp_detector.detection import check_grid, detect_grasps, select_grasps

    binary = model_target(metadata) == "binary"

    def detect(tsdf):
        grid, voxel_size_m, origin = tsdf
        if not np.any(grid):
            return []
        if not binary:
            return detect_grasps(model, grid, voxel_size_m, origin, validness_threshold=protocol.validness_threshold,
                                 min_score_n=protocol.min_score_n, max_grasps=protocol.max_grasps)
        with torch.inference_mode():
            g = torch.as_tensor(np.asarray(grid, np.float32))
            check_grid(g, model.resolution)
            half = model.half_features(g[None, None]).float()
            _, logit = model.score_and_validness_from_half(half)
            validness = torch.sigmoid(logit[0])
            return select_grasps(g, validness, validness, lambda index: model.rotation_at(half, index, half=True),
                                 model.rotation_representation, voxel_size_m, origin,
                                 validness_threshold=protocol.validness_threshold, min_score_n=0.0,
                                 max_grasps=protocol.max_grasps)
    return detect


# ----------------------------------------------------------------------------------
# one round (a worker task)


@dataclasses.dataclass(frozen=True)
class RoundTask:
    method: str
    model_path: str
    model_sha256: str
    mass_kg: float
    scene: dict
    protocol: Protocol


def run_round(task: RoundTask) -> dict:
    import torch

    from gravgrasp_detector.model_file import check_volume, load_model
    from gravgrasp_detector.tsdf import TSDFVolume

    torch.set_num_threads(1)  # one core per round: the pool gives the parallelism
    t0 = time.process_time()
    model, metadata = load_model(task.model_path)
    volume = TSDFVolume(size_m=metadata["tsdf"]["size_m"], resolution=metadata["tsdf"]["resolution"])
    check_volume(metadata, volume.resolution, volume.voxel_size_m, volume.truncation_m)
    cell = SimCell(task.scene, task.mass_kg, task.protocol, volume)
    settle_s = cell.settle()
    left_before_start = cell.remove_fallen()  # not counted: no method could have grasped them
    names = cell.objects_on_table()
    n_objects = len(names)
    record = clear_table(cell, make_detector(model, metadata, task.protocol), n_objects,
                         task.protocol.attempts_per_object)
    return {"schema_version": SCHEMA_VERSION, "method": task.method, "model_sha256": task.model_sha256,
            "target": model_target(metadata), "mass_kg": task.mass_kg, "scene_id": task.scene["scene_id"],
            "objects": names, "n_objects": n_objects, "left_before_start": left_before_start,
            "settle_s": round(settle_s, 2), **record,
            "successes": sum(a["success"] for a in record["attempts"]),
            "sim_time_s": round(cell.world.time_s, 3), "cpu_s": round(time.process_time() - t0, 1)}


# ----------------------------------------------------------------------------------
# the run


def weight_key(mass_kg: float) -> str:
    return repr(float(mass_kg))  # 0.1, 1.0, 1.5


def file_sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def resolve_methods(names, models_dir, overrides=None, note=print):
    """{method: model path} of the methods whose model file exists; a note per missing one."""
    overrides = overrides or {}
    found = {}
    for name in names:
        if name not in METHODS and name not in overrides:
            raise ValueError(f"unknown method {name!r}: use {', '.join(METHODS)} (or --model NAME=PATH)")
        path = pathlib.Path(overrides.get(name) or pathlib.Path(models_dir) / METHODS[name])
        if path.is_file():
            found[name] = str(path.resolve())
        else:
            note(f"benchmark: skipping {name}: model file {path} not found")
    return found


def method_weights(method, weights_kg, ablation_weights_kg=None) -> list:
    if method in ABLATION_METHODS and ablation_weights_kg is not None:
        return [float(w) for w in ablation_weights_kg]
    return [float(w) for w in weights_kg]


def run_benchmark(out_dir, methods: dict, weights_kg, n_scenes: int, seed: int = 0, meshes_dir=None,
                  protocol: Protocol = Protocol(), workers=None, scheduler=None, progress=True, note=print,
                  ablation_weights_kg=None) -> list:
    """Run (or resume) every round; write the outputs; return the summary rows.
    `methods`: {name: model path}; ABLATION_METHODS run at `ablation_weights_kg` if given."""
    plan = {m: method_weights(m, weights_kg, ablation_weights_kg) for m in methods}
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    atomic_files.remove_stale_temporaries(out)
    config = {"seed": seed, "meshes": str(pathlib.Path(meshes_dir).resolve()) if meshes_dir else None,
              "procedural_seed": None if meshes_dir else PROCEDURAL_SEED, "objects_per_scene": OBJECTS_PER_SCENE,
              "protocol": dataclasses.asdict(protocol)}
    config_path = out / "config.json"
    if config_path.exists():
        previous = json.loads(config_path.read_text())
        if previous != config:
            raise ValueError(f"{out} holds a run with another configuration ({config_path}); "
                             "use another --out, or delete it to start over")
    atomic_files.save_json(config_path, config)

    usable, excluded = object_pool(meshes_dir)
    atomic_files.save_json(out / "excluded_objects.json", list(excluded))
    ids = scene_ids(n_scenes)
    scenes, pending = {}, []
    for sid in ids:
        path = out / "scenes" / f"{sid}.json"
        if path.exists():
            scenes[sid] = json.loads(path.read_text())
        else:
            pending.append(SceneTask(sid, task_seed(seed, "scene", sid), tuple(usable)))

    shas = {m: file_sha256(p) for m, p in methods.items()}
    rounds_dir = out / "rounds"

    def round_path(method, mass_kg, sid):
        return rounds_dir / method / weight_key(mass_kg) / f"{sid}.json"

    def done(method, w, sid):
        rp = round_path(method, w, sid)
        return rp.exists() and json.loads(rp.read_text()).get("model_sha256") == shas[method]

    def on_scene(task, scene):
        atomic_files.save_json(out / "scenes" / f"{task.scene_id}.json", scene)
        scenes[task.scene_id] = scene

    def on_round(task, result):
        if "error" in result:
            errors.append((task, result["error"]))
        else:
            atomic_files.save_json(round_path(task.method, task.mass_kg, task.scene["scene_id"]), result)

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
                tasks = [RoundTask(m, path, shas[m], w, scenes[sid], protocol)
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
    return write_outputs(out, plan, shas, ids, excluded, protocol, meshes_dir)


def _guarded_round(task):
    """A round that raises is reported (and retried by the next run), not fatal to the others."""
    try:
        return run_round(task)
    except Exception as e:  # Drake, a bad object, a model that does not fit the volume
        return {"error": f"{type(e).__name__}: {str(e).strip().splitlines()[0][:300] if str(e).strip() else ''}"}


class _InProcess:
    """A sequential executor (workers=0): for tests and debugging."""

    def submit(self, fn, *args):
        import concurrent.futures as cf

        f = cf.Future()
        try:
            f.set_result(fn(*args))
        except BaseException as e:
            f.set_exception(e)
        return f


def _executor(workers, scheduler):
    import contextlib

    if workers == 0 and not scheduler:
        return contextlib.nullcontext(_InProcess())
    return make_executor(workers, scheduler)


# ----------------------------------------------------------------------------------
# outputs


def summarize(rounds: list, plan: dict) -> list:
    """plan: {method: [weights]} -> one row per method and weight."""
    rows = []
    for method, weights_kg in plan.items():
        for w in weights_kg:
            rs = [r for r in rounds if r["method"] == method and r["mass_kg"] == float(w)]
            s = sum(r["successes"] for r in rs)
            a = sum(len(r["attempts"]) for r in rs)
            o = sum(r["n_objects"] for r in rs)
            rows.append({"method": method, "mass_kg": float(w), "rounds": len(rs), "objects": o, "attempts": a,
                         "left_before_start": sum(len(r.get("left_before_start", [])) for r in rs),
                         "fell_off": sum(len(r["fell_off"]) for r in rs),
                         "successes": s, "SR": s / a if a else math.nan, "SR_ci95": wilson_interval(s, a),
                         "CR": s / o if o else math.nan, "CR_ci95": wilson_interval(s, o)})
    return rows


def write_outputs(out, plan, shas, ids, excluded, protocol, meshes_dir) -> list:
    rounds = []
    for method, weights_kg in plan.items():
        for w in weights_kg:
            for sid in ids:
                p = out / "rounds" / method / weight_key(w) / f"{sid}.json"
                if p.exists():
                    r = json.loads(p.read_text())
                    if r.get("model_sha256") == shas[method]:
                        rounds.append(r)
    attempts = []
    for r in rounds:
        for i, a in enumerate(r["attempts"]):
            attempts.append({"method": r["method"], "mass_kg": r["mass_kg"], "scene_id": r["scene_id"],
                             "attempt": i + 1, "object": a["lifted"], "pose": a["pose"],
                             "score": a["score"], "score_unit": "probability" if r["target"] == "binary" else "N",
                             "validness": a["validness"], "rank": a["rank"], "outcome": a["outcome"],
                             "success": a["success"], "reason": a["reason"]})
    atomic_files.save_json(out / "attempts.json", {
        "schema_version": SCHEMA_VERSION, "attempts": attempts,
        "rounds": [{k: r[k] for k in ("method", "mass_kg", "scene_id", "objects", "n_objects", "end",
                                      "successes", "fell_off", "left_before_start", "sim_time_s")} | {"attempts": len(r["attempts"])}
                   for r in rounds]})
    rows = summarize(rounds, plan)
    atomic_files.save_json(out / "results.json", rows)
    expected = len(ids)
    lines = ["# Clutter-removal benchmark against object weight", "",
             f"Scenes: {expected} ({', '.join(ARRANGEMENTS)} alternating), {OBJECTS_PER_SCENE} objects each, "
             f"objects: {'meshes in ' + str(meshes_dir) if meshes_dir else f'procedural (seed {PROCEDURAL_SEED})'}; "
             f"hold {protocol.hold_s:.1f} s, shake +-{protocol.shake_m * 100:.0f} cm, grip {protocol.grip_force_n:.0f} N, "
             f"dt {protocol.time_step_s * 1e3:g} ms. SR = successes / attempts, CR = successes / objects, "
             "[95 % Wilson interval].", "",
             "| method | weight [kg] | rounds | SR | SR 95 % CI | CR | CR 95 % CI | successes / attempts / objects "
             "| left before start / fell off |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        lines.append(f"| {r['method']} | {r['mass_kg']:g} | {r['rounds']}/{expected} | {_pct(r['SR'])} | "
                     f"{_ci(r['SR_ci95'])} | {_pct(r['CR'])} | {_ci(r['CR_ci95'])} | "
                     f"{r['successes']} / {r['attempts']} / {r['objects']} | "
                     f"{r['left_before_start']} / {r['fell_off']} |")
    lines += ["", *outcome_lines(rounds, plan)]
    ends = {}
    for r in rounds:
        ends[r["end"]] = ends.get(r["end"], 0) + 1
    lines += ["", "Round ends: " + (", ".join(f"{k} {v}" for k, v in sorted(ends.items())) or "none"), ""]
    lines.append(f"Excluded objects ({len(excluded)}): " + (", ".join(
        f"{e['name']} ({e.get('min_width_mm', '?')} mm)" if "min_width_mm" in e else f"{e['name']} ({e['reason']})"
        for e in excluded) or "none"))
    atomic_files.save_bytes(out / "results.md", ("\n".join(lines) + "\n").encode())
    plot(rows, plan, out / "sr_cr_vs_weight.png")
    return rows


def outcome_lines(rounds, plan) -> list:
    """Markdown table: how every attempt ended, per method and weight (why SR is what it is)."""
    counts = {}
    for r in rounds:
        row = counts.setdefault((r["method"], float(r["mass_kg"])), {})
        for a in r["attempts"]:
            row[a["outcome"]] = row.get(a["outcome"], 0) + 1
    outcomes = ["success", *sorted({o for row in counts.values() for o in row} - {"success"})]
    lines = ["Outcomes of the attempts:", "", "| method | weight [kg] | " + " | ".join(outcomes) + " |",
             "| --- | --- |" + " --- |" * len(outcomes)]
    for method, weights_kg in plan.items():
        for w in weights_kg:
            row = counts.get((method, float(w)))
            if row:
                lines.append(f"| {method} | {w:g} | " + " | ".join(str(row.get(o, 0)) for o in outcomes) + " |")
    return lines


def _pct(x):
    return "—" if math.isnan(x) else f"{100 * x:.1f} %"


def _ci(ci):
    return "—" if math.isnan(ci[0]) else f"{100 * ci[0]:.1f}–{100 * ci[1]:.1f} %"


def plot(rows, methods, path):
    import io

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for ax, key in zip(axes, ("SR", "CR")):
        for method in methods:
            rs = [r for r in rows if r["method"] == method and not math.isnan(r[key])]
            if not rs:
                continue
            x = np.array([r["mass_kg"] for r in rs])
            y = np.array([r[key] for r in rs])
            lo = y - np.array([r[f"{key}_ci95"][0] for r in rs])
            hi = np.array([r[f"{key}_ci95"][1] for r in rs]) - y
            ax.errorbar(x, 100 * y, yerr=100 * np.vstack([lo, hi]), marker="o", capsize=3, label=method)
        ax.set_xlabel("object weight [kg]")
        ax.set_ylabel(f"{key} [%]")
        ax.set_ylim(-2, 102)  # points at 0 % and 100 % stay visible
        ax.grid(alpha=0.3)
    axes[0].set_title("success ratio")
    axes[1].set_title("clear ratio")
    axes[1].legend(fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    atomic_files.save_bytes(path, buf.getvalue())


# ----------------------------------------------------------------------------------
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
    p = argparse.ArgumentParser(description="Clutter-removal benchmark against object weight (issue 8).")
    p.add_argument("--out", default=None, help="output directory (resumes there); default out/benchmark[_quick]")
    p.add_argument("--quick", action="store_true", help=f"2 scenes (1 packed, 1 pile), weights "
                   f"{', '.join(map(str, QUICK_WEIGHTS_KG))} kg: CI minutes")
    p.add_argument("--scenes", type=int, default=None, help="scenes (packed and pile alternate); default 10, quick 2")
    p.add_argument("--weights", default=None, help="comma-separated kg; default 0.1,0.3,0.5,0.8,1.0,1.5")
    p.add_argument("--ablation-weights", default=None,
                   help=f"weights of {', '.join(ABLATION_METHODS)}; default 0.5 (quick 0.1), or --weights when given")
    p.add_argument("--methods", default=",".join(METHODS), help=f"comma-separated, of {', '.join(METHODS)}")
    p.add_argument("--models-dir", default="models")
    p.add_argument("--model", action="append", default=[], metavar="NAME=PATH",
                   help="a model file for a method (also a new method name)")
    p.add_argument("--meshes", default=None, help="URDF/OBJ directory instead of procedural objects")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=None, help="local processes (default: CPU count; 0 = this process)")
    p.add_argument("--scheduler", default=None, help="Dask scheduler address, e.g. tcp://host:8786")
    p.add_argument("--validness-threshold", type=float, default=Protocol.validness_threshold)
    p.add_argument("--min-score-n", type=float, default=Protocol.min_score_n,
                   help="ignore grasps scored below this [N] (not applied to binary models)")
    p.add_argument("--hold-s", type=float, default=Protocol.hold_s)
    p.add_argument("--shake-m", type=float, default=Protocol.shake_m, help="0 = no shake")
    p.add_argument("--time-step-s", type=float, default=Protocol.time_step_s)
    p.add_argument("--relaxation-time-s", type=float, default=Protocol.relaxation_time_s,
                   help="SAP relaxation time of every contact; default: SimSettings' choice for the time step")
    p.add_argument("--no-progress", action="store_true")
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
    overrides = {}
    for item in args.model:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            print(f"benchmark: --model {item!r}: use NAME=PATH", file=sys.stderr)
            return 2
        overrides[name] = path
    names = [m for m in args.methods.split(",") if m] + [m for m in overrides if m not in args.methods.split(",")]
    try:
        methods = resolve_methods(names, args.models_dir, overrides)
    except ValueError as e:
        print(f"benchmark: {e}", file=sys.stderr)
        return 2
    if not methods:
        print("benchmark: no method has a model file: train them (models/) or pass --model NAME=PATH", file=sys.stderr)
        return 2
    protocol = Protocol(validness_threshold=args.validness_threshold, min_score_n=args.min_score_n,
                        hold_s=args.hold_s, shake_m=args.shake_m, time_step_s=args.time_step_s,
                        relaxation_time_s=args.relaxation_time_s)
    out = args.out or ("out/benchmark_quick" if args.quick else "out/benchmark")
    t0 = time.monotonic()
    from .objects import ObjectError
    try:
        rows = run_benchmark(out, methods, weights, n_scenes, args.seed, args.meshes, protocol,
                             args.workers, args.scheduler, progress=not args.no_progress,
                             ablation_weights_kg=ablation)
    except (ObjectError, ValueError) as e:
        print(f"benchmark: {e}", file=sys.stderr)
        return 2
    except BrokenProcessPool as e:
        print(f"benchmark: worker processes keep dying ({e}); finished rounds are kept: rerun the same "
              "command to resume", file=sys.stderr)
        return 3
    incomplete = any(r["rounds"] < n_scenes for r in rows)
    print(f"benchmark: {out}/results.md, attempts.json, sr_cr_vs_weight.png ({time.monotonic() - t0:.0f} s)"
          + ("; some rounds failed: rerun to retry them" if incomplete else ""), flush=True)
    for r in rows:
        print(f"CR_{r['method']}_{weight_key(r['mass_kg'])}={r['CR']:.2f}")
    for r in rows:
        print(f"SR_{r['method']}_{weight_key(r['mass_kg'])}={r['SR']:.2f}")
    return 1 if incomplete else 0


if __name__ == "__main__":
    sys.exit(main())
