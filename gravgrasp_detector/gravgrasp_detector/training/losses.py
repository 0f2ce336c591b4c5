"""The losses of the paper and the validation metrics.

Losses:
- score: L2 on the gravity-rejection score [N] at valid voxels only;
- validness: cross-entropy over all voxels, weighted per voxel: explicit negatives
  (simulated failures and colliding poses in the scene) by `negative_weight`, voxels
  with no label either way by `unlabelled_weight`, positives by `positive_weight` or,
  by default, the ratio of the summed negative weight to the positives (labels are a
  few hundred voxels in 64k; v1 weighed every unlabelled voxel 1 and had no explicit
  negatives);
- rotation: at valid voxels, squared Frobenius distance between the rebuilt R (Eq. 2
  for ex-ez) and the label, taking the min over the 2F-85's 180 deg twin.
Metrics: the rotation's angular error and the validness AUROC.
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from scipy.stats import rankdata

from ..perception import rotation
from .config import TrainConfig


def stacked(batch, key, device):
    """One field of every example of a batch, concatenated, on `device`."""
    return torch.cat([ex[key] for ex in batch]).to(device)


def listed_voxels(batch, device):
    """The (batch, i, j, k) index tensors of every example's listed voxels (labels, then
    explicit negatives) and a mask of the positives (validness target 1) among them."""
    b_idx = torch.cat([torch.full((len(ex["index"]),), n) for n, ex in enumerate(batch)]).to(device)
    ijk = stacked(batch, "index", device).long()
    return (b_idx, ijk[:, 0], ijk[:, 1], ijk[:, 2]), stacked(batch, "valid", device) > 0.5


def training_outputs(model, x, batch):
    """model.forward_at for a batch: the rotation only at its positives."""
    at, pos = listed_voxels(batch, x.device)
    return model.forward_at(x, tuple(a[pos] for a in at))


def losses(model, outputs, batch, config: TrainConfig):
    """-> dict of the three loss terms and their weighted total, for a batch (examples on
    the CPU, outputs wherever the model runs): of `model(x)` (dense rotation) or of
    `training_outputs` (rotation at the positives only)."""
    device = outputs["validness_logit"].device
    at, pos = listed_voxels(batch, device)
    target_valid = stacked(batch, "valid", device)
    loss_valid = validness_loss(outputs["validness_logit"], at, target_valid, config)
    zero = outputs["score_n"].sum() * 0.0
    if config.target == "binary" or not pos.any():
        loss_score = zero
    else:
        target_score = stacked(batch, "score", device)
        loss_score = F.mse_loss(outputs["score_n"][at][pos], target_score[pos]) / model.score_scale_n ** 2
    if not pos.any():
        loss_rot = zero
    else:
        channels = (outputs["rotation_at"] if "rotation_at" in outputs
                    else outputs["rotation"].permute(0, 2, 3, 4, 1)[at][pos]).float()
        loss_rot = rotation_loss(model.rotation_representation, channels, stacked(batch, "R", device)[pos])
    total = (config.loss_weight_score * loss_score + config.loss_weight_validness * loss_valid
             + config.loss_weight_rotation * loss_rot)
    return {"total": total, "score": loss_score, "validness": loss_valid, "rotation": loss_rot}


def validness_loss(logits, at, target_valid, config: TrainConfig):
    """Weighted cross-entropy over all voxels (module docstring). `at`: the (batch, i, j,
    k) indices of the listed voxels, positives (target 1) and negatives (target 0)."""
    valid_dense = torch.zeros_like(logits)
    valid_dense[at] = target_valid
    weight = torch.full_like(logits, config.unlabelled_weight)
    weight[at] = config.negative_weight
    positive = valid_dense > 0.5
    n_positive = positive.sum().clamp_min(1)
    if config.positive_weight > 0:
        pos_weight = torch.tensor(config.positive_weight, device=logits.device)
    else:
        pos_weight = (weight[~positive].sum() / n_positive).clamp(1.0, 1000.0)
    weight = torch.where(positive, pos_weight.to(weight.dtype), weight)
    # the mean over voxels, as v1's pos_weight form: same loss at the default weights
    return F.binary_cross_entropy_with_logits(logits, valid_dense, weight=weight, reduction="mean")


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
    """Area under the ROC curve (rank statistic, tied scores share their mean rank, so a
    constant score gives 0.5); nan without both classes."""
    scores, labels = np.asarray(scores, float), np.asarray(labels, bool)
    n_pos, n_neg = labels.sum(), (~labels).sum()
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    ranks = rankdata(scores)
    return float((ranks[labels].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))
