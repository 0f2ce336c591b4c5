"""From which weight does a power grasp hold what no precision grasp of the same object
does, in the labels' physics? `python -m sim_bridge.studies.mode_payload_study`.

Issue 42 asks Ours to beat Ours-Precision at 4 kg "where the label physics separates the
modes", and otherwise to say at which weight, if any, power grasps pay. This reads the
committed grasp tables (no simulation): each object in each of its resting poses on the
table (weighted by the pose's probability), its held grasps in that pose, kept where a
benchmark could execute them (approach within APPROACH_CONE_DEG of straight down, the
open hand and its 5 cm approach above the table: `hand_collision`, as datagen labels),
and each grasp's gravity-rejection score f_g (paper Eq. 1, `gravity_projection`). At a
weight m, a mode "holds" an object's pose when its best grasp there has f_g >= m g.

The table it prints, per weight: the share of object poses that a precision grasp holds,
that a power grasp holds, that only a power grasp holds (what power labels can add) and
that only a precision grasp holds; and among the grasps that hold, the power share.
Scores are capped at the simulation's max_force_n (100 N), so weights past ~10 kg say
nothing. Executed grasps hold less than their labels (doc/label-execution-study.md), so
this is the most power grasps could add, not what the benchmark will show.

A power grasp counts as one only where it wraps (palm or proximal contact, both distal
links past their stop: grasp_simulation.classify_mode); tables are read with the rows
appended for labelling (perturbed, toward the palm).

Writes `--out` (JSON) and prints the table; the last lines are `only_power_fraction_<kg>kg=`,
`power_over_precision_best_fg=` (median best power f_g over median best precision f_g,
poses with both) and `wrap_power_fraction=` (the share of executable held grasps that wrap).
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import numpy as np
from gravgrasp_detector import atomic_files
from gravgrasp_detector.training.scenes import G_MPS2

from ..datagen.object_grasps import MODE_NAMES, wrapping_power
from ..datagen.perturbed_grasps import load_labelling_table
from ..physics import hand_collision
from ..physics.gravity_projection import gravity_rejection_score

WEIGHTS_KG = (0.1, 0.5, 1.0, 1.5, 2.5, 4.0, 6.0, 8.0)
APPROACH_CONE_DEG = 80.0  # the benchmark's executable approaches (datagen's execution check)
APPROACH_M = 0.05         # the executor's pre-grasp distance
POWER, PRECISION = MODE_NAMES.index("power"), MODE_NAMES.index("precision")


def pose_scores(table: dict) -> list:
    """[(rest probability, power f_g's, precision f_g's)] of the executable held grasps in each
    resting pose of one grasp table."""
    held = np.flatnonzero(table["grasped"].astype(bool))
    # the commanded pose, as the scene labels carry it (scene_dataset's label_pose): where the
    # robot puts the hand, checked against the table; the settled pose of a wrap sits deeper,
    # where the object was pulled onto the palm without gravity
    X_object_tcp = table["X_object_tcp_candidate"][held].astype(np.float64)
    mode = np.where(wrapping_power(table), POWER, PRECISION)[held]
    out = []
    for X_table_object, p in zip(table["rest_X_table_object"], table["rest_probability"]):
        X = X_table_object[None] @ X_object_tcp
        ok = -X[:, 2, 2] >= np.cos(np.deg2rad(APPROACH_CONE_DEG))
        ok[ok] = ~hand_collision.collides(X[ok], None, table_z_m=0.0, approach_m=APPROACH_M)
        f_g = gravity_rejection_score(table["scores_n"][held][ok], X[ok, :3, :3]) if ok.any() else np.zeros(0)
        m = mode[ok]
        out.append((float(p), f_g[m == POWER], f_g[m == PRECISION]))
    return out


def best(f_g) -> float:
    """The strongest grasp's f_g; -inf without one."""
    return float(np.max(f_g, initial=-np.inf))


