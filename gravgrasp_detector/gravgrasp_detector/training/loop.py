"""The training loop: epochs over the training scenes, validation after each, an atomic
`checkpoint.pt` (model, optimiser, epoch, history, RNG state) that a rerun with the same
output directory resumes from, and at the end `model.pt` (with the data summary and the
command), `history.json` and `training_curve.png`."""
from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import platform
import sys
import time

import numpy as np
import torch
from tqdm import tqdm

from .. import atomic_files
from ..perception import model_file, networks, rotation, tsdf
from .config import TrainConfig
from .losses import angular_error_deg, auroc, losses, training_outputs
from .scenes import DataError, load_scene, make_example, select_labels, split_scenes


@torch.no_grad()
def evaluate(model, scenes, config, device):
    """Validation metrics over whole scenes (no augmentation)."""
    model.eval()
    logits, labels, listed, abs_err, ang = [], [], [], [], []
    loss_sum = {"total": 0.0, "score": 0.0, "validness": 0.0, "rotation": 0.0}
    for scene in scenes:
        ex = make_example(scene, config)
        out = training_outputs(model, ex["tsdf"][None].to(device), [ex])  # rotation at the positives
        for k, v in losses(model, out, [ex], config).items():
            loss_sum[k] += float(v) / max(len(scenes), 1)
        valid_dense = torch.zeros(out["validness_logit"].shape[1:])
        idx = ex["index"]
        valid_dense[idx[:, 0], idx[:, 1], idx[:, 2]] = ex["valid"]
        logits.append(out["validness_logit"][0].flatten().cpu())
        labels.append(valid_dense.flatten() > 0.5)
        listed_dense = torch.zeros_like(valid_dense, dtype=torch.bool)
        listed_dense[idx[:, 0], idx[:, 1], idx[:, 2]] = True
        listed.append(listed_dense.flatten())
        pos = ex["valid"] > 0.5
        if pos.any():
            i, j, k = idx[pos].T
            abs_err.append((out["score_n"][0, i, j, k].cpu() - ex["score"][pos]).abs())
            ch = out["rotation_at"].float().cpu()
            ang.append(angular_error_deg(rotation.reconstruct(model.rotation_representation, ch), ex["R"][pos]))
    logits, labels, listed = torch.cat(logits).numpy(), torch.cat(labels).numpy(), torch.cat(listed).numpy()
    predicted = logits > 0.0
    tp = float((predicted & labels).sum())
    negatives = listed & ~labels
    metrics = {f"loss_{k}": v for k, v in loss_sum.items()}
    metrics.update({
        "validness_precision": tp / max(predicted.sum(), 1),
        "validness_recall": tp / max(labels.sum(), 1),
        "validness_auroc": auroc(logits, labels),
        # Among voxels whose answer is known (a label, or an explicit negative: a failure or
        # a colliding pose), unlike the precision above, which counts every unlabelled voxel
        # predicted valid as wrong.
        "validness_precision_known": (tp / max(float((predicted & listed).sum()), 1.0)
                                      if negatives.any() else float("nan")),
        "validness_negatives_rejected": (float((~predicted[negatives]).mean())
                                         if negatives.any() else float("nan")),
        "score_mae_n": float(torch.cat(abs_err).mean()) if abs_err else float("nan"),
        "rotation_error_deg": float(torch.cat(ang).mean()) if ang else float("nan"),
    })
    model.train()
    return metrics


def train(config: TrainConfig, progress=True, argv=None):
    """Train (or resume) and write model.pt, checkpoint.pt, history.json and
    training_curve.png into config.out. Returns the final validation metrics."""
    torch.manual_seed(config.seed)
    torch.set_num_threads(config.threads)
    torch.use_deterministic_algorithms(True, warn_only=True)
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    out = pathlib.Path(config.out)
    out.mkdir(parents=True, exist_ok=True)
    checkpoint_path, model_path = out / "checkpoint.pt", out / "model.pt"
    finished = _finished_history(checkpoint_path, model_path, config, device)
    if finished is not None:
        # Writing model.pt again would change its bytes (created_utc), so its sha256, which
        # the benchmark's rounds record: every finished round of the model would run again.
        print(f"{out} is trained to epoch {config.epochs} already: keeping {model_path} "
              "(delete it to write it again)", flush=True)
        return finished[-1] if finished else {}

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
    if checkpoint_path.exists():
        ckpt = _checkpoint(checkpoint_path, config, device)
        model.load_state_dict(ckpt["model"])
        optimizer.load_state_dict(ckpt["optimizer"])
        history, start_epoch = ckpt["history"], ckpt["epoch"]
        torch.set_rng_state(ckpt["torch_rng"].cpu())  # map_location moved it to the device
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
                outputs = training_outputs(model, x, batch)
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
        "labels_train": int(len(all_scores)),
        "negatives_train": int(sum(len(s["negative_index"]) for s in train_scenes)),
        "target": config.target, "subset": config.subset,
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
    # Scenes are fused with tsdf.TSDFVolume's defaults (tsdf.SIZE_M, tsdf.TRUNCATION_VOXELS).
    model_file.save_model(out / "model.pt", model.cpu(), tsdf.volume_metadata(resolution=resolution),
                          training_data=summary)
    atomic_files.save_json(out / "history.json", history)
    plot_history(history, out / "training_curve.png")
    return history[-1] if history else {}


def _checkpoint(path, config: TrainConfig, device):
    """The checkpoint at `path`; DataError if it was written with other options."""
    ckpt = torch.load(path, map_location=device, weights_only=False)
    # options added since a checkpoint was written count at their defaults
    written = dataclasses.asdict(TrainConfig(data=config.data, out=config.out)) | ckpt["config"]
    if written != dataclasses.asdict(config) | {"epochs": ckpt["config"]["epochs"]}:
        raise DataError(f"{path} was written with different options; use a new "
                        "--out directory or delete the checkpoint to start over")
    return ckpt


def _finished_history(checkpoint_path, model_path, config: TrainConfig, device):
    """The history of a run already trained to config.epochs whose model.pt was written
    from its last checkpoint (not older than it), else None."""
    if not (checkpoint_path.exists() and model_path.exists()
            and model_path.stat().st_mtime >= checkpoint_path.stat().st_mtime):
        return None
    ckpt = _checkpoint(checkpoint_path, config, device)
    return ckpt["history"] if ckpt["epoch"] >= config.epochs else None


def _cpu_model() -> str:
    try:
        for line in pathlib.Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def plot_history(history, path):
    # lazy: matplotlib (seconds), with the Agg backend chosen before pyplot loads
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
