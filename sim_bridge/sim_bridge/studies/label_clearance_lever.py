"""The label-time clearance lever: a label the executor would refuse becomes an explicit
validness negative instead of a positive. Tried on Ours, worse on the benchmark, not
shipped (sim_bridge/doc/label-clearance-lever.md).

Data generation keeps a grasp whose open hand clears the true geometry of the scene; the
executor refuses one whose open hand, swept from the pre-grasp along the approach, meets
the occupied voxels of the TSDF it observes (hand_clearance: the band behind every seen
surface counts as solid, the true object may be thinner). A network trained on labels of
the first kind learns to pick grasps of the second. This applies the executor's own check
(`hand_clearance.hands_collide`, first_collision's verdict) to each label at the pose
detection publishes for its voxel, on the scene's own TSDF, and moves the refused ones to
the negatives with reason NEGATIVE_REFUSED, on the scene as stored: training's
augmentation then moves them with the volume as it moves the other negatives.

    python -m sim_bridge.studies.label_clearance_lever SCENE_DIR               # what it refuses
    python -m sim_bridge.studies.label_clearance_lever SCENE_DIR --write OUT   # scenes to train on
"""
from __future__ import annotations

import argparse
import pathlib
import sys
import time

import numpy as np

from gravgrasp_detector import atomic_files
from gravgrasp_detector.execution.executor import ExecutionLimits
from gravgrasp_detector.perception import hand_clearance, tsdf
from gravgrasp_detector.perception.hand_clearance import ROBOTIQ_2F85, HandGeometry
from gravgrasp_detector.training.scenes import DataError, load_scene

# negative_reason codes: datagen's are 1 (a simulated failure) and 2 (the hand collides
# with the true geometry); this one is the lever's
NEGATIVE_REFUSED = 3
# the executor's default pre-grasp stand-off, the one the benchmark runs with
PREGRASP_DISTANCE_M = ExecutionLimits.pregrasp_distance_m


def label_poses(index, e_x, e_z, voxel_size_m: float) -> np.ndarray:
    """(K, 4, 4) TCP poses of labels in the grid's frame: the voxel centre
    (index + 0.5) x voxel size, the pose detection publishes for a voxel, and the rotation
    [e_x, e_z x e_x, e_z] that training's rotation target uses."""
    e_x = np.asarray(e_x, float) / np.linalg.norm(e_x, axis=1, keepdims=True)
    e_z = np.asarray(e_z, float) / np.linalg.norm(e_z, axis=1, keepdims=True)
    X = np.repeat(np.eye(4)[None], len(e_x), axis=0)
    X[:, :3, 0], X[:, :3, 1], X[:, :3, 2] = e_x, np.cross(e_z, e_x), e_z
    X[:, :3, 3] = (np.asarray(index, float) + 0.5) * voxel_size_m
    return X


def refused_labels(scene, approach_m: float = PREGRASP_DISTANCE_M,
                   hand: HandGeometry = ROBOTIQ_2F85) -> np.ndarray:
    """(K,) bool: the labels of a scene (load_scene's dict) whose open hand, swept
    `approach_m` from the pre-grasp, meets the scene's occupied TSDF voxels. The volume is
    tsdf.SIZE_M wide, as the scene stage fuses it."""
    grid = scene["tsdf"]
    voxel_size_m = tsdf.SIZE_M / grid.shape[0]
    points = hand_clearance.occupied_points(grid, voxel_size_m)
    poses = label_poses(scene["index"], scene["e_x"], scene["e_z"], voxel_size_m)
    return hand_clearance.hands_collide(poses, points, voxel_size_m, approach_m, hand)


def parts_hit(scene, refused) -> dict[str, int]:
    """{hand part: how many of the `refused` labels it meets the observed voxels with}
    (first_collision's words for them; a label can count for several parts)."""
    voxel_size_m = tsdf.SIZE_M / scene["tsdf"].shape[0]
    poses = label_poses(scene["index"][refused], scene["e_x"][refused], scene["e_z"][refused], voxel_size_m)
    counts = {}
    for X in poses:
        pregrasp = X.copy()
        pregrasp[:3, 3] -= PREGRASP_DISTANCE_M * X[:3, 2]
        hits = hand_clearance.collisions({"pregrasp": pregrasp, "grasp": X},
                                         (scene["tsdf"], voxel_size_m, np.zeros(3)))
        for part in {part for by_part in hits.values() for part in by_part}:
            counts[part] = counts.get(part, 0) + 1
    return counts


