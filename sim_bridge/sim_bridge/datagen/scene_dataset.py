"""Scene stage: scenes -> TSDF + sparse gravity-rejection voxel labels (paper Sec. III).

For scene i (seed from --seed and i only):
1. draw 1..max_objects objects among those whose grasp table has a successful grasp
   (how many: `object_count`, below), and "packed" or "pile"; settle them on the
   table in Drake (scenes.arrange; packed objects start in a resting pose of their
   table, see resting_poses);
2. render 1..max_views depth images from random views on the upper hemisphere
   (Open3D ray casting of the posed visual meshes and the table) and fuse them into
   the 40^3 TSDF of the 0.30 m workspace;
3. project every successful grasp of every object by the object's pose
   (X_task_tcp = X_task_object X_object_tcp).  label_pose "commanded" (default)
   uses the pose the hand was driven to (X_object_tcp_candidate): the pose the
   robot will command, so labels and execution agree about the approach;
   "settled" uses the hand pose after the object settled in it (the v1 dataset);
   with `symmetry` (default) every grasp is also placed at each rotational
   symmetry of its object (object_symmetry: same contacts, same scores) and,
   with `mirrors` (default), at each mirror symmetry (the hand mirrored too:
   +x and -x scores exchanged);
4. drop a grasp if the open hand at that pose, or on its last `approach_m` of
   straight approach, intersects the table or another object (and, for
   commanded poses, the grasped object itself); with `execution_check`
   (default) also if the executor would refuse it, its approach more than
   APPROACH_CONE_DEG from straight down (an object in a pile, or a copy at a
   symmetry, can turn a sampled approach past the executor's cone; such a grasp
   is no label, and no negative either, so that its voxel can be labelled with a
   grasp the robot can execute), or if it would fail where the robot executes it: detection
   publishes the *voxel centre* (up to half a voxel off the simulated pose, so a
   deep grasp lands in its object and jams on the approach), so the open hand
   and its approach are checked there too, and the fingers closed as they
   settled in the simulation (their pad tips reach up to 14 mm past the open
   hand's) must stay above the table there (else the fingertips press into it
   and the lift is blocked);
5. f_g from the 6 disturbance scores and the scene gravity (paper Eq. 1);
6. label the TCP voxel of each grasp (best f_g per voxel).

Stored per scene in `<out>/scenes/<i:06d>.npz`: tsdf (40,40,40) float32 (network
input convention of gravgrasp_detector.perception.tsdf), label_index (K,3) uint8,
label_score (K,) float32 [N], label_e_x / label_e_z (K,3) float32, label_mode (K,)
uint8 (power/precision), label_object (K,) uint8, label_grasp (K,) int32 and
label_symmetry (K,) uint8 (provenance: row of that object's grasp table and the
symmetry it was moved by, 0 = the simulated pose), the object names and poses,
the arrangement, the camera poses and intrinsics, and the counts of projected
grasps, of those that passed every check of step 4 (n_grasps_collision_free),
of those dropped where executed (n_grasps_dropped_executed) or outside the
cone (n_grasps_outside_cone), and how many labels the simulated grasps alone give
(n_labels_without_copies). The explicit negatives for validness: negative_index
(M,3) uint8, voxels without a label that hold a simulated failure (tried at the
commanded pose, symmetries too; negative_reason 1) or a held grasp whose open hand
or approach collides in this scene (reason 2).
"""

import functools
import hashlib
import json
import pathlib
from dataclasses import dataclass

import numpy as np
import trimesh

from gravgrasp_detector import atomic_files
from gravgrasp_detector.execution.executor import ExecutionLimits
from gravgrasp_detector.perception.tsdf import CameraIntrinsics, TSDFVolume

from ..parallel import make_executor, run_tasks, task_seed
from ..physics import hand_collision
from ..physics.depth_rendering import DepthRenderer, random_view_on_hemisphere
from ..physics.gravity_projection import GRAVITY_DIRECTION_TASK, GRAVITY_PROJECTION_EPS, gravity_rejection_score
from ..physics.hand_model import FingerKinematics
from ..physics.scenes import ARRANGEMENTS, TABLE_HEIGHT_M, VOLUME_SIZE_M, SceneSettings, arrange
from . import object_symmetry
from .object_grasps import MODE_NAMES
from .perturbed_grasps import load_labelling_table
from .object_sources import object_from_table, shape_sha256
from .resting_poses import RestingPoses
from .voxel_labels import RESOLUTION, at_voxel_centres, voxel_labels

