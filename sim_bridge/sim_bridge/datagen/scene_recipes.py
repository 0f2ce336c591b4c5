"""Scene recipes: what a scene is made of, small enough to commit, from which the scene
stage's file is rebuilt without the physics.

Most of a scene's cost is settling its objects in Drake (step 1 of scene_dataset: ~4
CPU-s a scene on 2 cores, piles more); given the settled poses, rendering, fusing,
projecting and checking the grasps (steps 2-6, `scene_dataset.label_scene`) take ~0.9
CPU-s. A scene file is ~60 KB, too much to commit 5,000 of; a recipe keeps only what
step 1 decided (the objects, their settled poses, the camera poses, the arrangement, the
requested object count, the seed), ~1 KB, and a digest of the labels to check a rebuilt
scene against. So a dataset that took hours of physics survives a lost `out/`:

    python -m sim_bridge.datagen recipes pack out/scenes_v3 models/scene_recipes_v3
    python -m sim_bridge.datagen recipes restore models/scene_recipes_v3 out/scenes_v3 \\
        --objects models/grasp_tables_v2 --meshes ../shared/meshes/vgn_train

Recipes are stored in blocks of BLOCK scenes (`recipes_<first:06d>.npz`); `pack` rewrites
a block only when scene files hold scenes it lacks (and never drops one), so commits of a
growing dataset add whole blocks and rewrite one partial block. `restore` writes the
scene files that are missing, with the manifest that lets `datagen scenes` resume there.
A rebuilt scene whose labels differ from the recorded digest (another CPU or library
version can move a grasp across a voxel boundary or a collision margin by rounding) is
kept, and counted: its labels are still those of its own objects and TSDF.

The recipes also record which grasp tables labelled the scenes (per object: shape,
candidates, held grasps). `restore` refuses other tables, unless asked to `relabel`:
then the same settled scenes get the labels of the new tables (grown tables, say) into a
new directory, with no physics redone; the objects' shapes must be unchanged.
"""
from __future__ import annotations

import hashlib
import json
import pathlib
from dataclasses import dataclass

import numpy as np

from gravgrasp_detector import atomic_files

from ..parallel import make_executor, run_tasks
from .perturbed_grasps import load_labelling_table, perturbed_path
from .object_sources import object_from_table
from .scene_dataset import SceneStore, SceneTask, label_scene, usable_tables

BLOCK = 500  # scenes per recipe file
DIGEST_KEYS = ("label_index", "label_mode", "label_object", "label_grasp", "label_symmetry",
               "negative_index", "negative_reason")


class RecipeError(Exception):
    """Recipes or scenes that cannot be packed or restored; the message says what to do."""


