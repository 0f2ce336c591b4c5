"""Benchmark: (a) TSDF grid -> ranked grasps (network + extraction), (b) one depth integration.

Real volumes come from the committed rendered tabletop bag (tests/data/tabletop_bag):
its four 640x480 frames fused one by one (4 volumes) and each frame alone (4 more).
Prints `name=value` lines; the last two are `detect_median_ms` and
`integrate_median_ms`. Also reports fp32 timings (for CPUs without bf16) and the
top-10 agreement of bf16 with fp32 rankings, which decides whether bf16 may be used.

    bench_detect [--model models/gravgrasp.pt] [--bag tests/data/tabletop_bag] [--runs 50]
                 [--threads 1] [--validness-threshold 0.5] [--free-space-mask off]
"""

import argparse
import os
import pathlib
import platform
import statistics
import sys
import time

import numpy as np
import open3d
import torch
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from ..perception import detection, model_file, networks
from ..perception.tsdf import CameraIntrinsics, TSDFVolume, depth_from_image_msg, depth_from_millimetres
from ..poses import matrix_from_pose

ROOT = pathlib.Path(os.environ.get("GRAVGRASP_ROOT", os.getcwd()))


def read_frames(bag):
    """[(depth float32 m, CameraIntrinsics, T_task_camera)] from a bag with depth, info, pose."""
    store = get_typestore(Stores.ROS2_JAZZY)
    frames, info, pose = [], None, None
    with Reader(bag) as reader:
        for connection, _, raw in reader.messages():
            msg = store.deserialize_cdr(raw, connection.msgtype)
            if connection.msgtype == "sensor_msgs/msg/CameraInfo":
                info = CameraIntrinsics.from_k(msg.k, msg.width, msg.height)
            elif connection.msgtype == "geometry_msgs/msg/PoseStamped":
                p, q = msg.pose.position, msg.pose.orientation
                pose = matrix_from_pose((p.x, p.y, p.z), (q.x, q.y, q.z, q.w))
            elif connection.msgtype == "sensor_msgs/msg/Image":
                depth = depth_from_image_msg(msg)
                if depth.dtype == np.uint16:
                    depth = depth_from_millimetres(depth)
                frames.append((depth, info, pose))
    if not frames:
        raise SystemExit(f"bench_detect: {bag} holds no depth images")
    return frames


def real_volumes(frames):
    grids = []
    fused = TSDFVolume()
    for depth, k, T in frames:
        fused.integrate(depth, k, T)
        grids.append(fused.grid())
        single = TSDFVolume()
        single.integrate(depth, k, T)
        grids.append(single.grid())
    return grids


def median_ms(fn, runs, warmup=5):
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return 1e3 * statistics.median(times)


