"""How many labels per scene do more candidates per object buy? `python -m sim_bridge.studies.table_size_study`.

Labels are voxels (one per voxel: the best grasp there), so more simulated candidates
per object add labels only where they land in voxels no other grasp holds yet. This
study measures that without any physics: it relabels a sample of committed scenes
(scene recipes: the settled objects and views) with every grasp table cut to its first
n candidates, for several n. Candidates past n are marked as simulation errors, so they
are neither labels nor explicit negatives: the scene is labelled as if the table had
been simulated to n. Tables grow block by block with the same seed, so the first n
candidates of a grown table are those of a table simulated to n.

Reported: the median and mean labels per scene at each n, and the elasticity between
the two largest n (d log labels / d log n: 1 would mean labels grow as candidates do).
Last line: `labels_per_scene_median_at_<largest n>=`.
"""

import argparse
import json
import pathlib
import sys
from dataclasses import dataclass

import numpy as np
from gravgrasp_detector import atomic_files

from ..datagen.scene_dataset import SceneTask, label_scene, usable_tables
from ..datagen.scene_recipes import read_recipes, scene_task, settled_scene
from ..parallel import make_executor, run_tasks

CUT_REASON = "simulation error (table cut by table_size_study)"  # startswith: not a negative


@dataclass(frozen=True)
class StudyTask:
    scene: SceneTask
    recipe: dict
    sizes: tuple


def cut_table(table: dict, n: int) -> dict:
    """The table as if simulated to its first n candidates (the arrays keep their length)."""
    t = dict(table)
    grasped = t["grasped"].astype(bool).copy()
    grasped[n:] = False
    reason = t["reason"].astype(str) if "reason" in t else np.full(len(grasped), "")
    reason = reason.astype(f"<U{max(len(CUT_REASON), reason.dtype.itemsize // 4)}")
    reason[n:] = CUT_REASON
    t["grasped"], t["reason"] = grasped, reason
    return t


def run_study_task(task: StudyTask):
    """Worker: ("ok", {n: labels}) or ("error", message)."""
    try:
        tables, specs, poses, views = settled_scene(task.scene, task.recipe)
        return "ok", {n: len(label_scene(task.scene, [cut_table(t, n) for t in tables], specs, poses, views)
                             ["label_score"]) for n in task.sizes}
    except Exception as e:  # reported; the other scenes go on
        return "error", f"scene {task.scene.index}: {type(e).__name__}: {e}"


def summarize(counts: dict, sizes) -> dict:
    """counts {scene: {n: labels}} -> per n median/mean, and the elasticity between the
    two largest n."""
    a = np.array([[c[n] for n in sizes] for c in counts.values()], float).reshape(-1, len(sizes))
    out = dict(scenes=len(a), sizes=list(sizes), median=np.median(a, 0).tolist(), mean=a.mean(0).tolist())
    if len(sizes) > 1 and len(a) and out["median"][-2] > 0:
        out["elasticity_median"] = float(np.log(out["median"][-1] / out["median"][-2]) / np.log(sizes[-1] / sizes[-2]))
    return out


def main(argv=None):
    p = argparse.ArgumentParser(prog="table_size_study", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--recipes", default="models/scene_recipes_v3", help="scene recipes (datagen recipes pack)")
    p.add_argument("--tables", default="models/grasp_tables_v2",
                   help="objects-stage output (holds objects/) to label with; the scenes' objects must be in it")
    p.add_argument("--meshes", action="append", default=[], help="where the tables' mesh files are")
    p.add_argument("--sizes", default="64,128,192,256", help="candidates per object to cut the tables to")
    p.add_argument("--every", type=int, default=100, help="study every N-th scene of the recipes")
    p.add_argument("--workers", type=int, default=None)
    p.add_argument("--out", default="out/table_size_study.json", help="results (resumes: scenes done are kept)")
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    sizes = tuple(sorted(int(s) for s in args.sizes.split(",")))
    recipes_dir = pathlib.Path(args.recipes)
    if not (recipes_dir / "manifest.json").exists():
        p.error(f"{recipes_dir} holds no scene recipes (no manifest.json)")
    manifest = json.loads((recipes_dir / "manifest.json").read_text())
    objects_dir = pathlib.Path(args.tables) / "objects"
    names = tuple(usable_tables(objects_dir))
    recipes = read_recipes(recipes_dir)
    out = pathlib.Path(args.out)
    done = json.loads(out.read_text()) if out.exists() else {}
    if done and done.get("sizes") != list(sizes):
        p.error(f"{out} holds a study of sizes {done.get('sizes')}: use those or another --out")
    counts = {int(i): {int(n): v for n, v in c.items()} for i, c in done.get("counts", {}).items()}
    missing = sorted({str(n) for r in recipes.values() for n in r["object_names"]} - set(names))
    if missing:
        p.error(f"{len(missing)} objects of the scenes have no usable table in {objects_dir} (e.g. {missing[0]})")
    tasks = [StudyTask(scene_task(manifest, i, recipes[i], objects_dir, names, args.meshes), recipes[i], sizes)
             for i in sorted(recipes)[::args.every] if i not in counts]
    errors = []

    def save():
        atomic_files.save_json(out, dict(recipes=str(recipes_dir), tables=str(args.tables), sizes=list(sizes),
                                         counts={str(i): {str(n): v for n, v in c.items()} for i, c in counts.items()}))

    def on_result(task, result):
        status, payload = result
        if status != "ok":
            errors.append(payload)
            return
        counts[task.scene.index] = payload
        save()

    out.parent.mkdir(parents=True, exist_ok=True)
    if tasks:
        with make_executor(args.workers) as ex:
            run_tasks(ex, run_study_task, tasks, on_result, desc="table size study", progress=not args.no_progress)
    for e in errors:
        print(e)
    s = summarize(counts, sizes)
    print(f"{s['scenes']} scenes of {recipes_dir}, labelled with {objects_dir} cut to n candidates per object:")
    for n, med, mean in zip(sizes, s["median"], s["mean"]):
        print(f"  n={n}: labels per scene median {med:g}, mean {mean:.1f}")
    if "elasticity_median" in s:
        print(f"elasticity of the median between n={sizes[-2]} and {sizes[-1]}: {s['elasticity_median']:.2f}")
    print(f"labels_per_scene_median_at_{sizes[-1]}={s['median'][-1]:g}" if s["scenes"] else "no scene was studied")
    return 1 if errors or not s["scenes"] else 0


if __name__ == "__main__":
    sys.exit(main())
