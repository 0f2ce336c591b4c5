"""Summary of generated data: `ros2 run sim_bridge data_report DIR [--png FILE]`.

DIR is a datagen output directory (with objects/ and optionally scenes/) or a
directory of grasp tables.  Prints objects, simulated and successful grasps, mode
split, the wraps (held power grasps whose distal links wrapped past their stop, from each
row's finger angles: the wrap rule of physics.grasp_simulation.classify_mode), the
toward-the-palm rows of `datagen wrap`, what `datagen rescore` simulated again (its rows'
core-hours, held rows that no longer hold), skipped objects with their reasons, score
statistics per mode, labels per scene and their gravity-rejection score per mode;
writes a PNG with the score histograms per mode and the labels per scene.
Scenes are read from DIR/scenes or from --scenes (the tables are committed under
models/, the scenes are regenerated under out/).  The last four lines are
machine-readable:
  objects=<tables>   grasps=<successful grasps>   power_fraction=<power / successful>
  labels_per_scene_median=<median voxel labels per scene, or n/a without scenes>
"""

import argparse
import io
import json
import pathlib
import sys

import numpy as np

from gravgrasp_detector import atomic_files
from .object_grasps import MODE_NAMES, wrapping_power
from .power_grasps import DIRECTORY as TOWARD_PALM
from .rescored_tables import rescored_rows


def _tables_dir(d):
    d = pathlib.Path(d)
    return d / "objects" if (d / "objects").is_dir() else d


def wraps_of(table) -> np.ndarray:
    """Per row of an open table (np.load): does the held grasp wrap (object_grasps.wrapping_power)?
    None for a table that records no finger angles."""
    if "finger_joint_names" not in table.files:
        return None
    return wrapping_power(table) & table["grasped"].astype(bool)


def collect(data_dir, scenes_dir=None):
    """Aggregate statistics of a data directory as a dict."""
    tdir = _tables_dir(data_dir)
    per_mode = {"power": [], "precision": []}
    stats = dict(objects=0, simulated=0, grasped=0, power=0, precision=0, sim_wall_time_s=0.0,
                 grasped_per_object=[], skipped=[], perturbed={}, perturbed_objects=0, wraps=0, without_wrap_measure=0,
                 toward_palm=dict(objects=0, closed=0, held=0, wraps=0),
                 rescored=dict(objects=0, unread=0, simulated=0, wall_time_s=0.0, source_held=0, lost=0))
    table_rows = {}
    for p in sorted(tdir.glob("*.npz")):
        with np.load(p) as t:
            table_rows[p.stem] = len(t["grasped"])
            names = [str(n) for n in t["mode_names"]]
            mode, grasped, scores = t["mode"], t["grasped"], t["scores_n"]
            stats["objects"] += 1
            stats["simulated"] += len(mode)
            stats["grasped"] += int(grasped.sum())
            stats["grasped_per_object"].append(int(grasped.sum()))
            stats["sim_wall_time_s"] += float(t["wall_time_s"].sum()) if "wall_time_s" in t.files else 0.0
            for m in per_mode:
                sel = grasped & (mode == names.index(m))
                stats[m] += int(sel.sum())
                per_mode[m].append(scores[sel])
            wraps = wraps_of(t)
            stats["wraps"] += int(wraps.sum()) if wraps is not None else 0
            stats["without_wrap_measure"] += wraps is None
            if "rescored_from" in t.files:
                rs, rows = stats["rescored"], rescored_rows(t)
                rs["objects"] += 1
                rs["unread"] += rows is None
                if rows is not None:
                    again, source_held = rows
                    rs["simulated"] += int(again.sum())
                    rs["wall_time_s"] += float(t["wall_time_s"][again].sum())
                    rs["source_held"] += int(source_held.sum())
                    rs["lost"] += int((source_held & ~grasped.astype(bool)).sum())
    for p in sorted((tdir / TOWARD_PALM).glob("*.npz")):  # datagen wrap's rows (power_grasps)
        with np.load(p) as t:
            tp = stats["toward_palm"]
            tp["objects"] += 1
            tp["closed"] += len(t["grasped"])
            tp["held"] += int(t["grasped"].sum())
            tp["wraps"] += int(wraps_of(t).sum())  # the wrap stage always records the finger angles
    for p in sorted(tdir.glob("*.skip.json")):
        stats["skipped"].append(json.loads(p.read_text()))
    for p in sorted((tdir / "perturbed").glob("*.npz")):  # datagen perturb's rows (perturbed_grasps)
        with np.load(p) as t:
            stats["perturbed_objects"] += 1
            for shift, held in zip(t["shift_tcp_m"], t["grasped"]):
                way = "across the pads" if shift[0] else "shallower" if shift[2] else "unmoved"
                held_tried = stats["perturbed"].setdefault(way, [0, 0])
                held_tried[0] += int(held)
                held_tried[1] += 1
    stats["scores"] = {m: (np.concatenate(v) if v else np.zeros((0, 6))) for m, v in per_mode.items()}
    sdir = pathlib.Path(scenes_dir) if scenes_dir else pathlib.Path(data_dir) / "scenes"
    if (sdir / "scenes").is_dir():
        sdir = sdir / "scenes"
    labels, fg, fg_mode, arrangements, without_copies, copies, valid = [], [], [], [], [], [], []
    negatives, from_perturbed = [], 0
    for p in sorted(sdir.glob("*.npz")) if sdir.is_dir() else []:
        with np.load(p) as z:
            labels.append(len(z["label_score"]))
            negatives.append(len(z["negative_index"]) if "negative_index" in z.files else 0)
            if stats["perturbed"]:  # a label_grasp past its table's rows came from a perturbed row
                rows = np.array([table_rows.get(str(n), 1 << 30) for n in z["object_names"]])
                if len(z["label_object"]):
                    from_perturbed += int((z["label_grasp"] >= rows[z["label_object"]]).sum())
            fg.append(z["label_score"])
            fg_mode.append(z["label_mode"])
            arrangements.append(str(z["arrangement"]))
            if "n_labels_without_copies" in z.files:  # scenes made with object symmetries
                without_copies.append(int(z["n_labels_without_copies"]))
                copies.append(int((z["label_symmetry"] > 0).sum()))
            if "n_grasps_dropped_executed" in z.files:  # scenes made with the execution check
                # n_grasps_collision_free counts the grasps that passed every check of the
                # scene stage, the execution check included (dropped ones are already out)
                valid.append(int(z["n_grasps_collision_free"]))
    stats["labels_per_scene"] = np.asarray(labels)
    stats["label_scores"] = np.concatenate(fg) if fg else np.zeros(0)  # f_g of each label (Eq. 1 along gravity) [N]
    stats["label_modes"] = np.concatenate(fg_mode) if fg_mode else np.zeros(0, np.uint8)
    stats["arrangements"] = arrangements
    stats["labels_without_copies"] = np.asarray(without_copies)
    stats["labels_from_copies"] = int(np.sum(copies))
    stats["valid_grasps_per_scene"] = np.asarray(valid)
    stats["negatives_per_scene"] = np.asarray(negatives)
    stats["labels_from_perturbed"] = from_perturbed
    return stats