APPROACH_M = 0.05  # straight approach checked for collisions (pre-grasp distance)
APPROACH_CONE_DEG = ExecutionLimits.approach_cone_deg  # the executor's default: it refuses the rest
# VGN's simulated camera
IMAGE_WIDTH, IMAGE_HEIGHT, FOCAL_PX = 640, 480, 540.0


@dataclass(frozen=True)
class SceneTask:
    index: int
    master_seed: int
    objects_dir: str            # <objects out>/objects
    table_names: tuple          # usable grasp tables, sorted (the object pool)
    mesh_dirs: tuple
    max_objects: int = 5
    max_views: int = 6
    approach_m: float = APPROACH_M
    settings: SceneSettings = SceneSettings()
    label_pose: str = "commanded"   # | "settled"
    symmetry: bool = True           # also place grasps at the object's symmetries
    mirrors: bool = True            # ... its mirror symmetries included
    execution_check: bool = True    # step 4: the executor's cone; at the voxel centre, closed pad tips vs the table
    object_count: str = "poisson"   # | "uniform": see OBJECT_COUNTS


# How many objects a scene requests. "poisson": VGN's data generation (Poisson with mean
# 4, plus 1), capped at max_objects (the paper's 1-5): with 5, P(1..5) = 2/7/15/20/57 %,
# close to the benchmark's 5-object scenes, and labels per scene follow the object count.
# "uniform": 1..max_objects alike (the v2 scenes).
OBJECT_COUNTS = ("poisson", "uniform")
OBJECT_COUNT_LAMBDA = 4


def requested_object_count(rng, how, max_objects):
    if how == "poisson":
        return int(min(rng.poisson(OBJECT_COUNT_LAMBDA) + 1, max_objects))
    if how == "uniform":
        return int(rng.integers(1, max_objects + 1))
    raise ValueError(f"object_count {how!r}: use one of {OBJECT_COUNTS}")


def usable_tables(objects_dir):
    """Names of grasp tables with at least one successful grasp, sorted."""
    names = []
    for p in sorted(pathlib.Path(objects_dir).glob("*.npz")):
        with np.load(p) as t:
            if t["grasped"].any():
                names.append(p.stem)
    return names


def run_scene(task: SceneTask):
    """Worker: ("ok", arrays) or ("error", message)."""
    try:
        return "ok", _run_scene(task)
    except Exception as e:  # reported, retried on the next run
        return "error", f"scene {task.index}: {type(e).__name__}: {e}"


def _run_scene(task):
    rng = np.random.default_rng(task_seed(task.master_seed, "scene", task.index))
    for _ in range(5):  # redraw (same rng: still deterministic) if every object left the table or the drop blew up
        n_req = requested_object_count(rng, task.object_count, task.max_objects)
        arrangement = str(rng.choice(ARRANGEMENTS))
        pick = rng.choice(len(task.table_names), size=min(n_req, len(task.table_names)), replace=False)
        tables = [load_labelling_table(task.objects_dir, task.table_names[i]) for i in pick]
        specs = [object_from_table(t, task.mesh_dirs) for t in tables]
        try:
            keep, poses = arrange(specs, arrangement, rng, task.settings, rest=[_resting_poses(t) for t in tables])
        except RuntimeError as e:
            # A drop that blew up numerically (scene 1591 of seed 0: "SceneGraph
            # encountered a non-finite value") fails the same way on every rerun: redraw.
            if "non-finite" not in str(e):
                raise
            keep, poses = [], []
        tables = [tables[i] for i in keep]
        specs = [specs[i] for i in keep]
        if keep:
            break
    target = np.array([VOLUME_SIZE_M / 2, VOLUME_SIZE_M / 2, TABLE_HEIGHT_M])
    views = [random_view_on_hemisphere(rng, target) for _ in range(int(rng.integers(1, task.max_views + 1)))]
    scene = label_scene(task, tables, specs, poses, views)
    scene.update(arrangement=np.asarray(arrangement), n_objects_requested=np.asarray(n_req))
    return scene


