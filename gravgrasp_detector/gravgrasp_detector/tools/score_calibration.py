"""Can the scores be trusted? Predicted against simulated gravity-rejection score at the
labelled voxels of held-out scenes, per grasp mode (power / precision).

`ros2 run gravgrasp_detector score_calibration --model M --data SCENES --out DIR`
(`make calibration`) writes DIR/calibration.png (one panel per mode: predicted against
simulated score, the y = x line; then the validness reliability diagram) and
DIR/calibration.json, and prints per mode the number of labels, the MAE [N] and
Spearman's rank correlation, then validness precision / recall at the deployed threshold,
precision at equal recalls (EQUAL_RECALLS) and AUROC over the voxels `detect` considers, and where `detect`'s top 1 and top 5 grasps
of a scene land under each ranking (score, expected_score = validness x score and
validness for a score model, and told_<m>kg: by validness among the
grasps scored >= 1.5 x m g, a detector told the payload m): on a labelled voxel (a grasp there held), on an explicit
negative (a simulated failure or a colliding pose there), or on neither, and how many top-1
picks landed on a label whose simulated f_g holds 0.1 / 0.5 / 1.5 / 2.5 / 4 kg (f_g >= m g:
the benchmark's weights in label physics); last line `score_mae_n=<all modes>`.

Which scenes: by default those the model's own training split held out (the seed and
validation fraction stored in the model file; the split is by file name, so the same
scenes are held out whatever else is in the folder). `--split all` uses every scene, for
scenes the model never trained on (another dataset, the held-out meshes).

Every label of a scene file is a grasp that held in simulation, with its simulated
score (paper Eq. 1 projected on gravity); the prediction is the network's score head at
that voxel, the same number `detect` ranks by.
"""
from __future__ import annotations

import argparse
import pathlib
import sys

import numpy as np
import torch
from scipy.stats import spearmanr

from ..atomic_files import save_figure, save_json
from ..perception import model_file
from ..perception.detection import (DetectionOptions, detect_grasps, near_surface_mask, network_outputs,
                                   payload_min_score_n, rotations_at, select_grasps)
from ..training.config import TrainConfig
from ..training.losses import auroc
from ..training.scenes import G_MPS2, DataError, load_scene, split_scenes


@torch.no_grad()
def network_at_labels(model, scene_files, surface_distance_voxels=DetectionOptions().surface_distance_voxels):
    """One forward pass per scene -> (pairs, validness):
    pairs: {mode name: (predicted_n, simulated_n)} at the labelled voxels (scenes
    without label_mode count as mode 'all');
    validness: (predicted probability, labelled) at every voxel `detect` considers (near
    an observed surface, its `surface_distance_voxels`); a voxel is labelled valid when
    a grasp that held sits there, every other candidate voxel counts as not valid, as in
    training's validation metrics."""
    model.eval()
    found: dict[str, tuple[list, list]] = {}
    probability, labelled = [], []
    for path in scene_files:
        scene = load_scene(path)
        if scene["tsdf"].shape != (model.resolution,) * 3:
            raise DataError(f"scene {path} has a {scene['tsdf'].shape} grid but the model takes "
                            f"{model.resolution}^3: use scenes made with the model's TSDF settings")
        grid = torch.from_numpy(np.ascontiguousarray(scene["tsdf"]))
        out = model(grid[None, None])
        i, j, k = torch.from_numpy(scene["index"]).T
        valid = torch.zeros(grid.shape, dtype=torch.bool)
        valid[i, j, k] = True
        candidate = near_surface_mask(grid, surface_distance_voxels)
        probability.append(torch.sigmoid(out["validness_logit"][0].float())[candidate].numpy())
        labelled.append(valid[candidate].numpy())
        if not len(scene["score"]):
            continue
        predicted = out["score_n"][0][i, j, k].float().numpy()
        modes = (np.zeros(len(predicted), int) if scene["mode"] is None else scene["mode"])
        names = ["all"] if scene["mode"] is None else list(scene["mode_names"])
        for m in np.unique(modes):
            pred, sim = found.setdefault(names[m], ([], []))
            pred.append(predicted[modes == m])
            sim.append(scene["score"][modes == m])
    pairs = {name: (np.concatenate(p), np.concatenate(s)) for name, (p, s) in found.items()}
    validness = (np.concatenate(probability), np.concatenate(labelled)) if probability else (np.zeros(0), np.zeros(0, bool))
    return pairs, validness


