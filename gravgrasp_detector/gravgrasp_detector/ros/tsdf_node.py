"""ROS 2 node `tsdf`: fuses depth images into the workspace TSDF and publishes it.

Subscribes (sensor-data QoS, the depth image with a queue of 1 so the newest frame is
fused next and a busy node drops the older ones; overridable with the standard
qos_overrides parameters, e.g.
qos_overrides./camera/depth/image.subscription.reliability:=reliable; names are
relative, remap them to the camera):
  depth/image        sensor_msgs/Image, 16UC1 (mm) or 32FC1 (m), REP-118
  depth/camera_info  sensor_msgs/CameraInfo of that image
  camera_pose        geometry_msgs/PoseStamped, pose of the camera optical frame in the
                     task frame (only with camera_pose_source:=topic); each image is
                     fused with the pose closest to its stamp (within
                     pose_time_tolerance_s); images wait up to sync_timeout_s for
                     their CameraInfo and pose.
Publishes:
  tsdf               gravgrasp_msgs/TSDFVolume (reliable, transient local, depth 1) as
                     soon as a frame is fused, at most publish_rate_hz (a volume the
                     limit holds back goes out within half a period of when it allows).
Services:
  ~/reset            std_srvs/Trigger: forget all fused frames.
  ~/set_integrating  std_srvs/SetBool: pause (false) or resume (true) fusing.
Bad input is logged once per cause with what to fix; the node keeps running.
"""

import array
import collections
import sys
import time

from gravgrasp_msgs.msg import TSDFVolume as TSDFVolumeMsg
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import CameraInfo, Image
from std_srvs.srv import SetBool, Trigger

from ..perception.tsdf import (CameraIntrinsics, InputError, TSDFVolume, check_camera_pose, depth_from_image_msg,
                               to_network_grid)
from ..poses import PoseError
from ..problem_log import ProblemLog
from .interface import described, float_range, int_range, matrix_from_pose_msg, run_node, stamp_s

VOLUME_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Sensor-data QoS with a queue of 1: a frame that waited while the node fused another is
# stale when a newer one exists (with the usual 5, a busy node fused frames ~130 ms old).
DEPTH_QOS = QoSProfile(depth=1, reliability=qos_profile_sensor_data.reliability,
                       durability=qos_profile_sensor_data.durability)


def camera_pose_from_msg(pose):
    """geometry_msgs/Pose of the camera -> T_task_camera; raises InputError."""
    try:
        return matrix_from_pose_msg(pose)
    except PoseError as e:
        raise InputError("camera_pose_quaternion", f"camera pose {e}: publish a finite pose with a unit quaternion") from None