def label_scene(task, tables, specs, poses, views):
    """Steps 2-6 for objects already settled (poses X_task_object) and camera poses
    `views`: all of the scene file but the arrangement and the requested object count.
    Everything after the physics; scene_recipes rebuilds scenes with it."""
    # depth views -> TSDF
    table_mesh = trimesh.creation.box((2.0, 2.0, 0.05))
    table_mesh.apply_translation([VOLUME_SIZE_M / 2, VOLUME_SIZE_M / 2, TABLE_HEIGHT_M - 0.025])
    renderer = DepthRenderer([table_mesh] + [(_visual_mesh(s), X) for s, X in zip(specs, poses)])
    intrinsics = CameraIntrinsics(IMAGE_WIDTH, IMAGE_HEIGHT, FOCAL_PX, FOCAL_PX,
                                  (IMAGE_WIDTH - 1) / 2, (IMAGE_HEIGHT - 1) / 2)
    tsdf = TSDFVolume(size_m=VOLUME_SIZE_M, resolution=RESOLUTION)
    for T in views:
        tsdf.integrate(renderer.render(intrinsics, T), intrinsics, T)

    # project grasps, filter collisions, gravity projection
    meshes = [s.collision_mesh() for s in specs]
    points = [hand_collision.surface_points(m, seed=0) @ X[:3, :3].T + X[:3, 3] for m, X in zip(meshes, poses)]
    X_all, f_all, mode_all, obj_all, row_all, sym_all = [], [], [], [], [], []
    failed_all, collides_all = [], []  # poses known not to work here: the explicit negatives
    n_projected, n_dropped_executed, n_outside_cone = 0, 0, 0
    for k, (t, X_obj) in enumerate(zip(tables, poses)):
        key = "X_object_tcp_candidate" if task.label_pose == "commanded" else "X_object_tcp"
        S = None
        if task.symmetry:
            S = object_symmetry.cached_symmetry_transforms(
                pathlib.Path(task.objects_dir).parent / "symmetry", str(t["name"]),
                str(t["shape_sha256"]) if "shape_sha256" in t else shape_sha256(specs[k]), meshes[k], specs[k].com_m)
            if not task.mirrors:
                S = S[~object_symmetry.is_mirror(S)]  # the rotations, first in S: their indices stay
            mirrored = object_symmetry.is_mirror(S)
        # Simulated failures (a simulation error says nothing about the grasp) at the
        # commanded pose, the one that was tried, copied to the symmetries as successes are.
        reason = t["reason"].astype(str) if "reason" in t else np.full(len(t["grasped"]), "")
        failed = np.flatnonzero(~t["grasped"].astype(bool) & ~np.char.startswith(reason, "simulation error"))
        X_failed = t["X_object_tcp_candidate"][failed].astype(np.float64)
        if S is not None:
            X_failed = object_symmetry.replicate(X_failed, S)[0]
        failed_all.append(X_obj[None] @ X_failed)
        rows = np.flatnonzero(t["grasped"])
        X = t[key][rows].astype(np.float64)
        sym = np.zeros(len(rows), np.int64)
        if S is not None:
            X, src = object_symmetry.replicate(X, S)
            rows, sym = rows[src], np.repeat(np.arange(len(S)), len(src) // len(S))
        X = X_obj[None] @ X
        n_projected += len(rows)
        if task.execution_check:
            in_cone = -X[:, 2, 2] >= np.cos(np.deg2rad(APPROACH_CONE_DEG))
            n_outside_cone += int((~in_cone).sum())
            X, rows, sym = X[in_cone], rows[in_cone], sym[in_cone]
        # the settled hand touches its object by definition; a commanded pose must clear it
        obstacles = [p for j, p in enumerate(points) if j != k or task.label_pose == "commanded"]
        others = np.concatenate(obstacles) if obstacles else None
        free = ~hand_collision.collides(X, others, table_z_m=TABLE_HEIGHT_M, approach_m=task.approach_m)
        if task.execution_check:
            executed = free.copy()
            executed[free] = executable(X[free], t, rows[free], others, task.approach_m)
            n_dropped_executed += int(free.sum() - executed.sum())
            free = executed
        collides_all.append(X[~free])
        X, rows, sym = X[free], rows[free], sym[free]
        X_all.append(X)
        scores = t["scores_n"][rows]
        if task.symmetry:
            scores = object_symmetry.copy_scores(scores, mirrored[sym])
        f_all.append(gravity_rejection_score(scores, X[:, :3, :3]) if len(rows) else np.zeros(0))
        mode_all.append(t["mode"][rows])
        obj_all.append(np.full(len(rows), k))
        row_all.append(rows)
        sym_all.append(sym)
    cat = (lambda a, shape, dt: np.concatenate(a).astype(dt) if a else np.zeros(shape, dt))
    X_all = cat(X_all, (0, 4, 4), np.float64)
    f_all = cat(f_all, (0,), np.float64)
    labels = voxel_labels(X_all, f_all)
    g = labels["grasp"]
    simulated = cat(sym_all, (0,), np.int64) == 0
    n_without_copies = len(voxel_labels(X_all[simulated], f_all[simulated])["score"])
    negatives = negative_voxels(labels["index"], cat(failed_all, (0, 4, 4), np.float64),
                                cat(collides_all, (0, 4, 4), np.float64))
    return dict(
        tsdf=tsdf.grid(),
        label_index=labels["index"], label_score=labels["score"],
        label_e_x=labels["e_x"], label_e_z=labels["e_z"],
        label_mode=cat(mode_all, (0,), np.uint8)[g], label_object=cat(obj_all, (0,), np.uint8)[g],
        label_grasp=cat(row_all, (0,), np.int32)[g], label_symmetry=cat(sym_all, (0,), np.uint8)[g],
        object_names=np.asarray([str(t["name"]) for t in tables] or [""])[:len(tables)],
        X_task_object=np.asarray(poses, np.float64).reshape(-1, 4, 4),  # float64: scene_recipes rebuilds from it
        T_task_camera=np.asarray(views, np.float64).reshape(-1, 4, 4),
        intrinsics=np.asarray([IMAGE_WIDTH, IMAGE_HEIGHT, FOCAL_PX, FOCAL_PX, intrinsics.cx, intrinsics.cy]),
        n_grasps_projected=np.asarray(n_projected), n_grasps_collision_free=np.asarray(len(f_all)),
        n_labels_without_copies=np.asarray(n_without_copies),
        execution_check=np.asarray(task.execution_check), n_grasps_dropped_executed=np.asarray(n_dropped_executed),
        n_grasps_outside_cone=np.asarray(n_outside_cone),
        negative_index=negatives["index"], negative_reason=negatives["reason"],
        table_height_m=np.asarray(TABLE_HEIGHT_M), gravity_task=GRAVITY_DIRECTION_TASK,
        gravity_eps=np.asarray(GRAVITY_PROJECTION_EPS), approach_m=np.asarray(task.approach_m),
        label_pose=np.asarray(task.label_pose), symmetry=np.asarray(task.symmetry),
        mirrors=np.asarray(task.symmetry and task.mirrors),
        mode_names=np.asarray(MODE_NAMES), seed=np.asarray(task_seed(task.master_seed, "scene", task.index), np.uint64),
    )


def executable(X_task_tcp, table, rows, obstacles, approach_m):
    """(N,) bool: grasp N (pose X_task_tcp, row rows[n] of its object's table) still works
    where the robot will execute it, the centre of its voxel: the open hand and its
    approach clear `obstacles` (surface points) and the table, and the pad tips of the
    fingers closed as they settled in the simulation stay above the table."""
    X = at_voxel_centres(X_task_tcp)
    ok = ~hand_collision.collides(X, obstacles, table_z_m=TABLE_HEIGHT_M, approach_m=approach_m)
    if len(rows):
        # symmetry copies share their row's fingers: the linkage once per row
        unique_rows, of_row = np.unique(rows, return_inverse=True)
        tips = _finger_kinematics().pad_tips_tcp(table["finger_joint_names"],
                                                 table["finger_joint_angles"][unique_rows])[of_row]
        ok &= hand_collision.lowest_z_m(X, tips) >= TABLE_HEIGHT_M
    return ok


@functools.lru_cache(maxsize=1)
def _finger_kinematics():
    return FingerKinematics()  # a Drake plant: once per worker process


NEGATIVE_FAILED, NEGATIVE_COLLIDES = 1, 2  # negative_reason codes


def negative_voxels(label_index, X_failed, X_collides):
    """Voxels holding a grasp pose known not to work in this scene, and no label: the TCP
    voxels of simulated failures (NEGATIVE_FAILED) and of held grasps whose open hand or
    approach collides here (NEGATIVE_COLLIDES; a voxel with both gets the first).
    -> {index (M,3) uint8 sorted, reason (M,) uint8}."""
    codes = np.concatenate([np.full(len(X_failed), NEGATIVE_FAILED), np.full(len(X_collides), NEGATIVE_COLLIDES)])
    X = np.concatenate([np.asarray(X_failed).reshape(-1, 4, 4), np.asarray(X_collides).reshape(-1, 4, 4)])
    # voxel_labels keeps the best "score" per voxel: minus the code keeps the smallest code
    per_voxel = voxel_labels(X, -codes)

    def flat(ijk):
        return np.ravel_multi_index(np.asarray(ijk, np.int64).reshape(-1, 3).T, (RESOLUTION,) * 3)

    keep = ~np.isin(flat(per_voxel["index"]), flat(label_index))
    return {"index": per_voxel["index"][keep], "reason": codes[per_voxel["grasp"][keep]].astype(np.uint8)}


def _resting_poses(table):
    """The table's RestingPoses, or None (tables of the free sampler have none)."""
    if "rest_probability" in table and len(table["rest_probability"]):
        p = np.asarray(table["rest_probability"], float)
        return RestingPoses(np.asarray(table["rest_X_table_object"], float), p, np.ones(len(p), bool))
    return None


_VISUAL_CACHE = {}


def _visual_mesh(spec):
    """What the camera sees: the visual mesh if the object has one, else its collision pieces."""
    if spec.visual_mesh_path:
        if spec.visual_mesh_path not in _VISUAL_CACHE:
            _VISUAL_CACHE[spec.visual_mesh_path] = trimesh.load(spec.visual_mesh_path, force="mesh")
        return _VISUAL_CACHE[spec.visual_mesh_path]
    return spec.collision_mesh()


class SceneStore:
    def __init__(self, out_dir):
        self.dir = pathlib.Path(out_dir) / "scenes"

    def path(self, i):
        return self.dir / f"{i:06d}.npz"

    def pin_manifest(self, manifest: dict) -> list:
        """Write `manifest` (what makes scene i reproducible from its seed) beside the scenes,
        or compare it with the one already there: the keys that differ, [] where none does."""
        path = self.dir / "manifest.json"
        if not path.exists():
            atomic_files.save_json(path, manifest)
            return []
        old = json.loads(path.read_text())
        return sorted(k for k in set(old) | set(manifest) if old.get(k) != manifest.get(k))


def run_scene_stage(out_dir, objects_out_dir, mesh_dirs, n_scenes, seed, workers=None, scheduler=None,
                    max_objects=5, max_views=6, progress=True, executor=None, settings=SceneSettings(),
                    label_pose="commanded", symmetry=True, mirrors=True, execution_check=True,
                    object_count="poisson"):
    """Generate scenes 0..n_scenes-1 that do not exist yet; returns a summary dict."""
    objects_dir = pathlib.Path(objects_out_dir) / "objects"
    names = tuple(usable_tables(objects_dir))
    if not names:
        raise SystemExit(f"no grasp table with a successful grasp in {objects_dir}: run `datagen objects` first")
    store = SceneStore(out_dir)
    store.dir.mkdir(parents=True, exist_ok=True)
    atomic_files.remove_stale_temporaries(store.dir)
    # the object pool must not change under a resumed run, or scene i would differ
    if label_pose not in ("commanded", "settled"):
        raise ValueError(f"label_pose {label_pose!r}: use 'commanded' or 'settled'")
    if object_count not in OBJECT_COUNTS:
        raise ValueError(f"object_count {object_count!r}: use one of {OBJECT_COUNTS}")
    manifest = dict(seed=seed, max_objects=max_objects, max_views=max_views, label_pose=label_pose,
                    symmetry=bool(symmetry), mirrors=bool(symmetry and mirrors),
                    objects_dir=str(objects_dir.resolve()),
                    object_pool_sha256=hashlib.sha256("\n".join(names).encode()).hexdigest(),
                    object_pool_size=len(names), execution_check=bool(execution_check),
                    packed_footprints=True, object_count=object_count,
                    approach_cone_deg=APPROACH_CONE_DEG if execution_check else None)
    # (a directory made before footprint packing or object_count cannot be resumed by this
    # generator: its manifest lacks those keys)
    changed = store.pin_manifest(manifest)
    if changed:
        raise SystemExit(f"{store.dir} was generated with different {', '.join(changed)}; "
                         "use a new --out (scenes must stay reproducible from their seed)")
    tasks = [SceneTask(i, seed, str(objects_dir), names, tuple(str(d) for d in mesh_dirs), max_objects, max_views,
                       settings=settings, label_pose=label_pose, symmetry=bool(symmetry),
                       mirrors=bool(symmetry and mirrors), execution_check=bool(execution_check),
                       object_count=object_count)
             for i in range(n_scenes) if not store.path(i).exists()]
    errors = []

    def on_result(task, result):
        status, payload = result
        if status == "ok":
            atomic_files.save_npz(store.path(task.index), **payload)
        else:
            errors.append(payload)

    if tasks:
        if executor is not None:
            run_tasks(executor, run_scene, tasks, on_result, desc="scenes", progress=progress)
        else:
            with make_executor(workers, scheduler) as ex:
                run_tasks(ex, run_scene, tasks, on_result, desc="scenes", progress=progress)
    for e in errors:
        print(e)
    done = [store.path(i) for i in range(n_scenes) if store.path(i).exists()]
    labels = 0
    for p in done:
        with np.load(p) as z:
            labels += len(z["label_score"])
    return dict(done=len(done), error=len(errors), labels=labels, errors=errors)