def study(tables: dict, weights_kg=WEIGHTS_KG) -> dict:
    """tables: {name: grasp table} -> per weight, the probability-weighted shares over
    objects (each object counts 1, split over its resting poses)."""
    poses = {name: pose_scores(t) for name, t in tables.items()}
    rows = []
    for kg in weights_kg:
        need = kg * G_MPS2
        acc = dict.fromkeys(("precision", "power", "only_power", "only_precision", "either"), 0.0)
        held_power = held_all = 0
        for per_pose in poses.values():
            total_p = sum(p for p, *_ in per_pose) or 1.0
            for p, power, precision in per_pose:
                w = p / total_p
                a, b = best(power) >= need, best(precision) >= need
                acc["power"] += w * a
                acc["precision"] += w * b
                acc["only_power"] += w * (a and not b)
                acc["only_precision"] += w * (b and not a)
                acc["either"] += w * (a or b)
                held_power += int((power >= need).sum())
                held_all += int((power >= need).sum() + (precision >= need).sum())
        n = len(poses) or 1
        rows.append({"mass_kg": kg, **{k: v / n for k, v in acc.items()},
                     "power_share_of_holding_grasps": held_power / held_all if held_all else float("nan"),
                     "holding_grasps": held_all})
    pose_list = [pose for per in poses.values() for pose in per]
    both = np.array([(best(a), best(b)) for _, a, b in pose_list if a.size and b.size]).reshape(-1, 2)
    all_power = np.concatenate([a for _, a, _ in pose_list] or [np.zeros(0)])
    all_precision = np.concatenate([b for _, _, b in pose_list] or [np.zeros(0)])
    return {"objects": len(poses), "weights": rows,
            "median_f_g_n": {"power": float(np.median(all_power)) if all_power.size else float("nan"),
                             "precision": float(np.median(all_precision)) if all_precision.size else float("nan")},
            "grasps": {"power": int(all_power.size), "precision": int(all_precision.size)},
            # object poses that have executable held grasps of both modes: how their best compare
            "poses_with_both_modes": len(both),
            # what issue targets name: the share of executable held grasps that wrap, and
            # the median best power f_g over the median best precision one where a pose has both
            "wrap_power_fraction": (float(all_power.size / (all_power.size + all_precision.size))
                                    if all_power.size + all_precision.size else float("nan")),
            "power_over_precision_best_fg": (float(np.median(both[:, 0]) / np.median(both[:, 1]))
                                             if len(both) else float("nan")),
            "power_best_stronger": float((both[:, 0] > both[:, 1]).mean()) if len(both) else float("nan"),
            "median_best_f_g_n": {"power": float(np.median(both[:, 0])) if len(both) else float("nan"),
                                  "precision": float(np.median(both[:, 1])) if len(both) else float("nan")}}


def report_lines(result: dict) -> list:
    lines = [f"{result['objects']} objects; executable held grasps over their resting poses: power "
             f"{result['grasps']['power']} (median f_g {result['median_f_g_n']['power']:.1f} N), precision "
             f"{result['grasps']['precision']} (median {result['median_f_g_n']['precision']:.1f} N)",
             f"object poses with both modes: {result['poses_with_both_modes']}; the best power grasp stronger than "
             f"the best precision one in {result['power_best_stronger']:.3f} of them (medians of the best: power "
             f"{result['median_best_f_g_n']['power']:.1f} N, precision {result['median_best_f_g_n']['precision']:.1f} N)",
             "",
             "| weight | precision holds | power holds | only power | only precision | power share of holding grasps |",
             "| --- | --- | --- | --- | --- | --- |"]
    for r in result["weights"]:
        lines.append(f"| {r['mass_kg']:g} kg ({r['mass_kg'] * G_MPS2:.1f} N) | {r['precision']:.3f} | {r['power']:.3f} | "
                     f"{r['only_power']:.3f} | {r['only_precision']:.3f} | "
                     f"{r['power_share_of_holding_grasps']:.3f} ({r['holding_grasps']}) |")
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("--tables", default="models/grasp_tables_v3", help="grasp tables (objects/*.npz)")
    p.add_argument("--out", default="sim_bridge/results/mode_payload_study.json", help="the JSON to write")
    p.add_argument("--weights", default=",".join(f"{w:g}" for w in WEIGHTS_KG), help="comma-separated kg")
    args = p.parse_args(argv)
    files = sorted(pathlib.Path(args.tables).glob("objects/*.npz"))
    if not files:
        print(f"mode_payload_study: no grasp tables under {args.tables}/objects: give --tables the directory "
              "that `datagen objects` wrote (e.g. models/grasp_tables_v3)", file=sys.stderr)
        return 2
    try:
        weights = tuple(float(w) for w in args.weights.split(","))
    except ValueError:
        print(f"mode_payload_study: --weights {args.weights!r}: give kg separated by commas, e.g. 0.1,1.5,4",
              file=sys.stderr)
        return 2
    # each table with the rows appended for labelling (perturbed, toward the palm)
    result = study({f.stem: load_labelling_table(f.parent, f.stem) for f in files}, weights)
    result["tables"] = args.tables
    atomic_files.save_json(pathlib.Path(args.out), result)
    print("\n".join(report_lines(result)))
    last = result["weights"][-1]
    print(f"only_power_fraction_{last['mass_kg']:g}kg={last['only_power']:.3f}")
    print(f"power_over_precision_best_fg={result['power_over_precision_best_fg']:.3f}")
    print(f"wrap_power_fraction={result['wrap_power_fraction']:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
