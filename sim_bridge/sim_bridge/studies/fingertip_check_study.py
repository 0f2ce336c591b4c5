"""Does the executor's fingertip-table check agree with the labels? (gravgrasp_detector
README, *Fingertips and the table*.)

For every label of a scene directory, at the pose detection would publish for it (its
voxel centre, its rotation): the executor's estimate of the lowest closed pad tip
(`hand_clearance`: the pads stop at the extent of the occupied TSDF voxels between them,
closing in parallel) against the tip the simulation's own fingers reach (forward
kinematics of the finger angles the grasp table recorded when the object settled). Per
grasp mode: how many labels the check would refuse and the estimate's error along the
approach. The last line is `power_refused_fraction=`.

    python -m sim_bridge.studies.fingertip_check_study --scenes out/scenes_v3 \
        --objects models/grasp_tables_v2 [--max-scenes 40]
"""
from __future__ import annotations

import argparse
import pathlib

import numpy as np

from gravgrasp_detector.perception import hand_clearance
from robotiq_driver.hand_geometry import pad_tip_z_m

from ..datagen.object_grasps import MODE_NAMES
from ..datagen.perturbed_grasps import load_labelling_table
from ..datagen.voxel_labels import RESOLUTION, label_poses
from ..physics.hand_model import FingerKinematics
from ..physics.scenes import VOLUME_SIZE_M


def compare(scene_dir, objects_dir, max_scenes=0):
    """-> {mode name: dict(n, refused, error_mm (estimate - actual tip depth))}."""
    fingers = FingerKinematics()
    tables, out = {}, {}
    files = sorted((pathlib.Path(scene_dir) / "scenes").glob("*.npz"))[:max_scenes or None]
    for path in files:
        z = dict(np.load(path))
        table_z, voxel = float(z["table_height_m"]), VOLUME_SIZE_M / RESOLUTION
        X = label_poses(z, voxel)
        opening, low = hand_clearance.closed_tips_estimate(X, (z["tsdf"], voxel, np.zeros(3)), table_z)
        refused = low < table_z
        for i, name in enumerate(str(n) for n in z["object_names"]):
            rows = np.flatnonzero(z["label_object"] == i)
            if not len(rows):
                continue
            if name not in tables:
                tables[name] = load_labelling_table(pathlib.Path(objects_dir) / "objects", name)
            t = tables[name]
            tips = fingers.pad_tips_tcp(t["finger_joint_names"], t["finger_joint_angles"][z["label_grasp"][rows]])
            error_mm = 1000 * (pad_tip_z_m(opening[rows]) - tips[:, :, 2].max(axis=1))
            for mode in np.unique(z["label_mode"][rows]):
                sel = z["label_mode"][rows] == mode
                d = out.setdefault(MODE_NAMES[int(mode)], {"n": 0, "refused": 0, "error_mm": []})
                d["n"] += int(sel.sum())
                d["refused"] += int(refused[rows][sel].sum())
                d["error_mm"].extend(error_mm[sel].tolist())
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", required=True, help="scene stage output directory (holds scenes/)")
    parser.add_argument("--objects", required=True, help="objects stage output directory (holds objects/)")
    parser.add_argument("--max-scenes", type=int, default=0, help="the first N scenes (0: all)")
    args = parser.parse_args(argv)
    result = compare(args.scenes, args.objects, args.max_scenes)
    for mode, d in sorted(result.items()):
        e = np.asarray(d["error_mm"])
        print(f"{mode}: labels={d['n']} refused={d['refused']} ({d['refused'] / max(d['n'], 1):.3f}) "
              f"estimate_minus_actual_mm median={np.median(e):.1f} p10={np.percentile(e, 10):.1f} "
              f"p90={np.percentile(e, 90):.1f}")
    power = result.get("power", {"n": 0, "refused": 0})
    print(f"power_refused_fraction={power['refused'] / max(power['n'], 1):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