def report_text(s):
    lines = []
    g = s["grasped"]
    power_fraction = s["power"] / g if g else 0.0
    lines.append(f"grasp tables: {s['objects']} objects, {s['simulated']} simulated grasps, "
                 f"{g} held ({100 * g / max(1, s['simulated']):.1f}%)")
    lines.append(f"modes of held grasps: power {s['power']}, precision {s['precision']}")
    if s["without_wrap_measure"] < s["objects"]:
        lines.append(f"wraps (held grasps meeting the wrap rule): {s['wraps']} ({100 * s['wraps'] / max(1, g):.1f}% of held)"
                     + (f"; {s['without_wrap_measure']} tables record no finger angles"
                        if s["without_wrap_measure"] else ""))
    tp = s["toward_palm"]
    if tp["objects"]:
        both = g + tp["held"]
        lines.append(f"toward-the-palm rows (datagen wrap) of {tp['objects']} objects: {tp['closed']} closed, "
                     f"{tp['held']} held, {tp['wraps']} wraps; with them: {s['wraps'] + tp['wraps']} wraps of "
                     f"{both} held ({100 * (s['wraps'] + tp['wraps']) / max(1, both):.1f}%)")
    if s["sim_wall_time_s"] > 0:
        lines.append(f"simulation wall time: {s['sim_wall_time_s'] / 3600:.2f} core-hours, "
                     f"{3600 * s['simulated'] / s['sim_wall_time_s']:.0f} grasps per core-hour"
                     + ("; rescored tables count their copied rows at the source's time" if s["rescored"]["objects"] else ""))
    rs = s["rescored"]
    if rs["objects"]:
        # per-row wall time of a worker that had a core to itself: the rescoring's core-hours
        lines.append(f"rescored tables (datagen rescore): {rs['objects']} objects, {rs['simulated']} rows simulated "
                     f"again in {rs['wall_time_s'] / 3600:.2f} core-hours (the other rows copied); held in the source "
                     f"but not now: {rs['lost']} of {rs['source_held']} ({100 * rs['lost'] / max(1, rs['source_held']):.1f}%)"
                     + (f"; {rs['unread']} tables' sources not found (run from the project root)" if rs["unread"] else ""))
    if s["grasped_per_object"]:
        gp = np.asarray(s["grasped_per_object"])
        lines.append(f"held grasps per object: median {np.median(gp):.0f}, min {gp.min()}, max {gp.max()}, "
                     f"objects with none: {(gp == 0).sum()}")
    for m, sc in s["scores"].items():
        if len(sc):
            worst = sc.min(axis=1)
            lines.append(f"{m:9s} scores [N]: worst direction median {np.median(worst):.1f} "
                         f"(p10 {np.percentile(worst, 10):.1f}, p90 {np.percentile(worst, 90):.1f}); "
                         f"mean over directions median {np.median(sc.mean(axis=1)):.1f}")
    if s["perturbed"]:
        ways = "; ".join(f"{way} {held}/{tried} held ({100 * held / tried:.0f}%)"
                         for way, (held, tried) in sorted(s["perturbed"].items()))
        lines.append(f"perturbed rows (datagen perturb) of {s['perturbed_objects']} objects: {ways}")
    if s["skipped"]:
        lines.append(f"skipped objects: {len(s['skipped'])}")
        for e in s["skipped"]:  # the stage's reasons already begin with the name
            reason = e["reason"]
            lines.append(f"  {reason}" if reason.startswith(f"{e['name']}:") else f"  {e['name']}: {reason}")
    n = s["labels_per_scene"]
    if len(n):
        arr = {a: s["arrangements"].count(a) for a in sorted(set(s["arrangements"]))}
        lf = s["label_modes"]
        lines.append(f"scenes: {len(n)} ({', '.join(f'{k} {v}' for k, v in arr.items())}); labels per scene "
                     f"mean {n.mean():.1f}, median {np.median(n):.0f}, min {n.min()}, max {n.max()}; "
                     f"scenes without labels: {(n == 0).sum()}")
        if len(lf):
            fg = s["label_scores"]
            per_mode = ", ".join(f"{m} {np.median(fg[lf == k]):.1f} N" for k, m in enumerate(MODE_NAMES[:2])
                                 if (lf == k).any())
            lines.append(f"labels: {len(lf)}, power {100 * (lf == 0).mean():.1f}%; gravity-rejection score "
                         f"median {np.median(fg):.1f} N ({per_mode})")
        neg = s["negatives_per_scene"]
        lines.append(f"explicit validness negatives per scene: median {np.median(neg):.0f}, mean {neg.mean():.1f}")
        if s["perturbed"] and len(lf):
            lines.append(f"labels from perturbed rows: {s['labels_from_perturbed']} "
                         f"({100 * s['labels_from_perturbed'] / len(lf):.1f}%)")
        w = s["labels_without_copies"]
        if len(w) == len(n) and len(lf):
            lines.append(f"symmetric copies: {100 * s['labels_from_copies'] / len(lf):.1f}% of labels; the simulated "
                         f"grasps alone would give a median {np.median(w):.0f} labels per scene (mean {w.mean():.1f})")
        v = s["valid_grasps_per_scene"]
        if len(v) == len(n):
            # a label is one voxel; several valid grasps (copies, neighbouring candidates)
            # often share it. Counted as grasps, as the paper's "1.2K per scene" may be:
            lines.append(f"valid grasps per scene (clear of the scene, checked where executed): median "
                         f"{np.median(v):.0f}, mean {v.mean():.1f}; {v.sum() / max(len(lf), 1):.1f} per labelled voxel")
    lines.append(f"objects={s['objects']}")
    lines.append(f"grasps={g}")
    lines.append(f"power_fraction={power_fraction:.4f}")
    lines.append(f"labels_per_scene_median={np.median(n):.0f}" if len(n) else "labels_per_scene_median=n/a")
    return "\n".join(lines)


