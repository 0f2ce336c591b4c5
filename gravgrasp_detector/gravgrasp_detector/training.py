"""Training of the grasp network on generated scenes (paper Sec. IV).

    ros2 run gravgrasp_detector train --data DIR --out models/run [--epochs 20] ...

Data: scene files (`*.npz`) written by sim_bridge's data generation, each holding the
fused TSDF grid and sparse voxel labels (see `load_scene`). Scenes are split into
train/validation by scene, with a split that depends only on the file names and the
seed, so adding scenes does not reshuffle the validation set.

Losses, per the paper:
- score: L2 on the gravity-rejection score [N] at valid voxels only;
- validness: cross-entropy over all voxels, positives weighted by the negative/
  positive ratio (labels are a few hundred voxels in 64k);
- rotation: at valid voxels, squared Frobenius distance between the rebuilt R (Eq. 2
  for ex-ez) and the label, taking the min over the 2F-85's 180 deg twin.

Variants (the paper's comparisons): --rotation ex-ez|ey-ez|quat, --target
gravity-score|binary (binary: VGN-style classifier, positive iff the grasp holds the
nominal weight; ranked by validness), --data all|precision-only.

Runs resume: `checkpoint.pt` in the output directory is written atomically after
every epoch (model, optimiser, epoch, history, RNG state) and picked up on the next
run with the same output directory.
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
import os
import pathlib
import platform
import sys
import time

import numpy as np
import torch
import torch.nn.functional as F

from . import atomic_files, model_file, networks, rotation, tsdf

G_MPS2 = 9.81
# Mode names as sim_bridge.datagen.object_grasps writes them; scene files carry their own
# `mode_names`, which win.
DEFAULT_MODE_NAMES = ("power", "precision", "none")


@dataclasses.dataclass
class TrainConfig:
    data: str
    out: str
    epochs: int = 20
    batch_size: int = 8
    learning_rate: float = 3e-4
    rotation: str = "ex-ez"
    target: str = "gravity-score"          # or "binary"
    subset: str = "all"                    # or "precision-only"
    nominal_mass_kg: float = 0.5           # binary target: holds this weight x g
    validation_fraction: float = 0.1
    seed: int = 0
    threads: int = 2
    bf16: bool = False                     # CPU bf16 autocast (AMX); fp32 otherwise
    max_scenes: int = 0                    # 0 = all
    loss_weight_score: float = 1.0
    loss_weight_validness: float = 1.0
    loss_weight_rotation: float = 1.0


class DataError(RuntimeError):
    """Training data that cannot be used; the message says why and what to do."""


# --- data -------------------------------------------------------------------------

def load_scene(path):
    """A scene file -> dict(tsdf (R,R,R) float32, index (K,3) int64, score (K,),
    e_x (K,3), e_z (K,3), mode (K,) or None)."""
    try:
        with np.load(path) as z:
            scene = {
                "tsdf": z["tsdf"].astype(np.float32),
                "index": z["label_index"].astype(np.int64).reshape(-1, 3),
                "score": z["label_score"].astype(np.float32).reshape(-1),
                "e_x": z["label_e_x"].astype(np.float32).reshape(-1, 3),
                "e_z": z["label_e_z"].astype(np.float32).reshape(-1, 3),
                "mode": z["label_mode"].astype(np.int64).reshape(-1) if "label_mode" in z else None,
                "mode_names": [str(n) for n in z["mode_names"]] if "mode_names" in z else DEFAULT_MODE_NAMES,
            }
    except (OSError, KeyError, ValueError) as err:
        raise DataError(f"scene file {path} is unreadable or lacks tsdf/label_* arrays ({err}); "
                        "regenerate it with 'ros2 run sim_bridge datagen scenes'") from None
    return scene


def select_labels(scene, config: TrainConfig):
    """Apply the --data subset and --target to a scene's labels -> (index, score,
    valid_target, e_x, e_z)."""
    keep = np.ones(len(scene["score"]), bool)
    if config.subset == "precision-only":
        if scene["mode"] is None:
            raise DataError("--data precision-only needs label_mode in the scene files; "
                            "regenerate scenes with a datagen that records grasp modes")
        keep &= scene["mode"] == list(scene["mode_names"]).index("precision")
    index, score = scene["index"][keep], scene["score"][keep]
    valid = np.ones(len(score), np.float32)
    if config.target == "binary":
        valid = (score >= config.nominal_mass_kg * G_MPS2).astype(np.float32)
    return index, score, valid, scene["e_x"][keep], scene["e_z"][keep]


def split_scenes(files, validation_fraction, seed):
    """Deterministic split by scene: a file is in validation iff a hash of its name
    and the seed falls below the fraction."""
    train, val = [], []
    for f in files:
        h = int(hashlib.sha256(f"{seed}:{pathlib.Path(f).name}".encode()).hexdigest()[:8], 16)
        (val if h / 2**32 < validation_fraction else train).append(f)
    if not val and len(train) > 1:
        val.append(train.pop())
    return train, val


def rotate_about_gravity(grid, index, e_x, e_z, quarter_turns):
    """Rotate the volume and its labels by quarter_turns x 90 deg about the task z axis
    through the volume centre (exact on the voxel grid)."""
    k = quarter_turns % 4
    if k == 0:
        return grid, index, e_x, e_z
    r = grid.shape[0]
    grid = np.rot90(grid, k, axes=(0, 1)).copy()
    c, s = [1, 0, -1, 0][k], [0, 1, 0, -1][k]
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], np.float32)
    i, j = index[:, 0], index[:, 1]
    for _ in range(k):  # one 90 deg turn: (i, j) -> (r-1-j, i), matching np.rot90
        i, j = r - 1 - j, i
    index = np.stack([i, j, index[:, 2]], 1)
    return grid, index, e_x @ Rz.T, e_z @ Rz.T


def shift(grid, index, offset):
    """Translate volume and labels by an integer voxel offset (x, y only: the table
    stays at its height); voxels shifted in are unobserved (0), labels leaving drop."""
    r = grid.shape[0]
    out = np.zeros_like(grid)
    dx, dy = offset
    src = (slice(max(0, -dx), r - max(0, dx)), slice(max(0, -dy), r - max(0, dy)))
    dst = (slice(max(0, dx), r - max(0, -dx)), slice(max(0, dy), r - max(0, -dy)))
    out[dst] = grid[src]
    moved = index + np.array([dx, dy, 0])
    inside = ((moved >= 0) & (moved < r)).all(1)
    return out, moved, inside


def make_example(scene, config, rng=None):
    """One training example as dense tensors; augmented when rng is given."""
    index, score, valid, e_x, e_z = select_labels(scene, config)
    grid = scene["tsdf"]
    keep = np.ones(len(score), bool)
    if rng is not None:
        grid, index, e_x, e_z = rotate_about_gravity(grid, index, e_x, e_z, int(rng.integers(4)))
        grid, index, keep = shift(grid, index, rng.integers(-2, 3, size=2))
    index, score, valid, e_x, e_z = index[keep], score[keep], valid[keep], e_x[keep], e_z[keep]
    return {
        "tsdf": torch.from_numpy(np.ascontiguousarray(grid))[None],
        "index": torch.from_numpy(index),
        "score": torch.from_numpy(score),
        "valid": torch.from_numpy(valid),
        "R": torch.from_numpy(np.stack([e_x, np.cross(e_z, e_x), e_z], -1).astype(np.float32)),
    }


# --- losses and metrics --------------------------------------------------------------

def losses(model, outputs, batch, config):
    """-> dict of the three loss terms and their weighted total, for a batch."""
    b_idx = torch.cat([torch.full((len(ex["index"]),), n) for n, ex in enumerate(batch)])
    ijk = torch.cat([ex["index"] for ex in batch]).long()
    target_valid = torch.cat([ex["valid"] for ex in batch])
    valid_dense = torch.zeros_like(outputs["validness_logit"])
    valid_dense[b_idx, ijk[:, 0], ijk[:, 1], ijk[:, 2]] = target_valid
    positives = valid_dense.sum().clamp_min(1.0)
    pos_weight = ((valid_dense.numel() - positives) / positives).clamp(1.0, 1000.0)
    loss_valid = F.binary_cross_entropy_with_logits(
        outputs["validness_logit"], valid_dense, pos_weight=pos_weight)

    at = (b_idx, ijk[:, 0], ijk[:, 1], ijk[:, 2])
    pos = target_valid > 0.5
    zero = outputs["score_n"].sum() * 0.0
    if config.target == "binary" or not pos.any():
        loss_score = zero
    else:
        target_score = torch.cat([ex["score"] for ex in batch])
        loss_score = F.mse_loss(outputs["score_n"][at][pos], target_score[pos]) / model.score_scale_n ** 2
    if not pos.any():
        loss_rot = zero
    else:
        channels = outputs["rotation"].permute(0, 2, 3, 4, 1)[at][pos].float()
        loss_rot = rotation_loss(model.rotation_representation, channels, torch.cat([ex["R"] for ex in batch])[pos])
    total = (config.loss_weight_score * loss_score + config.loss_weight_validness * loss_valid
             + config.loss_weight_rotation * loss_rot)
    return {"total": total, "score": loss_score, "validness": loss_valid, "rotation": loss_rot}


def rotation_loss(representation, channels, R_target):
    """Mean over grasps of min(|R - R_t|_F^2, |R - twin(R_t)|_F^2)."""
    R = rotation.reconstruct(representation, channels)
    d = ((R - R_target) ** 2).sum((-1, -2))
    d_twin = ((R - rotation.symmetric_twin(R_target)) ** 2).sum((-1, -2))
    return torch.minimum(d, d_twin).mean()


def angular_error_deg(R, R_target):
    """Geodesic angle between R and the nearer of R_target and its 180 deg twin."""
    def angle(a, b):
        cos = (((a.transpose(-1, -2) @ b).diagonal(dim1=-2, dim2=-1).sum(-1)) - 1) / 2
        return torch.rad2deg(torch.arccos(cos.clamp(-1, 1)))
    return torch.minimum(angle(R, R_target), angle(R, rotation.symmetric_twin(R_target)))


def auroc(scores, labels):
    """Area under the ROC curve (rank statistic); nan without both classes."""
    scores, labels = np.asarray(scores, float), np.asarray(labels, bool)
    n_pos, n_neg = labels.sum(), (~labels).sum()
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    order = np.argsort(scores, kind="mergesort")
    ranks = np.empty(len(scores))
    ranks[order] = np.arange(1, len(scores) + 1)
    return float((ranks[labels].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


@torch.no_grad()
def evaluate(model, scenes, config, device):
    """Validation metrics over whole scenes (no augmentation)."""
    model.eval()
    logits, labels, abs_err, ang = [], [], [], []
    loss_sum = {"total": 0.0, "score": 0.0, "validness": 0.0, "rotation": 0.0}
    for scene in scenes:
        ex = make_example(scene, config)
        out = model(ex["tsdf"][None].to(device))
        for k, v in losses(model, out, [ex], config).items():
            loss_sum[k] += float(v) / max(len(scenes), 1)
        valid_dense = torch.zeros(out["validness_logit"].shape[1:])
        idx = ex["index"]
        valid_dense[idx[:, 0], idx[:, 1], idx[:, 2]] = ex["valid"]
        logits.append(out["validness_logit"][0].flatten().cpu())
        labels.append(valid_dense.flatten() > 0.5)
        pos = ex["valid"] > 0.5
        if pos.any():
            i, j, k = idx[pos].T
            abs_err.append((out["score_n"][0, i, j, k].cpu() - ex["score"][pos]).abs())
            ch = out["rotation"][0].permute(1, 2, 3, 0)[i, j, k].float().cpu()
            ang.append(angular_error_deg(rotation.reconstruct(model.rotation_representation, ch), ex["R"][pos]))
    logits, labels = torch.cat(logits).numpy(), torch.cat(labels).numpy()
    predicted = logits > 0.0
    tp = float((predicted & labels).sum())
    metrics = {f"loss_{k}": v for k, v in loss_sum.items()}
    metrics.update({
        "validness_precision": tp / max(predicted.sum(), 1),
        "validness_recall": tp / max(labels.sum(), 1),
        "validness_auroc": auroc(logits, labels),
        "score_mae_n": float(torch.cat(abs_err).mean()) if abs_err else float("nan"),
        "rotation_error_deg": float(torch.cat(ang).mean()) if ang else float("nan"),
    })
    model.train()
    return metrics


# --- the loop --------------------------------------------------------------------------

def train(config: TrainConfig, progress=True, argv=None):
    """Train (or resume) and write model.pt, checkpoint.pt, history.json and
    training_curve.png into config.out. Returns the final validation metrics."""
    from tqdm import tqdm

    torch.manual_seed(config.seed)
    torch.set_num_threads(config.threads)
    torch.use_deterministic_algorithms(True, warn_only=True)
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    out = pathlib.Path(config.out)
    out.mkdir(parents=True, exist_ok=True)

    files = sorted(str(p) for p in pathlib.Path(config.data).rglob("*.npz"))
    if config.max_scenes:
        files = files[:config.max_scenes]
    if len(files) < 2:
        raise DataError(f"found {len(files)} scene files (*.npz) under {config.data}; generate "
                        "scenes first: ros2 run sim_bridge datagen scenes ...")
    train_files, val_files = split_scenes(files, config.validation_fraction, config.seed)
    train_scenes = [load_scene(f) for f in train_files]
    val_scenes = [load_scene(f) for f in val_files]
    resolution = train_scenes[0]["tsdf"].shape[0]
    all_scores = np.concatenate([select_labels(s, config)[1] for s in train_scenes])
    if len(all_scores) == 0:
        raise DataError(f"no labels left in {config.data} with --data {config.subset}")
    # Softplus output times this scale starts the score head near the data's range.
    score_scale_n = float(max(np.median(all_scores), 1.0))

    model = networks.GraspNet(config.rotation, score_scale_n=score_scale_n, resolution=resolution).to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.learning_rate)
    history, start_epoch = [], 0
    checkpoint_path = out / "checkpoint.pt"
    if checkpoint_path.exists():
        ckpt = torch.load(checkpoint_path, map_location=device, weights_only=False)
        if ckpt["config"] != dataclasses.asdict(config) | {"epochs": ckpt["config"]["epochs"]}:
            raise DataError(f"{checkpoint_path} was written with different options; use a new "
                            "--out directory or delete the checkpoint to start over")
        model.load_state_dict(ckpt["model"])
        optimizer.load_state_dict(ckpt["optimizer"])
        history, start_epoch = ckpt["history"], ckpt["epoch"]
        torch.set_rng_state(ckpt["torch_rng"])
        print(f"resuming {out} at epoch {start_epoch}", flush=True)

    model.train()
    t0 = time.monotonic() - (history[-1]["wall_s"] if history else 0.0)  # wall time survives a resume
    for epoch in range(start_epoch, config.epochs):
        rng = np.random.default_rng([config.seed, epoch])  # same batches whatever resumed
        order = rng.permutation(len(train_scenes))
        batches = [order[i:i + config.batch_size] for i in range(0, len(order), config.batch_size)]
        sums = {"total": 0.0, "score": 0.0, "validness": 0.0, "rotation": 0.0}
        bar = tqdm(batches, desc=f"epoch {epoch + 1}/{config.epochs}", disable=not progress, leave=False)
        for batch_ids in bar:
            batch = [make_example(train_scenes[i], config, rng) for i in batch_ids]
            x = torch.stack([ex["tsdf"] for ex in batch]).to(device)
            with torch.autocast(device.type, dtype=torch.bfloat16, enabled=config.bf16):
                outputs = model(x)
            terms = losses(model, outputs, batch, config)
            optimizer.zero_grad(set_to_none=True)
            terms["total"].backward()
            optimizer.step()
            for k in sums:
                sums[k] += float(terms[k].detach()) / len(batches)
            bar.set_postfix(loss=f"{float(terms['total'].detach()):.3f}")
        metrics = evaluate(model, val_scenes, config, device)
        record = {"epoch": epoch + 1, "wall_s": round(time.monotonic() - t0, 1),
                  **{f"train_{k}": v for k, v in sums.items()}, **{f"val_{k}": v for k, v in metrics.items()}}
        history.append(record)
        print(json.dumps(record), flush=True)
        atomic_files.save_torch(checkpoint_path, {
            "config": dataclasses.asdict(config), "model": model.state_dict(), "optimizer": optimizer.state_dict(),
            "epoch": epoch + 1, "history": history, "torch_rng": torch.get_rng_state()})

    argv = list(sys.argv[1:] if argv is None else argv)
    summary = {
        # relative to the working directory (the project), as model files store paths
        "data": os.path.relpath(os.path.abspath(config.data)), "scenes_train": len(train_scenes),
        "scenes_val": len(val_scenes),
        "labels_train": int(len(all_scores)), "target": config.target, "subset": config.subset,
        "nominal_mass_kg": config.nominal_mass_kg, "epochs": config.epochs, "seed": config.seed,
        "validation": history[-1] if history else {},
        "command": "ros2 run gravgrasp_detector train " + " ".join(argv),
        "argv": argv,
        "config": dataclasses.asdict(config),
        "train_wall_s": history[-1]["wall_s"] if history else 0.0,
        "machine": {"cpu": _cpu_model(), "cores": os.cpu_count(), "torch_threads": config.threads,
                    "device": device.type, "bf16": config.bf16},
    }
    # Model files load with weights_only=True: plain JSON types only, no numpy scalars.
    summary = json.loads(json.dumps(summary, default=float))
    # Scenes are fused with tsdf.TSDFVolume's defaults (0.30 m, 4-voxel truncation).
    model_file.save_model(out / "model.pt", model.cpu(), tsdf.TSDFVolume(resolution=resolution),
                          training_data=summary)
    (out / "history.json").write_text(json.dumps(history, indent=1))
    plot_history(history, out / "training_curve.png")
    return history[-1] if history else {}


def _cpu_model() -> str:
    try:
        for line in pathlib.Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def plot_history(history, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not history:
        return
    epochs = [h["epoch"] for h in history]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    for key in ("score", "validness", "rotation"):
        axes[0].plot(epochs, [h[f"train_{key}"] for h in history], label=f"train {key}")
        axes[0].plot(epochs, [h[f"val_loss_{key}"] for h in history], "--", label=f"val {key}")
    axes[0].set_yscale("log"); axes[0].set_title("losses"); axes[0].legend(fontsize=7)
    axes[1].plot(epochs, [h["val_score_mae_n"] for h in history], label="score MAE [N]")
    axes[1].plot(epochs, [h["val_rotation_error_deg"] for h in history], label="rotation error [deg]")
    axes[1].set_title("validation errors"); axes[1].legend(fontsize=7)
    for key in ("precision", "recall", "auroc"):
        axes[2].plot(epochs, [h[f"val_validness_{key}"] for h in history], label=key)
    axes[2].set_ylim(0, 1); axes[2].set_title("validness"); axes[2].legend(fontsize=7)
    for ax in axes:
        ax.set_xlabel("epoch")
    fig.tight_layout()
    atomic_files.save_figure(path, fig, dpi=90)
    plt.close(fig)


def main(argv=None) -> int:
    defaults = TrainConfig(data="", out="")
    p = argparse.ArgumentParser(description="Train the gravity-aware grasp network on generated scenes.")
    p.add_argument("--data", required=True, help="directory of scene files (*.npz, searched recursively)")
    p.add_argument("--out", required=True, help="output directory (resumes from its checkpoint.pt)")
    p.add_argument("--epochs", type=int, default=defaults.epochs)
    p.add_argument("--batch-size", type=int, default=defaults.batch_size)
    p.add_argument("--learning-rate", type=float, default=defaults.learning_rate)
    p.add_argument("--rotation", choices=sorted(rotation.CHANNELS), default=defaults.rotation)
    p.add_argument("--target", choices=["gravity-score", "binary"], default=defaults.target)
    p.add_argument("--data-subset", dest="subset", choices=["all", "precision-only"], default=defaults.subset,
                   help="'precision-only' keeps grasps whose settled mode is precision (Ours-Precision)")
    p.add_argument("--nominal-mass-kg", type=float, default=defaults.nominal_mass_kg,
                   help="binary target: a grasp is positive iff its score >= this x 9.81 N")
    p.add_argument("--validation-fraction", type=float, default=defaults.validation_fraction)
    p.add_argument("--seed", type=int, default=defaults.seed)
    p.add_argument("--threads", type=int, default=defaults.threads)
    p.add_argument("--bf16", action="store_true", help="bf16 autocast on CPU (AMX); ~3x faster here")
    p.add_argument("--max-scenes", type=int, default=0)
    p.add_argument("--no-progress", action="store_true")
    argv = list(sys.argv[1:] if argv is None else argv)
    args = vars(p.parse_args(argv))
    progress = not args.pop("no_progress")
    try:
        metrics = train(TrainConfig(**args), progress=progress, argv=argv)
    except DataError as err:
        print(f"train: {err}", file=sys.stderr)
        return 2
    for key in ("val_score_mae_n", "val_rotation_error_deg", "val_validness_auroc"):
        if key in metrics:
            print(f"{key}={metrics[key]:.4g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