class TSDFNode(Node):
    def __init__(self):
        super().__init__("tsdf")
        p = self.declare_parameter
        size_m = p("size_m", 0.30, float_range("Edge of the workspace cube, m (the model's)", 0.05, 5.0, read_only=True)).value
        resolution = p("resolution", 40, int_range("Voxels per edge (the model's)", 8, 256, step=8, read_only=True)).value
        truncation_voxels = p("truncation_voxels", 4.0, float_range("TSDF truncation distance, voxels", 1.0, 20.0, read_only=True)).value
        self.frame_id = p("frame_id", "task", described(
            "Gravity-aligned task frame: the volume's header.frame_id; its corner is at this frame's origin",
            read_only=True)).value
        rate = p("publish_rate_hz", 5.0, float_range("Most volumes published per second", 0.1, 100.0, read_only=True)).value
        self.pose_source = p("camera_pose_source", "topic", described(
            "'topic': camera pose from the camera_pose PoseStamped topic; "
            "'parameter': fixed camera_pose (static extrinsic)", read_only=True)).value
        static_pose = p("camera_pose", [0.0] * 7, described(
            "Static pose of the camera optical frame in the task frame: "
            "[x, y, z (m), qx, qy, qz, qw]; used with camera_pose_source:=parameter", read_only=True)).value
        self.max_camera_distance_m = p("max_camera_distance_m", 3.0, float_range(
            "Camera farther than this from the workspace centre is a pose error, m", 0.1, 20.0, read_only=True)).value
        max_depth_m = p("max_depth_m", 3.0, float_range("Depth returns beyond this are ignored, m", 0.1, 20.0, read_only=True)).value
        self.pose_tolerance_s = p("pose_time_tolerance_s", 0.05, float_range(
            "Largest |pose stamp - image stamp| accepted with camera_pose_source:=topic, s", 0.0, 10.0, read_only=True)).value
        self.sync_timeout_s = p("sync_timeout_s", 1.0, float_range(
            "How long an image waits for its CameraInfo and pose, s", 0.05, 30.0, read_only=True)).value
        # Topic names as parameters too, so one cell parameter file can point the node at
        # the camera (a params file cannot remap); -r remapping works as before.
        topic = lambda name, default, text: p(name, default, described(text, read_only=True)).value  # noqa: E731
        self.depth_topic = topic("depth_image_topic", "depth/image", "depth image topic (16UC1 or 32FC1)")
        self.info_topic = topic("camera_info_topic", "depth/camera_info", "CameraInfo of that depth image")
        self.pose_topic = topic("camera_pose_topic", "camera_pose", "camera pose topic (camera_pose_source:=topic)")

        self.problems = ProblemLog(self.get_logger().error, self.get_logger().info)
        self.volume = TSDFVolume(size_m, resolution, truncation_voxels, max_depth_m)
        self.integrating = True
        self.camera_info = None
        self.poses = collections.deque(maxlen=200)  # (stamp_s, T_task_camera)
        # (received monotonic s, header, depth) waiting for CameraInfo/pose; bounded so a
        # missing CameraInfo cannot pile up images (the oldest is dropped first).
        self.pending = collections.deque(maxlen=30)
        self.dirty = False
        self.min_publish_interval_s = 1.0 / rate
        self.last_publish_s = -float("inf")
        self.last_stamp = None
        self.static_T = None
        self.frames_received = self.frames_fused = self.volumes_published = 0
        # Inputs default to sensor-data QoS (best effort, as camera drivers publish);
        # qos_overrides.<topic>.subscription.reliability:=reliable for reliable sources.
        overridable = QoSOverridingOptions.with_default_policies()
        if self.pose_source == "parameter":
            self.static_T = self._static_pose(static_pose)
        elif self.pose_source != "topic":
            raise InputError("config", f"camera_pose_source is {self.pose_source!r}: use 'topic' or 'parameter'")
        else:
            self.create_subscription(PoseStamped, self.pose_topic, self._on_pose, qos_profile_sensor_data,
                                     qos_overriding_options=overridable)

        self.create_subscription(Image, self.depth_topic, self._on_depth, DEPTH_QOS,
                                 qos_overriding_options=overridable)
        self.create_subscription(CameraInfo, self.info_topic, self._on_camera_info, qos_profile_sensor_data,
                                 qos_overriding_options=overridable)
        self.publisher = self.create_publisher(TSDFVolumeMsg, "tsdf", VOLUME_QOS)
        self.create_service(Trigger, "~/reset", self._on_reset)
        self.create_service(SetBool, "~/set_integrating", self._on_set_integrating)
        self.create_timer(0.5 / rate, self._publish_if_due)  # what the rate limit held back
        self.create_timer(0.1, self._expire_pending)
        self.create_timer(10.0, self._log_counts)
        self.get_logger().info(
            f"TSDF {resolution}^3 over {size_m} m in '{self.frame_id}', camera pose from {self.pose_source}; "
            f"depth on {self.resolve_topic_name(self.depth_topic)}")

    def _static_pose(self, values):
        if len(values) != 7:
            raise InputError("config", f"camera_pose has {len(values)} values: give [x, y, z, qx, qy, qz, qw]")
        msg = PoseStamped()
        (msg.pose.position.x, msg.pose.position.y, msg.pose.position.z,
         msg.pose.orientation.x, msg.pose.orientation.y, msg.pose.orientation.z, msg.pose.orientation.w) = values
        try:
            T = camera_pose_from_msg(msg.pose)
            check_camera_pose(T, self.volume.size_m, self.max_camera_distance_m)
        except InputError as e:
            raise InputError("config", f"camera_pose parameter: {e}") from None
        return T

    # -- inputs ----------------------------------------------------------------------

    def _on_camera_info(self, msg):
        try:
            intrinsics = CameraIntrinsics.from_k(msg.k, msg.width, msg.height)
            intrinsics.check()
        except InputError as e:
            self.problems.report(e.cause, f"{e} (CameraInfo on {self.resolve_topic_name(self.info_topic)})")
            return
        self.problems.clear("camera_info_k", "camera_info_size", "no_camera_info")
        self.camera_info = intrinsics
        self._integrate_pending()

    def _on_pose(self, msg):
        if msg.header.frame_id and msg.header.frame_id != self.frame_id:
            self.problems.report(
                "pose_frame",
                f"camera pose is in frame '{msg.header.frame_id}', expected '{self.frame_id}': "
                "publish the optical frame's pose in the task frame (or set frame_id)")
            return
        try:
            T = camera_pose_from_msg(msg.pose)
        except InputError as e:
            self.problems.report(e.cause, str(e))
            return
        self.problems.clear("pose_frame")
        self.poses.append((stamp_s(msg.header.stamp), T))
        self._integrate_pending()

    def _on_depth(self, msg):
        if not self.integrating:
            return
        try:
            depth = depth_from_image_msg(msg)
        except InputError as e:
            self.problems.report(e.cause, str(e))
            return
        except (ValueError, TypeError) as e:  # e.g. absurd width/step values
            self.problems.report("malformed_image", f"depth image cannot be decoded ({e}): the publisher fills the message wrongly")
            return
        self.problems.clear("encoding", "malformed_image")
        self.get_logger().debug(f"depth {stamp_s(msg.header.stamp):.3f} received, {len(self.pending)} pending")
        self.frames_received += 1
        self.pending.append((time.monotonic(), msg.header, depth))
        self._integrate_pending()

    def _pose_for(self, stamp_s):
        """-> T, or None to wait; raises InputError when no pose will ever match."""
        if self.static_T is not None:
            return self.static_T
        if not self.poses:
            return None
        t, T = min(self.poses, key=lambda tp: abs(tp[0] - stamp_s))
        if abs(t - stamp_s) <= self.pose_tolerance_s:
            return T
        newest = self.poses[-1][0]
        if newest > stamp_s + self.pose_tolerance_s:
            raise InputError(
                "pose_sync",
                f"no camera pose within {self.pose_tolerance_s} s of a depth image (closest is "
                f"{t - stamp_s:+.3f} s away): stamp poses like the images or raise pose_time_tolerance_s")
        return None

    def _integrate_pending(self):
        self._fuse_pending()
        self._publish_if_due()  # at once: waiting for a timer tick added up to 1/rate of latency

    def _fuse_pending(self):
        while self.pending and self.camera_info is not None:
            _, header, depth = self.pending[0]
            try:
                T = self._pose_for(stamp_s(header.stamp))
                if T is None:
                    return  # wait for the pose
                self.pending.popleft()
                check_camera_pose(T, self.volume.size_m, self.max_camera_distance_m)
                self.volume.integrate(depth, self.camera_info, T)
            except InputError as e:
                if self.pending and self.pending[0][2] is depth:
                    self.pending.popleft()
                self.problems.report(e.cause, str(e))
                continue
            except Exception as e:  # keep running: one unexpected frame must not stop the node
                if self.pending and self.pending[0][2] is depth:
                    self.pending.popleft()
                self.problems.report(type(e).__name__, f"could not fuse a depth image: {type(e).__name__}: {e}")
                continue
            self.problems.clear()  # a fused frame: every input is fine again
            self.frames_fused += 1
            self.dirty = True
            self.last_stamp = header.stamp
            self.get_logger().debug(f"depth {stamp_s(header.stamp):.3f} fused ({self.volume.frames_integrated} frames)")

    def _expire_pending(self):
        now = time.monotonic()
        while self.pending and now - self.pending[0][0] > self.sync_timeout_s:
            self.pending.popleft()
            if self.camera_info is None:
                self.problems.report(
                    "no_camera_info",
                    f"no CameraInfo received on {self.resolve_topic_name(self.info_topic)} within "
                    f"{self.sync_timeout_s} s of a depth image: remap depth/camera_info to the camera's "
                    "camera_info topic")
            else:
                self.problems.report(
                    "no_pose",
                    f"no camera pose on {self.resolve_topic_name(self.pose_topic)} for a depth image within "
                    f"{self.sync_timeout_s} s: publish the camera optical frame's pose (PoseStamped) or "
                    "use camera_pose_source:=parameter with a static camera_pose")

    # -- output and services -------------------------------------------------------

    def _publish_if_due(self):
        if self.dirty and time.monotonic() - self.last_publish_s >= self.min_publish_interval_s:
            self._publish()

    def _publish(self):
        if not self.dirty:
            return
        self.dirty = False
        self.last_publish_s = time.monotonic()
        tsdf, weights = self.volume.tsdf_and_weights()
        msg = TSDFVolumeMsg()
        msg.header.frame_id = self.frame_id
        msg.header.stamp = self.last_stamp
        msg.origin.orientation.w = 1.0  # corner at the task origin
        msg.voxel_size_m = self.volume.voxel_size_m
        msg.resolution = self.volume.resolution
        msg.truncation_m = self.volume.truncation_m
        msg.tsdf = array.array("f", to_network_grid(tsdf, weights).tobytes())
        msg.weights = array.array("f", weights.tobytes())
        self.publisher.publish(msg)
        self.volumes_published += 1

    def _log_counts(self):
        """Every 10 s while frames arrive: how many were fused and published (the rest
        waited too long for CameraInfo/pose or were bad; see the other log lines)."""
        if self.frames_received != getattr(self, "_logged_received", 0):
            self._logged_received = self.frames_received
            self.get_logger().info(f"frames: {self.frames_received} received, {self.frames_fused} fused; "
                                   f"{self.volumes_published} volumes published")

    def _on_reset(self, request, response):
        self.volume.reset()
        self.pending.clear()
        self.dirty = False
        response.success = True
        response.message = "TSDF reset"
        self.get_logger().info("TSDF reset")
        return response

    def _on_set_integrating(self, request, response):
        self.integrating = bool(request.data)
        response.success = True
        response.message = "integrating" if self.integrating else "paused"
        self.get_logger().info(f"integration {response.message}")
        return response


def main(args=None):
    return run_node("tsdf", TSDFNode, InputError, args=args)


if __name__ == "__main__":
    sys.exit(main())