def label_digest(scene) -> str:
    """16 hex digits over the integer label arrays of a scene (dict or npz)."""
    h = hashlib.sha256()
    for k in DIGEST_KEYS:
        a = np.ascontiguousarray(scene[k])
        h.update(f"{k}{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()[:16]


def tables_fingerprint(objects_dir) -> dict:
    """{name: "shape:candidates:held"} of the usable grasp tables in objects_dir, with
    ":perturbed:candidates:held" where the table has perturbed rows: what the labels of a
    scene depend on, cheap to compare (a grown table changes its counts)."""
    out = {}
    for name in usable_tables(objects_dir):
        with np.load(pathlib.Path(objects_dir) / f"{name}.npz") as t:
            shape = str(t["shape_sha256"])[:16] if "shape_sha256" in t.files else "-"
            out[name] = f"{shape}:{len(t['grasped'])}:{int(t['grasped'].sum())}"
        extra = perturbed_path(objects_dir, name)
        if extra.exists():
            with np.load(extra) as t:
                out[name] += f":perturbed:{len(t['grasped'])}:{int(t['grasped'].sum())}"
    return out


def _table_changes(old: dict, new: dict, names) -> tuple:
    """-> (names whose shape differs or table is missing, names whose counts differ)."""
    shape, counts = [], []
    for n in sorted(set(names)):
        if n not in new or old[n].split(":")[0] != new[n].split(":")[0]:
            shape.append(n)
        elif old[n] != new[n]:
            counts.append(n)
    return shape, counts


def _scene_dir(path):
    """out/scenes_v3 or out/scenes_v3/scenes -> the directory holding the scene files."""
    path = pathlib.Path(path)
    return path / "scenes" if (path / "scenes").is_dir() else path


def _block_path(recipe_dir, first):
    return pathlib.Path(recipe_dir) / f"recipes_{first:06d}.npz"


def read_block(path) -> dict:
    """A recipe file -> {scene index: recipe dict}."""
    try:
        with np.load(path) as z:
            b = {k: z[k] for k in z.files}
    except (OSError, ValueError, KeyError) as err:
        raise RecipeError(f"{path} is not a recipe file ({err}); pack it again from the scene files") from None
    o_end, v_end = np.cumsum(b["object_count"]), np.cumsum(b["view_count"])
    recipes = {}
    for j, i in enumerate(b["index"]):
        o0, v0 = o_end[j] - b["object_count"][j], v_end[j] - b["view_count"][j]
        recipes[int(i)] = dict(object_names=b["object_names"][o0:o_end[j]], X_task_object=b["X_task_object"][o0:o_end[j]],
                               T_task_camera=b["T_task_camera"][v0:v_end[j]], arrangement=b["arrangement"][j],
                               n_objects_requested=b["n_objects_requested"][j], seed=b["seed"][j],
                               approach_m=b["approach_m"][j], label_count=b["label_count"][j],
                               label_digest=str(b["label_digest"][j]))
    return recipes


def read_recipes(recipe_dir) -> dict:
    """Every recipe of a recipe directory: {scene index: recipe dict}."""
    recipes = {}
    for block in sorted(pathlib.Path(recipe_dir).glob("recipes_*.npz")):
        recipes.update(read_block(block))
    return recipes


def scene_task(manifest: dict, index: int, recipe: dict, objects_dir, names, mesh_dirs) -> SceneTask:
    """The scene stage's task for a recipe's scene, labelled with the tables in objects_dir."""
    return SceneTask(index, manifest["seed"], str(objects_dir), names, tuple(str(d) for d in mesh_dirs),
                     label_pose=manifest["label_pose"], symmetry=manifest["symmetry"], mirrors=manifest["mirrors"],
                     execution_check=manifest["execution_check"], approach_m=float(recipe["approach_m"]))


def _recipe_of(path) -> dict:
    try:
        with np.load(path) as z:
            return dict(object_names=z["object_names"][:len(z["X_task_object"])], X_task_object=z["X_task_object"],
                        T_task_camera=z["T_task_camera"], arrangement=z["arrangement"],
                        n_objects_requested=z["n_objects_requested"], seed=z["seed"], approach_m=z["approach_m"],
                        label_count=len(z["label_score"]), label_digest=label_digest(z))
    except (OSError, ValueError, KeyError) as err:
        raise RecipeError(f"scene file {path} is unreadable or not from `datagen scenes` ({err}); "
                          "delete it and rerun `datagen scenes` to remake it") from None


def _write_block(path, recipes: dict):
    order = sorted(recipes)
    r = [recipes[i] for i in order]
    atomic_files.save_npz(
        path, index=np.asarray(order, np.int32),
        object_count=np.asarray([len(x["X_task_object"]) for x in r], np.int16),
        object_names=np.asarray([str(n) for x in r for n in x["object_names"]]),
        X_task_object=np.concatenate([np.asarray(x["X_task_object"]).reshape(-1, 4, 4) for x in r]),
        view_count=np.asarray([len(x["T_task_camera"]) for x in r], np.int16),
        T_task_camera=np.concatenate([np.asarray(x["T_task_camera"]).reshape(-1, 4, 4) for x in r]),
        arrangement=np.asarray([str(x["arrangement"]) for x in r]),
        n_objects_requested=np.asarray([int(x["n_objects_requested"]) for x in r], np.int16),
        seed=np.asarray([x["seed"] for x in r], np.uint64),
        approach_m=np.asarray([float(x["approach_m"]) for x in r]),
        label_count=np.asarray([int(x["label_count"]) for x in r], np.int32),
        label_digest=np.asarray([x["label_digest"] for x in r]))


def pack(scene_dir, recipe_dir) -> dict:
    """Add the recipes of the scene files under scene_dir to recipe_dir.
    -> {scenes: recipes now held, written: blocks rewritten}."""
    src, out = _scene_dir(scene_dir), pathlib.Path(recipe_dir)
    manifest_path = src / "manifest.json"
    if not manifest_path.exists():
        raise RecipeError(f"{src} has no manifest.json: give the --out directory of `datagen scenes`")
    manifest = json.loads(manifest_path.read_text())
    if pathlib.Path(manifest["objects_dir"]).is_dir():  # the tables that labelled them
        manifest["tables"] = tables_fingerprint(manifest["objects_dir"])
    out.mkdir(parents=True, exist_ok=True)
    if (out / "manifest.json").exists():
        old = json.loads((out / "manifest.json").read_text())
        changed = sorted(k for k in set(old) | set(manifest) if k != "objects_dir" and old.get(k) != manifest.get(k)
                         and not (k == "tables" and k not in old))  # recipes packed before tables were recorded
        if changed:
            raise RecipeError(f"{out} holds recipes of scenes generated with different {', '.join(changed)}; "
                              "pack into a new directory")
    else:
        atomic_files.save_json(out / "manifest.json", manifest)
    by_block = {}
    for f in sorted(src.glob("*.npz")):
        if f.stem.isdigit():
            by_block.setdefault(int(f.stem) // BLOCK * BLOCK, []).append(f)
    written, held = 0, 0
    firsts = sorted(set(by_block) | {int(p.stem.split("_")[1]) for p in out.glob("recipes_*.npz")})
    for first in firsts:
        path = _block_path(out, first)
        recipes = read_block(path) if path.exists() else {}
        new = [f for f in by_block.get(first, []) if int(f.stem) not in recipes]
        if new:
            recipes.update({int(f.stem): _recipe_of(f) for f in new})
            _write_block(path, recipes)
            written += 1
        held += len(recipes)
    return dict(scenes=held, written=written)


@dataclass(frozen=True)
class RestoreTask:
    scene: SceneTask
    recipe: dict


def settled_scene(task: SceneTask, recipe: dict):
    """What label_scene takes, from a recipe: (tables, specs, poses, views)."""
    objects_dir = pathlib.Path(task.objects_dir)
    tables = [load_labelling_table(objects_dir, n) for n in recipe["object_names"]]
    specs = [object_from_table(t, task.mesh_dirs) for t in tables]
    return (tables, specs, list(np.asarray(recipe["X_task_object"], np.float64)),
            list(np.asarray(recipe["T_task_camera"], np.float64)))


def restore_scene(task: RestoreTask):
    """Worker: ("ok", arrays) or ("error", message)."""
    try:
        r = task.recipe
        scene = label_scene(task.scene, *settled_scene(task.scene, r))
        scene.update(arrangement=np.asarray(r["arrangement"]), n_objects_requested=np.asarray(r["n_objects_requested"]))
        if int(scene["seed"]) != int(r["seed"]):
            return "error", (f"scene {task.scene.index}: recipe seed {int(r['seed'])} is not the seed "
                             f"{int(scene['seed'])} of the manifest's master seed: the recipes are corrupt")
        return "ok", scene
    except Exception as e:  # reported; the other scenes go on
        return "error", f"scene {task.scene.index}: {type(e).__name__}: {e}"


def restore(recipe_dir, out_dir, objects_out_dir=None, mesh_dirs=(), workers=None, progress=True,
            relabel=False, keep=None) -> dict:
    """Write the scene files of recipe_dir that out_dir lacks (and, with `keep`, whose file
    name it accepts: e.g. a model's validation scenes). With relabel, the grasp
    tables may be others than those that labelled the scenes (same object shapes).
    -> {restored, differing (labels unlike the recorded digest), errors (messages), scenes,
        label_counts ({index: (recorded, now)} of the scenes written)}."""
    src = pathlib.Path(recipe_dir)
    if not (src / "manifest.json").exists():
        raise RecipeError(f"{src} holds no recipes (no manifest.json): make them with `recipes pack`")
    manifest = json.loads((src / "manifest.json").read_text())
    recorded_tables = manifest.pop("tables", None)
    objects_dir = (pathlib.Path(objects_out_dir) / "objects" if objects_out_dir
                   else pathlib.Path(manifest["objects_dir"]))
    names = tuple(usable_tables(objects_dir)) if objects_dir.is_dir() else ()
    recipes = read_recipes(src)
    pool_sha256 = hashlib.sha256("\n".join(names).encode()).hexdigest()
    if relabel:
        if recorded_tables is None:
            raise RecipeError(f"{src} does not record the tables its scenes were labelled with (packed before "
                              "they were): pack them again from their scene files to relabel")
        used = {str(n) for r in recipes.values() for n in r["object_names"]}
        shape, _ = _table_changes(recorded_tables, tables_fingerprint(objects_dir) if names else {}, used)
        if shape:
            raise RecipeError(f"{len(shape)} objects of the scenes have no usable table or another shape in "
                              f"{objects_dir} (e.g. {shape[0]}): relabelling needs the same objects, since their "
                              "settled poses came from the physics")
    else:
        if pool_sha256 != manifest["object_pool_sha256"]:
            raise RecipeError(f"the grasp tables in {objects_dir} ({len(names)} usable) are not the "
                              f"{manifest['object_pool_size']} the scenes were made from: give --objects the "
                              "objects stage's output they were generated with")
        if recorded_tables is not None:
            shape, counts = _table_changes(recorded_tables, tables_fingerprint(objects_dir), recorded_tables)
            if shape or counts:
                raise RecipeError(f"{len(shape) + len(counts)} grasp tables in {objects_dir} differ from those "
                                  f"that labelled these scenes (e.g. {(shape + counts)[0]}): give --objects those, "
                                  "or pass --relabel and a new output directory to label the scenes with these")
    store = SceneStore(out_dir)
    store.dir.mkdir(parents=True, exist_ok=True)
    atomic_files.remove_stale_temporaries(store.dir)
    # what `datagen scenes` writes: so it resumes here (with the new pool when relabelled)
    here = dict(manifest, objects_dir=str(objects_dir.resolve()), object_pool_sha256=pool_sha256,
                object_pool_size=len(names))
    changed = store.pin_manifest(here)
    if changed:
        raise RecipeError(f"{store.dir} holds scenes generated with different {', '.join(changed)}; "
                          "restore into a new directory")
    tasks = [RestoreTask(scene_task(manifest, i, r, objects_dir, names, mesh_dirs), r)
             for i, r in sorted(recipes.items())
             if not store.path(i).exists() and (keep is None or keep(store.path(i).name))]
    errors, differing, label_counts = [], [], {}

    def on_result(task, result):
        status, payload = result
        if status != "ok":
            errors.append(payload)
            return
        if not relabel and label_digest(payload) != task.recipe["label_digest"]:
            differing.append(task.scene.index)
        label_counts[task.scene.index] = (int(task.recipe["label_count"]), len(payload["label_score"]))
        atomic_files.save_npz(store.path(task.scene.index), **payload)

    if tasks:
        with make_executor(workers) as ex:
            run_tasks(ex, restore_scene, tasks, on_result, desc="restore scenes", progress=progress)
    return dict(scenes=len(recipes), restored=len(tasks) - len(errors), differing=sorted(differing), errors=errors,
                label_counts=label_counts)