def report(scene_dir) -> str:
    """What the lever does to the scene files under `scene_dir`: the labels it
    refuses, per grasp mode, the scenes it leaves without a label, its CPU per scene; the
    scores of the refused and kept labels, and the hand parts that meet the voxels."""
    files = _scene_files(scene_dir)
    labels, refused, empty_before, empty_after, cpu_s = {}, {}, 0, 0, 0.0
    scores_refused, scores_kept, parts = [], [], {}
    for f in files:
        scene = load_scene(f)
        t0 = time.process_time()
        hit = refused_labels(scene)
        cpu_s += time.process_time() - t0
        modes = (np.array(scene["mode_names"])[scene["mode"]] if scene["mode"] is not None
                 else np.full(len(hit), "unknown"))
        for name in np.unique(modes):
            labels[name] = labels.get(name, 0) + int((modes == name).sum())
            refused[name] = refused.get(name, 0) + int(hit[modes == name].sum())
        scores_refused.append(scene["score"][hit])
        scores_kept.append(scene["score"][~hit])
        for part, n in parts_hit(scene, hit).items():
            parts[part] = parts.get(part, 0) + n
        empty_before += len(hit) == 0
        empty_after += len(hit) == int(hit.sum())
    total, total_refused = sum(labels.values()), sum(refused.values())
    lines = [f"scenes={len(files)} labels={total} refused={total_refused} "
             f"refused_fraction={total_refused / max(total, 1):.4f}"]
    lines += [f"{name}: labels={labels[name]} refused={refused[name]} "
              f"refused_fraction={refused[name] / max(labels[name], 1):.4f}" for name in sorted(labels)]
    lines += [f"scenes_without_labels: before={empty_before} ({empty_before / len(files):.4f}) "
              f"after={empty_after} ({empty_after / len(files):.4f})",
              f"cpu_per_scene_s={cpu_s / len(files):.4f}",
              f"score_median_n: refused={_median(scores_refused):.1f} kept={_median(scores_kept):.1f}",
              "refused_by_part: " + ", ".join(f"{part}={n}" for part, n in
                                              sorted(parts.items(), key=lambda kv: -kv[1]))]
    return "\n".join(lines)


def _scene_files(scene_dir) -> list:
    files = sorted(pathlib.Path(scene_dir).rglob("*.npz"))
    if not files:
        raise DataError(f"no scene files (*.npz) under {scene_dir}; give the scenes directory of "
                        "'ros2 run sim_bridge datagen scenes' (or of 'recipes restore')")
    return files


def _median(arrays) -> float:
    values = np.concatenate(arrays)
    return float(np.median(values)) if len(values) else float("nan")


def write_scenes(scene_dir, out_dir) -> tuple[int, int]:
    """Every scene file under `scene_dir` written under `out_dir` (same relative path) with
    its refused labels moved to the negatives, the arrays otherwise as stored; a file
    already written is kept, so an interrupted run resumes. Returns (scenes written now,
    labels refused in them)."""
    scene_dir, out_dir = pathlib.Path(scene_dir), pathlib.Path(out_dir)
    files = _scene_files(scene_dir)
    written = refused_total = 0
    for f in files:
        out = out_dir / f.relative_to(scene_dir)
        if out.exists():
            continue
        scene = load_scene(f)
        hit = refused_labels(scene)
        with np.load(f) as z:
            arrays = {k: z[k] for k in z.files}
        if hit.any():
            for key in ("label_index", "label_score", "label_e_x", "label_e_z", "label_mode"):
                if key in arrays:
                    arrays[key] = arrays[key][~hit]
            negatives = arrays.get("negative_index", np.zeros((0, 3), np.uint8)).reshape(-1, 3)
            reasons = arrays.get("negative_reason", np.zeros(len(negatives), np.uint8)).reshape(-1)
            arrays["negative_index"] = np.concatenate([negatives, scene["index"][hit].astype(negatives.dtype)])
            arrays["negative_reason"] = np.concatenate([reasons, np.full(int(hit.sum()), NEGATIVE_REFUSED,
                                                                         reasons.dtype)])
        out.parent.mkdir(parents=True, exist_ok=True)
        atomic_files.save_npz(out, **arrays)
        written, refused_total = written + 1, refused_total + int(hit.sum())
    return written, refused_total


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m sim_bridge.studies.label_clearance_lever", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scene_dir", help="scene files (*.npz, searched recursively)")
    p.add_argument("--write", metavar="OUT", default="",
                   help="write the scenes with the refused labels as negatives under OUT (resumes)")
    args = p.parse_args(argv)
    try:
        if args.write:
            written, refused = write_scenes(args.scene_dir, args.write)
            print(f"labels_refused={refused}")
            print(f"scenes_written={written}")
        else:
            print(report(args.scene_dir))
    except DataError as err:
        print(f"label_clearance_lever: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