TOP_K = (1, 5)
# Object weights a pick is checked against (the benchmark's three, then heavier): a pick
# "holds m kg" when the label at its voxel says f_g >= m g (paper Eq. 1's meaning).
HOLDS_KG = (0.1, 0.5, 1.5, 2.5, 4.0)


def label_score_at(scene, grasp):
    """f_g [N] of the label at the grasp's voxel whose rotation is closest to the grasp's
    (pads swap: e_x up to sign), or None where the voxel holds no label."""
    rows = np.flatnonzero((scene["index"] == np.asarray(grasp.voxel_index)).all(axis=1))
    if not len(rows):
        return None
    e_x, e_z = grasp.pose[:3, 0], grasp.pose[:3, 2]
    angle = (np.arccos(np.clip(np.abs(scene["e_x"][rows] @ e_x), 0.0, 1.0))
             + np.arccos(np.clip(scene["e_z"][rows] @ e_z, -1.0, 1.0)))
    return float(scene["score"][rows[np.argmin(angle)]])


def told_ranking(mass_kg):
    """The top_picks ranking of a detector told the payload: "told_<m>kg"."""
    return f"told_{mass_kg:g}kg"


def told_mass_kg(ranking):
    """The payload [kg] a "told_<m>kg" ranking was told; None for detect's own rankings."""
    return float(ranking[len("told_"):-len("kg")]) if ranking.startswith("told_") else None


def pick_options(ranking, has_score, validness_threshold):
    """detect's options for a top_picks ranking: score or validness (detect's own),
    expected_score (ranked by the score's rules, keyed by validness x score: pick_grasps),
    or told_<m>kg: by validness among the grasps scored >= 1.5 x m g (the benchmark's
    ours_mass, a cell's stack.object_mass_kg)."""
    mass_kg = told_mass_kg(ranking)
    rank_by = "score" if ranking == "expected_score" else ranking if mass_kg is None else "validness"
    return DetectionOptions(max_grasps=max(TOP_K), has_score=has_score, validness_threshold=validness_threshold,
                            rank_by=rank_by, min_score_n=0.0 if mass_kg is None else payload_min_score_n(mass_kg))


def pick_grasps(model, grid, voxel_size_m, ranking, options):
    """detect's grasps of `grid` under a top_picks ranking (expected_score: validness x
    score ranks the candidates the score's rules keep)."""
    if ranking != "expected_score":
        return detect_grasps(model, grid, voxel_size_m, options=options)
    grid = torch.as_tensor(np.asarray(grid, dtype=np.float32))
    half, score_n, validness = network_outputs(model, grid, options.precision)
    return select_grasps(grid, score_n, validness, rotations_at(model, half), model.rotation_representation,
                         voxel_size_m, options=options, rank_key=score_n * validness)


@torch.inference_mode()
def top_picks(model, metadata, scene_files, voxel_size_m, rankings=None,
              validness_threshold=DetectionOptions().validness_threshold):
    """{ranking: {k: {label, negative, neither, holds_kg: {kg: picks}}}}: where detect's
    top-k grasps of each scene land, with the deployed options, and how many landed on a
    label whose f_g holds each of HOLDS_KG. A voxel that is neither may hold a grasp
    nobody simulated: "label" is a lower bound on picks that hold, "negative" an upper
    bound on none of them."""
    has_score = model_file.has_score(metadata)
    if rankings is None:
        rankings = (["score", "expected_score", "validness"] + [told_ranking(m) for m in HOLDS_KG] if has_score
                    else ["validness"])
    out = {r: {k: {"label": 0, "negative": 0, "neither": 0, "holds_kg": {str(m): 0 for m in HOLDS_KG}}
               for k in TOP_K} for r in rankings}
    for path in scene_files:
        scene = load_scene(path)
        negatives = {tuple(v) for v in scene["negative_index"].tolist()}
        for r in rankings:
            grasps = pick_grasps(model, scene["tsdf"], voxel_size_m, r, pick_options(r, has_score, validness_threshold))
            for k in TOP_K:
                for g in grasps[:k]:
                    f_g = label_score_at(scene, g)
                    where = "label" if f_g is not None else "negative" if tuple(g.voxel_index) in negatives else "neither"
                    out[r][k][where] += 1
                    for m in HOLDS_KG if f_g is not None else ():
                        out[r][k]["holds_kg"][str(m)] += int(f_g >= m * G_MPS2)
    return out


EQUAL_RECALLS = (0.8, 0.9, 0.95)  # where two models' validness is compared: precision at the same recall


