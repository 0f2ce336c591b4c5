"""Benchmark: one training step (forward, losses, backward, Adam) on a batch of scenes,
the training forward (`GraspNet.forward_at`: rotation at the labels only, dec3 and
the heads on the half grid) against the dense forward it replaced.

The batch is synthetic but shaped like the v2/v3 scenes: a 40^3 volume per scene,
150 labels and 250 explicit negatives at random voxels (the cost does not depend on
what the volume shows). Prints `name=value` lines; the last is `train_step_s`, the
median seconds per step of the training forward.

    bench_train [--batch-size 8] [--steps 10] [--threads 2] [--rotation ex-ez]
"""

import argparse
import os
import platform
import statistics
import time

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from ..perception import networks
from ..training.config import TrainConfig
from ..training.losses import losses, training_outputs


def synthetic_batch(batch_size, rng, labels=150, negatives=250, resolution=40):
    """Examples as training.scenes.make_example returns them."""
    batch = []
    for _ in range(batch_size):
        flat = rng.choice(resolution ** 3, labels + negatives, replace=False)
        index = np.stack(np.unravel_index(flat, (resolution,) * 3), -1)
        R = Rotation.random(labels + negatives, random_state=rng).as_matrix()
        batch.append({
            "tsdf": torch.from_numpy(rng.uniform(0, 1, (1,) + (resolution,) * 3).astype(np.float32)),
            "index": torch.from_numpy(index),
            "score": torch.from_numpy(np.r_[rng.uniform(5, 80, labels), np.zeros(negatives)].astype(np.float32)),
            "valid": torch.from_numpy(np.r_[np.ones(labels), np.zeros(negatives)].astype(np.float32)),
            "R": torch.from_numpy(R.astype(np.float32)),
        })
    return batch


def time_steps(model, optimizer, forward, batch, config, steps):
    x = torch.stack([ex["tsdf"] for ex in batch])
    times = []
    for _ in range(steps + 1):  # the first step warms oneDNN's primitive cache
        t0 = time.perf_counter()
        terms = losses(model, forward(x), batch, config)
        optimizer.zero_grad(set_to_none=True)
        terms["total"].backward()
        optimizer.step()
        times.append(time.perf_counter() - t0)
    return statistics.median(times[1:])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--rotation", default="ex-ez")
    args = parser.parse_args(argv)
    torch.manual_seed(0)
    torch.set_num_threads(args.threads)
    config = TrainConfig(data="", out="", negative_weight=250.0)
    batch = synthetic_batch(args.batch_size, np.random.default_rng(0))
    model = networks.GraspNet(args.rotation, score_scale_n=30.0)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-4)
    dense = time_steps(model, optimizer, model, batch, config, args.steps)
    fast = time_steps(model, optimizer, lambda x: training_outputs(model, x, batch), batch, config, args.steps)
    print(f"machine={platform.processor() or platform.machine()} cores={os.cpu_count()} threads={args.threads} "
          f"batch={args.batch_size} torch={torch.__version__}")
    print(f"train_step_dense_s={dense:.3f}")
    print(f"speedup={dense / fast:.1f}")
    print(f"train_step_s={fast:.3f}")


if __name__ == "__main__":
    main()
