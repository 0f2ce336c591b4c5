"""Training of the grasp network on generated scenes (paper Sec. IV): the command.

    ros2 run gravgrasp_detector train --data DIR --out models/run [--epochs 20] ...

Variants (the paper's comparisons): --rotation ex-ez|ey-ez|quat, --target
gravity-score|binary (binary: VGN-style classifier, positive iff the grasp holds the
nominal weight; ranked by validness), --data-subset all|precision-only.

The data (scenes.py), the losses (losses.py) and the loop with its
resumable checkpoint (loop.py) take their options as one TrainConfig
(config.py).
"""
from __future__ import annotations

import argparse
import sys

from ..perception import rotation
from .config import TrainConfig
from .loop import train
from .scenes import DataError


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
    p.add_argument("--negative-weight", type=float, default=defaults.negative_weight,
                   help="validness loss weight of an explicit negative voxel (simulated failure or colliding pose)")
    p.add_argument("--unlabelled-weight", type=float, default=defaults.unlabelled_weight,
                   help="validness loss weight of a voxel with no label either way")
    p.add_argument("--positive-weight", type=float, default=defaults.positive_weight,
                   help="validness loss weight of a labelled voxel; 0: the summed negative weight / positives")
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