def precision_at_recall(probability, labelled, recalls=EQUAL_RECALLS) -> dict:
    """{recall: precision} at the highest threshold whose recall reaches each of `recalls`:
    two models compared at their own thresholds differ in recall too, here they do not."""
    order = np.argsort(-np.asarray(probability), kind="stable")
    hits = np.cumsum(np.asarray(labelled, bool)[order])
    if not len(hits) or hits[-1] == 0:
        return {str(r): float("nan") for r in recalls}
    out = {}
    for r in recalls:
        k = int(np.searchsorted(hits, r * hits[-1] - 1e-9))  # first k with hits[k] >= r * positives
        out[str(r)] = float(hits[k] / (k + 1))
    return out


def validness_summary(probability, labelled, threshold=DetectionOptions().validness_threshold, bins=10):
    """Precision and recall at the deployed threshold, precision at equal recalls, AUROC,
    and the reliability diagram's bins (mean predicted probability, fraction labelled
    valid, voxels)."""
    above = probability >= threshold
    edges = np.linspace(0.0, 1.0, bins + 1)
    which = np.clip(np.digitize(probability, edges) - 1, 0, bins - 1)
    reliability = [{"from": float(edges[b]), "to": float(edges[b + 1]), "voxels": int((which == b).sum()),
                    "mean_predicted": float(probability[which == b].mean()) if (which == b).any() else float("nan"),
                    "fraction_valid": float(labelled[which == b].mean()) if (which == b).any() else float("nan")}
                   for b in range(bins)]
    return {"threshold": float(threshold), "voxels": int(len(probability)), "labelled_valid": int(labelled.sum()),
            "precision": float((above & labelled).sum() / max(above.sum(), 1)),
            "recall": float((above & labelled).sum() / max(labelled.sum(), 1)),
            "precision_at_recall": precision_at_recall(probability, labelled),
            "auroc": auroc(probability, labelled), "reliability": reliability}


def summarise(pairs):
    """Per mode and over all: n, MAE [N], Spearman, mean predicted and simulated [N]."""
    rows = dict(pairs)
    if "all" not in rows:
        rows["all"] = tuple(np.concatenate([v[i] for v in pairs.values()]) for i in (0, 1))
    out = {}
    for name, (pred, sim) in rows.items():
        rho = float(spearmanr(pred, sim).statistic) if len(pred) > 2 and np.ptp(sim) > 0 and np.ptp(pred) > 0 \
            else float("nan")
        out[name] = {"n": int(len(pred)), "mae_n": float(np.abs(pred - sim).mean()), "spearman": rho,
                     "mean_predicted_n": float(pred.mean()), "mean_simulated_n": float(sim.mean())}
    return out


def plot(pairs, summary, validness, path, title):
    """One panel per mode (predicted against simulated score, y = x), then the
    validness reliability diagram (fraction labelled valid per predicted-probability bin)."""
    # lazy: matplotlib takes seconds to import and only this figure needs it
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(pairs) + 1, figsize=(4.2 * (len(pairs) + 1), 4.2), squeeze=False)
    top = max(max(p.max(), s.max()) for p, s in pairs.values()) * 1.05
    for ax, (name, (pred, sim)) in zip(axes[0], sorted(pairs.items())):  # modes only, not "all"
        ax.scatter(sim, pred, s=4, alpha=0.3)
        ax.plot([0, top], [0, top], "k--", lw=1)
        row = summary[name]
        ax.set(xlim=(0, top), ylim=(0, top), xlabel="simulated score [N]", ylabel="predicted score [N]",
               title=f"{name}: n={row['n']}, MAE {row['mae_n']:.1f} N, rho {row['spearman']:.2f}")
    ax = axes[0][-1]
    bins = [b for b in validness["reliability"] if b["voxels"]]
    ax.plot([0, 1], [0, 1], "k--", lw=1)
    ax.plot([b["mean_predicted"] for b in bins], [b["fraction_valid"] for b in bins], "o-")
    for b in bins:
        ax.annotate(str(b["voxels"]), (b["mean_predicted"], b["fraction_valid"]), fontsize=6,
                    textcoords="offset points", xytext=(3, 3))
    ax.axvline(validness["threshold"], color="grey", lw=0.8)
    ax.set(xlim=(0, 1), ylim=(0, 1), xlabel="predicted validness", ylabel="fraction labelled valid",
           title=f"validness: P {validness['precision']:.3f} R {validness['recall']:.2f} AUROC {validness['auroc']:.3f}")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    save_figure(path, fig, dpi=110)
    plt.close(fig)


