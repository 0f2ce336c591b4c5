"""The options of a training run (`ros2 run gravgrasp_detector train`): what the data,
the losses and the loop read, what a checkpoint must match to resume, and what the model
file records (its metadata's `training_data.config`)."""
from __future__ import annotations

import dataclasses


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
    # Validness cross-entropy, per voxel: explicit negatives (the scene's negative_index:
    # simulated failures, colliding poses) weigh `negative_weight`, voxels with no label
    # either way `unlabelled_weight`, positives `positive_weight`, or with 0 the balance:
    # the summed negative weight over the positives (<= 1000). Defaults = v1's loss.
    negative_weight: float = 1.0
    unlabelled_weight: float = 1.0
    positive_weight: float = 0.0
