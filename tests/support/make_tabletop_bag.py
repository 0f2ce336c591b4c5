"""Test-data tool: write tests/data/tabletop_bag, a small rosbag2 (MCAP) of a rendered tabletop.

The scene is the paper's Sec. VI-A one: a 65 x 200 mm cylinder and a 100 x 80 x 100 mm
box standing on a table whose top is 5 cm above the task origin, in the 0.30 m
workspace cube. Four 640x480 depth frames from around the table (two 16UC1 mm, two
32FC1 m, so both REP-118 encodings are replayed), each with its CameraInfo and the
camera optical frame's pose in `task` (PoseStamped), messages zstd-compressed.

    source ros_ws/env.sh && python tests/support/make_tabletop_bag.py [OUT_DIR]
"""

import pathlib
import shutil
import sys

import numpy as np
import trimesh
from geometry_msgs.msg import PoseStamped
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import CameraInfo, Image

from gravgrasp_detector.perception.tsdf import CameraIntrinsics
from gravgrasp_detector.ros.bag_replay import msgtype_name, typestore_for
from sim_bridge.physics.depth_rendering import DepthRenderer, look_at

OUT = pathlib.Path(__file__).resolve().parents[1] / "data" / "tabletop_bag"
TOPIC_DEPTH = "/camera/depth/image"
TOPIC_INFO = "/camera/depth/camera_info"
TOPIC_POSE = "/camera/pose"
FRAME_TASK = "task"
FRAME_CAMERA = "camera_depth_optical_frame"
TABLE_Z = 0.05
INTRINSICS = CameraIntrinsics(640, 480, fx=540.0, fy=540.0, cx=319.5, cy=239.5)
# (azimuth deg, elevation deg, distance m) of each view, looking at the scene centre.
VIEWS = [(0, 55, 0.55), (100, 65, 0.5), (200, 45, 0.6), (290, 70, 0.5)]
T0_NS = 1_700_000_000_000_000_000
PERIOD_NS = 200_000_000


def scene():
    table = trimesh.creation.box(extents=(0.8, 0.8, 0.04))
    table.apply_translation((0.15, 0.15, TABLE_Z - 0.02))
    cylinder = trimesh.creation.cylinder(radius=0.0325, height=0.2, sections=64)
    cylinder.apply_translation((0.15 - 0.0325, 0.15, TABLE_Z + 0.1))
    box = trimesh.creation.box(extents=(0.10, 0.08, 0.10))
    box.apply_translation((0.15 + 0.06, 0.15, TABLE_Z + 0.05))
    return [table, cylinder, box]


def view_pose(azimuth_deg, elevation_deg, distance_m):
    target = np.array([0.15, 0.15, TABLE_Z + 0.05])
    a, e = np.radians(azimuth_deg), np.radians(elevation_deg)
    eye = target + distance_m * np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    return look_at(eye, target)


def stamp(ns):
    from builtin_interfaces.msg import Time

    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def messages():
    renderer = DepthRenderer(scene())
    k = INTRINSICS
    for n, view in enumerate(VIEWS):
        t_ns = T0_NS + n * PERIOD_NS
        T = view_pose(*view)
        depth = renderer.render(k, T)
        image = Image(height=k.height, width=k.width, is_bigendian=0)
        image.header.stamp, image.header.frame_id = stamp(t_ns), FRAME_CAMERA
        if n % 2 == 0:
            image.encoding, image.step = "16UC1", 2 * k.width
            image.data = np.round(depth * 1000.0).astype("<u2").tobytes()
        else:
            image.encoding, image.step = "32FC1", 4 * k.width
            image.data = depth.astype("<f4").tobytes()
        info = CameraInfo(height=k.height, width=k.width, distortion_model="plumb_bob")
        info.header = image.header
        info.k = [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0]
        info.p = [k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0]
        info.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        info.d = [0.0] * 5
        pose = PoseStamped()
        pose.header.stamp, pose.header.frame_id = stamp(t_ns), FRAME_TASK
        pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = (float(v) for v in T[:3, 3])
        q = Rotation.from_matrix(T[:3, :3]).as_quat()
        (pose.pose.orientation.x, pose.pose.orientation.y, pose.pose.orientation.z,
         pose.pose.orientation.w) = (float(v) for v in q)
        # Pose and CameraInfo first, as a camera driver + robot state would have them.
        yield TOPIC_POSE, pose, t_ns
        yield TOPIC_INFO, info, t_ns
        yield TOPIC_DEPTH, image, t_ns


def write(out=OUT):
    out = pathlib.Path(out)
    if out.exists():
        shutil.rmtree(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    msgs = list(messages())
    store = typestore_for({msgtype_name(m) for _, m, _ in msgs})
    writer = Writer(out, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.set_compression(CompressionMode.MESSAGE, CompressionFormat.ZSTD)
    with writer:
        connections = {}
        for topic, msg, t_ns in msgs:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype_name(msg), typestore=store)
            writer.write(connections[topic], t_ns, serialize_message(msg))
    size = sum(f.stat().st_size for f in out.iterdir())
    print(f"wrote {out} ({len(msgs)} messages, {size / 1e6:.2f} MB)")
    return out


if __name__ == "__main__":
    write(sys.argv[1] if len(sys.argv) > 1 else OUT)
