"""ROS 2 node `detect`: TSDF volume -> ranked gravity-rejection grasps.

Subscribes  tsdf           gravgrasp_msgs/TSDFVolume (reliable, transient local, depth 1)
Publishes   grasps         gravgrasp_msgs/GraspArray, sorted by score (highest first; a model
                           trained with --target binary: by validness, score NaN)
            grasp_markers  visualization_msgs/MarkerArray, gripper outlines by rank key
                           (built only while something subscribes, e.g. RViz)
Only the newest volume is processed: a volume arriving while the network runs
replaces any waiting one, so no queue grows when input outpaces detection.
Bad volumes are logged once per cause with what to fix; the node keeps running.
A model file that is missing, corrupt or inconsistent stops the node at startup
with one line and exit code 2.
"""

import os
import statistics
import sys
import threading
import time

import numpy as np
import torch
from builtin_interfaces.msg import Duration
from gravgrasp_msgs.msg import Grasp as GraspMsg
from gravgrasp_msgs.msg import GraspArray
from gravgrasp_msgs.msg import TSDFVolume as TSDFVolumeMsg
from rclpy.node import Node
from visualization_msgs.msg import MarkerArray

from ..perception import detection, model_file
from ..perception.model_file import ModelFileError
from ..perception.tsdf import TSDF_CONVENTION, InputError
from ..poses import PoseError
from ..problem_log import ProblemLog
from .interface import described, float_range, int_range, matrix_from_pose_msg, pose_msg_from_matrix, run_node
from .markers import grasp_markers
from .tsdf_node import VOLUME_QOS

DEFAULT_MODEL = "models/gravgrasp.pt"


def resolve_model_path(path):
    """Relative paths are relative to $GRAVGRASP_ROOT (set by ros_ws/env.sh), else the cwd."""
    if os.path.isabs(path):
        return path
    return os.path.join(os.environ.get("GRAVGRASP_ROOT", os.getcwd()), path)


def volume_grid(msg, metadata):
    """TSDFVolume message -> (grid (R, R, R) float32, T_task_grid). Raises InputError."""
    try:
        model_file.check_volume(metadata, msg.resolution, msg.voxel_size_m, msg.truncation_m, TSDF_CONVENTION)
    except ModelFileError as e:
        raise InputError("volume_geometry", str(e)) from None
    n = int(msg.resolution) ** 3
    if len(msg.tsdf) != n or len(msg.weights) != n:
        raise InputError(
            "volume_size",
            f"TSDF volume has {len(msg.tsdf)} values and {len(msg.weights)} weights for resolution "
            f"{msg.resolution} (need {n} each): the publisher fills the message wrongly")
    weights = np.asarray(msg.weights, dtype=np.float32)
    if not weights.any():
        raise InputError(
            "empty_tsdf",
            "TSDF volume is empty (no voxel ever observed): the tsdf node has not fused a depth "
            "image yet; check its log for depth, CameraInfo or camera pose problems")
    grid = np.asarray(msg.tsdf, dtype=np.float32).reshape((int(msg.resolution),) * 3)
    try:
        T = matrix_from_pose_msg(msg.origin)
    except PoseError as e:
        raise InputError("volume_origin", f"TSDF origin: {e}") from None
    return grid, T


def startup_lines(model_path, metadata, precision, threads):
    """What the node tells a user at start-up: one short line per fact (the model's
    whole training summary is in its card, models/<name>.md)."""
    root = os.environ.get("GRAVGRASP_ROOT", os.getcwd())
    shown = os.path.relpath(model_path, root) if model_path.startswith(root.rstrip("/") + "/") else model_path
    net, grid, td = metadata["network"], metadata["tsdf"], metadata.get("training_data") or {}
    lines = [f"model: {shown}",
             f"model input: {grid['resolution']}^3 TSDF, {grid['voxel_size_m'] * 1e3:g} mm voxels",
             f"model output: {model_file.training_target(metadata)}, rotation {net['rotation_representation']}"]
    if not model_file.has_score(metadata):
        lines.append("grasps ranked by validness (a binary model: no score in N, it publishes NaN)")
    if "scenes_train" in td:
        lines.append(f"model trained: {td['scenes_train']} + {td.get('scenes_val', 0)} scenes"
                     + (f" from {td['data']}" if td.get("data") else "")
                     + (f", {td['epochs']} epochs" if "epochs" in td else "")
                     + (f", {metadata['created_utc'][:10]}" if metadata.get("created_utc") else ""))
    elif td.get("note"):
        lines.append(f"model note: {td['note']}")
    lines.append(f"precision: {precision}, {threads} torch thread{'s' if threads != 1 else ''}")
    return lines