def main(argv=None):
    p = argparse.ArgumentParser(description="Predicted vs simulated gravity-rejection score, per grasp mode.")
    p.add_argument("--model", default="models/gravgrasp.pt")
    p.add_argument("--data", required=True, help="folder of scene files (searched recursively for *.npz)")
    p.add_argument("--split", choices=("val", "all"), default="val",
                   help="'val': the scenes the model's training split held out (default); 'all': every scene")
    p.add_argument("--out", default="out/calibration")
    p.add_argument("--validness-threshold", type=float, default=DetectionOptions().validness_threshold,
                   help="least validness of a grasp, as detect's parameter: for precision/recall and the top picks")
    args = p.parse_args(argv)
    if not 0.0 <= args.validness_threshold <= 1.0:
        print(f"calibration: --validness-threshold {args.validness_threshold} is outside [0, 1]", file=sys.stderr)
        return 2
    try:
        model, metadata = model_file.load_model(args.model)
    except model_file.ModelFileError as e:
        print(f"calibration: {e}", file=sys.stderr)
        return 2
    files = sorted(str(f) for f in pathlib.Path(args.data).rglob("*.npz"))
    if not files:
        print(f"calibration: no scene files (*.npz) under {args.data}: pass --data the folder that "
              "'datagen scenes' wrote", file=sys.stderr)
        return 2
    if args.split == "val":
        config = (metadata.get("training_data") or {}).get("config") or {}
        defaults = TrainConfig(data="", out="")
        files = split_scenes(files, config.get("validation_fraction", defaults.validation_fraction),
                             config.get("seed", defaults.seed))[1]
    try:
        pairs, (probability, labelled) = network_at_labels(model, files)
    except DataError as e:
        print(f"calibration: {e}", file=sys.stderr)
        return 2
    if not pairs:
        print(f"calibration: the {len(files)} scenes hold no labels", file=sys.stderr)
        return 1
    summary = summarise(pairs)
    validness = validness_summary(probability, labelled, args.validness_threshold)
    picks = top_picks(model, metadata, files, metadata["tsdf"]["voxel_size_m"],
                      validness_threshold=args.validness_threshold)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    title = f"{pathlib.Path(args.model).name} on {len(files)} {args.split} scenes of {args.data}"
    plot(pairs, summary, validness, out / "calibration.png", title)
    save_json(out / "calibration.json", {"model": str(args.model), "data": str(args.data), "split": args.split,
                                         "scenes": len(files), "modes": summary, "validness": validness,
                                         "top_picks": picks})
    for name, row in summary.items():
        print(f"{name}: n={row['n']} mae_n={row['mae_n']:.2f} spearman={row['spearman']:.3f} "
              f"mean_predicted_n={row['mean_predicted_n']:.1f} mean_simulated_n={row['mean_simulated_n']:.1f}")
    print(f"validness near surfaces: {validness['voxels']} voxels, {validness['labelled_valid']} labelled valid; "
          f"at {validness['threshold']:g}: precision={validness['precision']:.4f} recall={validness['recall']:.3f} "
          f"auroc={validness['auroc']:.4f}; precision at recall "
          + ", ".join(f"{r}: {v:.4f}" for r, v in validness["precision_at_recall"].items()))
    told = {told_mass_kg(r): by_k[1] for r, by_k in picks.items() if told_mass_kg(r) is not None}
    for r, by_k in picks.items():
        if told_mass_kg(r) is not None:
            continue
        n = {k: max(c["label"] + c["negative"] + c["neither"], 1) for k, c in by_k.items()}
        print(f"{r} ranking: " + "; ".join(
            f"top {k} on a label {c['label'] / n[k]:.2f}, on a negative {c['negative'] / n[k]:.2f} ({n[k]} picks)"
            for k, c in by_k.items()) + "; top 1 on a label holding " + ", ".join(
            f"{m} kg {held / n[1]:.2f}" for m, held in by_k[1]["holds_kg"].items()))
    if told:  # each its own weight: the top 1 of the detector told m, on a label holding m
        print("told the mass (by validness among grasps scored >= 1.5 x m g): top 1 on a label holding "
              + ", ".join(f"{m:g} kg {c['holds_kg'][str(m)] / len(files):.2f}" for m, c in told.items())
              + f" (of {len(files)} scenes)")
    print(f"score_mae_n={summary['all']['mae_n']:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