def report_png(s):
    # lazy: matplotlib (seconds), with the Agg backend chosen before pyplot loads
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    bins = np.linspace(0, max([1.0] + [float(v.max()) for v in s["scores"].values() if len(v)]), 40)
    for m, sc in s["scores"].items():
        if len(sc):
            axes[0].hist(sc.min(axis=1), bins=bins, alpha=0.6, label=f"{m} ({len(sc)})")
            axes[1].hist(sc.mean(axis=1), bins=bins, alpha=0.6, label=f"{m} ({len(sc)})")
    axes[0].set(title="worst-direction disturbance score", xlabel="N", ylabel="grasps")
    axes[1].set(title="mean of the 6 disturbance scores", xlabel="N")
    for ax in axes[:2]:
        ax.legend()
    if len(s["labels_per_scene"]):
        axes[2].hist(s["labels_per_scene"], bins=30)
    axes[2].set(title="labels (voxels) per scene", xlabel="labels", ylabel="scenes")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return buf.getvalue()


def main(argv=None):
    p = argparse.ArgumentParser(prog="data_report", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("data", help="datagen output directory (objects/, scenes/) or a directory of grasp tables")
    p.add_argument("--png", default=None, help="write the histograms here (default: DATA/report.png)")
    p.add_argument("--scenes", default=None, help="scene-stage output (default: DATA/scenes)")
    args = p.parse_args(argv)
    tdir = _tables_dir(args.data)
    if not tdir.is_dir():
        print(f"data_report: {args.data} is not a directory", file=sys.stderr)
        return 2
    s = collect(args.data, args.scenes)
    if not s["objects"] and not s["skipped"]:
        print(f"data_report: no grasp tables (*.npz) in {tdir}", file=sys.stderr)
        return 2
    png = pathlib.Path(args.png) if args.png else pathlib.Path(args.data) / "report.png"
    atomic_files.save_bytes(png, report_png(s))
    print(f"histograms: {png}")
    print(report_text(s))
    return 0


if __name__ == "__main__":
    sys.exit(main())