class DetectNode(Node):
    def __init__(self):
        super().__init__("detect")
        p = self.declare_parameter
        model_path = p("model_path", DEFAULT_MODEL, described(
            "Model file (.pt with metadata); relative to $GRAVGRASP_ROOT or the working directory",
            read_only=True)).value
        p("validness_threshold", 0.5, float_range("Least predicted validness of a returned grasp", 0.0, 1.0))
        p("min_score_n", 0.0, float_range(
            "Least gravity-rejection score of a returned grasp, N (e.g. object weight x g x safety factor)",
            0.0, 10000.0))
        p("max_grasps", 20, int_range("Most grasps per volume", 1, 1000))
        p("surface_distance_voxels", 6, int_range("Candidates lie within this many voxels of an observed surface", 1, 40))
        p("nms_radius_voxels", 2, int_range("Non-maximum suppression radius, voxels (0 = off)", 0, 10))
        p("pregrasp_distance_m", 0.05, float_range("Stand-off along -z of the TCP for the pre-grasp pose, m", 0.0, 0.5))
        threads = p("torch_threads", 1, int_range(
            "Intra-op threads of the network. 1 by default: on a small CPU shared with the tsdf "
            "node, OpenMP threads waiting on a busy core made detection up to 10x slower", 1, 64,
            read_only=True)).value
        torch.set_num_threads(threads)
        # 'auto': bf16 where the CPU has AMX (2x faster there; with AVX-512 BF16 alone it
        # was slower than fp32), else fp32. With the shipped model bench_detect measured
        # 98 % top-10 agreement with fp32 (8 volumes of tests/data/tabletop_bag); re-check
        # it for any other model.
        precision = p("precision", "auto", described(
            "Network arithmetic: 'fp32', 'bf16' (autocast, needs AVX-512 BF16/AMX to be fast; "
                        "check bench_detect's bf16-vs-fp32 top-10 agreement for your model first), "
                        "or 'auto' (bf16 where the CPU has AMX, where it is faster than fp32)", read_only=True)).value

        self.model_path = resolve_model_path(model_path)
        self.model, self.metadata = model_file.load_model(self.model_path)  # ModelFileError -> main
        try:
            self.precision = detection.resolve_precision(precision)
        except ValueError as e:
            raise ModelFileError(f"precision parameter: {e}") from None
        self.model_name = os.path.basename(self.model_path)
        # A binary model (trained with --target binary) is ranked by its validness, a
        # success probability; its score head is untrained, so its grasps carry
        # gravity_rejection_score NaN (no newtons), never a probability in its place.
        self.rank_by = model_file.ranking(self.metadata)
        self.has_score = model_file.has_score(self.metadata)
        self.problems = ProblemLog(self.get_logger().error, self.get_logger().info)
        self.grasps_pub = self.create_publisher(GraspArray, "grasps", 10)
        self.markers_pub = self.create_publisher(MarkerArray, "grasp_markers", 10)
        self.create_subscription(TSDFVolumeMsg, "tsdf", self._on_volume, VOLUME_QOS)

        self._latest = None
        self._wakeup = threading.Condition()
        self._stop = False
        self.dropped = 0
        self.processed = 0
        self.latencies_ms = []
        self._last_latency_log = -float("inf")
        self._worker = threading.Thread(target=self._run, name="detect", daemon=True)
        self._worker.start()
        for line in startup_lines(self.model_path, self.metadata, self.precision, threads):
            self.get_logger().info(line)

    def _on_volume(self, msg):
        with self._wakeup:
            if self._latest is not None:
                self.dropped += 1  # superseded before the worker got to it
            self._latest = (msg, time.monotonic())
            self._wakeup.notify()

    def _run(self):
        while True:
            with self._wakeup:
                while self._latest is None and not self._stop:
                    self._wakeup.wait()
                if self._stop:
                    return
                (msg, received), self._latest = self._latest, None
            try:
                self._detect(msg, received)
            except InputError as e:
                self.problems.report(e.cause, str(e))
            except Exception as e:  # keep answering: one unexpected volume must not kill the node
                self.problems.report(type(e).__name__, f"detection failed on a volume: {type(e).__name__}: {e}")

    def _detect(self, msg, received):
        grid, T_task_grid = volume_grid(msg, self.metadata)
        param = lambda name: self.get_parameter(name).value  # noqa: E731  (live, settable)
        options = detection.DetectionOptions(
            validness_threshold=param("validness_threshold"),
            min_score_n=param("min_score_n"),
            max_grasps=param("max_grasps"),
            surface_distance_voxels=param("surface_distance_voxels"),
            nms_radius_voxels=param("nms_radius_voxels"),
            precision=self.precision,
            rank_by=self.rank_by,
            has_score=self.has_score,
        )
        grasps = detection.detect_grasps(self.model, grid, msg.voxel_size_m, T_task_grid, options)
        self.problems.clear()
        latency_s = time.monotonic() - received
        out = GraspArray(header=msg.header, model_name=self.model_name)
        out.detection_latency = Duration(sec=int(latency_s), nanosec=int((latency_s % 1) * 1e9))
        pregrasp = float(param("pregrasp_distance_m"))
        out.grasps = [
            GraspMsg(pose=pose_msg_from_matrix(g.pose), validness=g.validness,
                     gravity_rejection_score=g.score_n,  # NaN: a binary model's grasps
                     voxel_index=list(g.voxel_index), pregrasp_distance_m=pregrasp)
            for g in grasps
        ]
        self.grasps_pub.publish(out)
        if self.markers_pub.get_subscription_count():  # ~4 ms of CPU per volume, for a viewer only
            self.markers_pub.publish(grasp_markers(grasps, msg.header))
        self.processed += 1
        self.latencies_ms = (self.latencies_ms + [latency_s * 1e3])[-50:]
        now = time.monotonic()
        if now - self._last_latency_log >= 5.0:  # the first one, then every 5 s
            self._last_latency_log = now
            best = "" if not grasps else (f", best {grasps[0].score_n:.2f} N" if self.rank_by == "score"
                                          else f", best validness {grasps[0].validness:.2f}"
                                          + (f" ({grasps[0].score_n:.2f} N)" if self.has_score else ""))
            self.get_logger().info(
                f"{len(grasps)} grasps{best}; latency {latency_s * 1e3:.1f} ms "
                f"(median {statistics.median(self.latencies_ms):.1f} ms of last {len(self.latencies_ms)}); "
                f"{self.processed} volumes processed, {self.dropped} superseded")

    def destroy_node(self):
        with self._wakeup:
            self._stop = True
            self._wakeup.notify()
        self._worker.join(timeout=5.0)
        super().destroy_node()


def main(args=None):
    return run_node("detect", DetectNode, ModelFileError, args=args)


if __name__ == "__main__":
    sys.exit(main())