def cpu_name():
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default=str(ROOT / "models" / "gravgrasp.pt"),
                        help="model file; if it does not exist, a freshly initialised network is timed")
    parser.add_argument("--bag", default=str(ROOT / "tests" / "data" / "tabletop_bag"))
    parser.add_argument("--runs", type=int, default=50)
    parser.add_argument("--max-grasps", type=int, default=20)
    parser.add_argument("--validness-threshold", type=float, default=0.5,
                        help="an untrained net predicts ~0.497 everywhere: 0.49 lets it return grasps")
    parser.add_argument("--threads", type=int, default=1,
                        help="torch intra-op threads (the detect node's torch_threads default is 1)")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    if args.runs < 50:
        parser.error("--runs must be at least 50")

    # Ranked as the detect node ranks this model: a binary model by validness (its score
    # head is untrained), a score model by its score.
    if os.path.exists(args.model):
        model, meta = model_file.load_model(args.model)
        model_note = f"{args.model} ({meta.get('training_data') or 'no training summary'})"
        ranking = {"rank_by": model_file.ranking(meta), "has_score": model_file.has_score(meta)}
    else:
        torch.manual_seed(0)
        model = networks.GraspNet().eval()
        model_note = f"UNTRAINED (seed 0; {args.model} does not exist): rankings are near-ties"
        ranking = {}
    frames = read_frames(args.bag)
    grids = real_volumes(frames)
    voxel_size = TSDFVolume().voxel_size_m

    print(f"machine={cpu_name()}, {os.cpu_count()} cores, torch threads {torch.get_num_threads()}, "
          f"bf16 native {detection.bf16_available()}, AMX {detection.bf16_faster()}, load average {os.getloadavg()[0]:.2f}")
    print(f"versions=python {platform.python_version()}, torch {torch.__version__}, open3d {open3d.__version__}")
    print(f"model={model_note}; validness threshold {args.validness_threshold}; "
          f"ranked by {ranking.get('rank_by', 'score')}")
    print(f"volumes={len(grids)} from {args.bag}")

    results = {}
    for precision in ("fp32", "bf16") if detection.bf16_available() else ("fp32",):
        cycle = iter(range(10**9))
        options = detection.DetectionOptions(validness_threshold=args.validness_threshold,
                                             max_grasps=args.max_grasps, precision=precision, **ranking)

        def detect():
            grid = grids[next(cycle) % len(grids)]
            return detection.detect_grasps(model, grid, voxel_size, options=options)

        results[f"detect_{precision}"] = median_ms(detect, args.runs)
        x = torch.from_numpy(grids[-2])[None, None]
        layout = detection._prepare(model, precision)
        x = x.contiguous(memory_format=layout)

        def network():  # what detect_grasps runs: backbone (bf16 or fp32), head in fp32
            with torch.inference_mode():
                with torch.autocast("cpu", dtype=torch.bfloat16, enabled=precision == "bf16"):
                    half = model.half_features(x)
                model.score_and_validness_from_half(half.float())

        results[f"network_{precision}"] = median_ms(network, args.runs)
        print(f"detect_{precision}_median_ms={results[f'detect_{precision}']:.2f}")
        print(f"network_{precision}_median_ms={results[f'network_{precision}']:.2f}")

    if "detect_bf16" in results:
        overlaps, near, found = [], [], []
        for grid in grids:
            top = {}
            for precision in ("fp32", "bf16"):
                options = detection.DetectionOptions(validness_threshold=args.validness_threshold,
                                                     max_grasps=10, precision=precision, **ranking)
                grasps = detection.detect_grasps(model, grid, voxel_size, options=options)
                top[precision] = [g.voxel_index for g in grasps]
            found.append(len(top["fp32"]))
            if not top["fp32"]:
                continue
            overlaps.append(len(set(top["fp32"]) & set(top["bf16"])) / len(top["fp32"]))
            # Same grasp up to one voxel (7.5 mm) of TCP position:
            near.append(sum(any(max(abs(np.subtract(a, b))) <= 1 for b in top["fp32"]) for a in top["bf16"])
                        / len(top["fp32"]))
        print(f"fp32_grasps_per_volume={found}")
        if overlaps:
            print(f"top10_overlap_bf16_vs_fp32_mean={np.mean(overlaps):.3f}")
            print(f"top10_overlap_bf16_vs_fp32_min={np.min(overlaps):.2f}")
            print(f"top10_within_1_voxel_bf16_vs_fp32_mean={np.mean(near):.3f}")
        else:
            print("top10_overlap_bf16_vs_fp32_mean=n/a (no grasp above the validness threshold in fp32)")

    volume = TSDFVolume()
    cycle = iter(range(10**9))
    metres = [(d, k, T) for d, k, T in frames]
    millimetres = [(np.round(d * 1000).astype(np.uint16), k, T) for d, k, T in frames]
    integrate_m = median_ms(lambda: volume.integrate(*metres[next(cycle) % len(metres)]), args.runs)
    integrate_mm = median_ms(lambda: volume.integrate(*millimetres[next(cycle) % len(millimetres)]), args.runs)
    grid_ms = median_ms(volume.grid, args.runs)
    print(f"integrate_16uc1_median_ms={integrate_mm:.2f}")
    print(f"grid_extraction_median_ms={grid_ms:.2f}")
    # What the detect node's default precision 'auto' runs here.
    default = f"detect_{detection.resolve_precision('auto')}"
    print(f"detect_median_ms={results[default]:.2f}")
    print(f"integrate_median_ms={integrate_m:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
