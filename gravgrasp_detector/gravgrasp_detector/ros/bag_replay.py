"""Write rosbag2 files from rclpy messages and replay them through rclpy.

`ros2 bag` (rosbag2) is not published on PyPI, so this module does the two things the
stack needs from it with the pure-Python `rosbags` library: record messages into a
rosbag2 directory (MCAP or sqlite3), and play a bag back onto live topics in order.
Raw CDR bytes go straight from the bag to `rclpy.serialization`, so what is replayed
is byte-for-byte what was recorded.

    ros2 run gravgrasp_detector bag_play BAG_DIR [--rate 1.0] [--topics /a /b]
"""
from __future__ import annotations

import argparse
import importlib
import pathlib
import sys
import time
from typing import Iterable, Iterator

import rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, DurabilityPolicy, HistoryPolicy
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.rosbag2 import Reader, ReaderError, Writer
from rosbags.rosbag2.enums import StoragePlugin
from rosbags.typesys import Stores, get_typestore, get_types_from_msg
from ament_index_python.packages import get_package_share_directory, PackageNotFoundError

# Bags are replayed reliably with depth large enough that a subscriber that keeps up
# loses nothing; live sensor topics use sensor-data QoS, which accepts this publisher.
REPLAY_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=100,
    reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)


def message_class(msgtype: str):
    """'sensor_msgs/msg/Image' -> the rclpy message class."""
    try:
        package, kind, name = msgtype.split("/")
        return getattr(importlib.import_module(f"{package}.{kind}"), name)
    except (ValueError, ImportError, AttributeError) as err:
        raise LookupError(
            f"message type {msgtype!r} is not importable ({err}); source ros_ws/env.sh "
            "or build the package that defines it") from err


def msgtype_name(msg) -> str:
    """rclpy message instance -> 'pkg/msg/Name'."""
    module = type(msg).__module__.split(".")
    return f"{module[0]}/{module[1]}/{type(msg).__name__}"


def typestore_for(msgtypes: Iterable[str]):
    """A Jazzy typestore that also knows the packages of any non-standard type in
    `msgtypes` (e.g. gravgrasp_msgs), read from their installed .msg files."""
    store = get_typestore(Stores.ROS2_JAZZY)
    for package in sorted({t.split("/")[0] for t in msgtypes if t not in store.fielddefs}):
        try:
            share = pathlib.Path(get_package_share_directory(package))
        except PackageNotFoundError as err:
            raise LookupError(f"message package {package!r} is not installed; build it "
                              "and source ros_ws/env.sh") from err
        types = {}
        for msg_file in sorted((share / "msg").glob("*.msg")):
            types.update(get_types_from_msg(msg_file.read_text(), f"{package}/msg/{msg_file.stem}"))
        store.register(types)
    return store


def write_bag(path: str | pathlib.Path, messages: Iterable[tuple[str, object, int]],
              storage: str = "mcap") -> pathlib.Path:
    """Record (topic, rclpy message, timestamp_ns) tuples into a new rosbag2 directory."""
    messages = list(messages)
    plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
    store = typestore_for({msgtype_name(m) for _, m, _ in messages})
    path = pathlib.Path(path)
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        connections = {}
        for topic, msg, stamp_ns in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype_name(msg), typestore=store)
            writer.write(connections[topic], stamp_ns, serialize_message(msg))
    return path


def read_bag(path: str | pathlib.Path, topics: Iterable[str] = ()) -> Iterator[tuple[str, object, int]]:
    """Yield (topic, rclpy message, timestamp_ns) in recorded order."""
    wanted = set(topics)
    with Reader(pathlib.Path(path)) as reader:
        connections = [c for c in reader.connections if not wanted or c.topic in wanted]
        classes = {c.id: message_class(c.msgtype) for c in connections}
        for connection, stamp_ns, raw in reader.messages(connections=connections):
            yield connection.topic, deserialize_message(bytes(raw), classes[connection.id]), stamp_ns


class BagPlayer:
    """Publishes a bag's messages on their topics from an existing node, in order."""

    def __init__(self, node: Node, path: str | pathlib.Path, topics: Iterable[str] = ()):
        self.node = node
        self.path = pathlib.Path(path)
        self.topics = list(topics)
        self.publishers = {}
        with Reader(self.path) as reader:
            missing = sorted(set(self.topics) - {c.topic for c in reader.connections})
            if missing:
                raise LookupError(f"{self.path} has no topic {', '.join(missing)}; its topics: "
                                  f"{', '.join(sorted({c.topic for c in reader.connections})) or 'none'}")
            for c in reader.connections:
                if not self.topics or c.topic in self.topics:
                    self.publishers[c.topic] = node.create_publisher(
                        message_class(c.msgtype), c.topic, REPLAY_QOS)

    def wait_for_subscribers(self, topics: Iterable[str], timeout_s: float = 10.0) -> bool:
        """Spin until each topic has a subscriber (discovery), or time out."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if all(self.publishers[t].get_subscription_count() > 0 for t in topics):
                return True
            rclpy.spin_once(self.node, timeout_sec=0.05)
        return False

    def play(self, rate: float = 0.0, on_message=None) -> int:
        """Publish every message; rate 0 = as fast as possible, 1 = recorded timing.

        `on_message(topic, msg)` runs after each publish (e.g. to spin a test node)."""
        count, first_bag_ns, start = 0, None, time.monotonic()
        for topic, msg, stamp_ns in read_bag(self.path, self.topics):
            if rate > 0:
                first_bag_ns = stamp_ns if first_bag_ns is None else first_bag_ns
                delay = (stamp_ns - first_bag_ns) / 1e9 / rate - (time.monotonic() - start)
                if delay > 0:
                    time.sleep(delay)
            self.publishers[topic].publish(msg)
            count += 1
            if on_message:
                on_message(topic, msg)
        return count


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="Replay a rosbag2 (MCAP or sqlite3) through rclpy.")
    parser.add_argument("bag", help="bag directory (contains metadata.yaml)")
    parser.add_argument("--rate", type=float, default=1.0, help="1 = recorded timing, 0 = as fast as possible")
    parser.add_argument("--topics", nargs="*", default=[], help="only these topics")
    parser.add_argument("--wait-subscribers", type=float, default=0.0,
                        help="seconds to wait for a subscriber on every topic before playing")
    args = parser.parse_args(argv)
    if not (pathlib.Path(args.bag) / "metadata.yaml").exists():
        print(f"bag_play: {args.bag} is not a rosbag2 directory (no metadata.yaml)", file=sys.stderr)
        return 2
    rclpy.init()
    node = rclpy.create_node("bag_play")
    try:
        player = BagPlayer(node, args.bag, args.topics)
        if args.wait_subscribers > 0:
            player.wait_for_subscribers(player.publishers, args.wait_subscribers)
        count = player.play(rate=args.rate)
        node.get_logger().info(f"played {count} messages from {args.bag}")
    except (LookupError, OSError) as err:
        print(f"bag_play: {err}", file=sys.stderr)
        return 1
    except ReaderError as err:  # a damaged or unsupported bag (metadata, storage file)
        first = (str(err).strip().splitlines() or ["no detail"])[0]  # YAML errors run over lines
        print(f"bag_play: {args.bag} cannot be read as a rosbag2 directory: {first}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
