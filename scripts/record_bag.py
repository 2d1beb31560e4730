#!/usr/bin/env python3
"""Record topics of a running graph into a rosbag2 with the `rosbags` library.

`ros2 bag record` is not on PyPI; this is its pip-only stand-in. After `source scripts/env.sh`:

    python scripts/record_bag.py [TOPIC ...] [--all] [-o DIR] [--storage mcap|sqlite3]
                                 [--compression none|zstd] [--duration S]

Without TOPICs it records the tsrrt run: camera image and intrinsics, perceived and true object
states, joint states, plan and markers, /clock. Messages are stored as the CDR bytes DDS
delivered (raw subscriptions: nothing is decoded or re-serialised), stamped with the wall-clock
receive time as `ros2 bag record` does. Each topic is subscribed when its first publisher
appears, with a QoS every publisher can serve, so topics of nodes started later are recorded too.

The bag is rosbag2 format version 9 (Jazzy), MCAP by default (Jazzy's default storage). Every
topic carries its message definition and RIHS01 type hash, custom tsrrt_interfaces types
included (read from their installed .msg files), so `ros2 bag info/play`, Foxglove and rosbags
can decode it. `--compression zstd` compresses the MCAP chunks (camera frames shrink several
fold; readers decompress transparently). SIGINT or SIGTERM (or --duration) ends the recording
and closes the bag properly.
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
import threading
import time
from collections.abc import Iterator
from datetime import datetime
from functools import partial
from pathlib import Path

import rclpy
from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
from graph import GraphToolError, import_interface, is_hidden_name, publisher_matched_qos
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.signals import SignalHandlerOptions
from rosbags.interfaces import (
    Connection,
    Nodetype,
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer, WriterError
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from tsrrt_common.errors import TsrrtError

DEFAULT_TOPICS = (
    "/camera/image_raw",
    "/camera/camera_info",
    "/perception/objects",
    "/joint_states",
    "/planner/plan",
    "/planner/markers",
    "/sim/object_states",
    "/clock",
)
DISCOVERY_PERIOD_S = 0.5
SUBSCRIPTION_DEPTH = 100     # camera frames arrive in bursts while a write is in progress


class RecorderError(TsrrtError):
    """The bag cannot be written as asked (bad path, unknown type definition)."""


class MessageDefinitions:
    """Message definitions for the bag: rosbags' Jazzy store, installed .msg files for the rest.

    Types outside the store (tsrrt_interfaces, or anything newer) are parsed from
    `<share>/<package>/msg/<Name>.msg`, with the types they reference, so `Writer.add_connection`
    can embed a full definition and compute the RIHS01 hash.
    """

    def __init__(self) -> None:
        self.typestore: Typestore = get_typestore(Stores.ROS2_JAZZY)

    def ensure(self, msgtype: str) -> None:
        """Make `msgtype` and every type it references known to the typestore."""
        if msgtype in self.typestore.fielddefs:
            return
        types = get_types_from_msg(self._installed_msg_text(msgtype), msgtype)
        self.typestore.register(types)
        for _, fielddef in types[msgtype][1]:
            for referenced in _referenced_types(fielddef):
                self.ensure(referenced)

    def rihs01(self, msgtype: str) -> str:
        return self.typestore.hash_rihs01(msgtype)

    @staticmethod
    def _installed_msg_text(msgtype: str) -> str:
        package, kind, name = msgtype.split("/")
        try:
            share = Path(get_package_share_directory(package))
        except PackageNotFoundError:
            raise RecorderError(f"no definition of {msgtype}: package '{package}' is not "
                                "installed (is the workspace sourced?)") from None
        path = share / kind / f"{name}.msg"
        if not path.is_file():
            raise RecorderError(f"no definition of {msgtype}: {path} does not exist")
        return path.read_text()


def _referenced_types(fielddef: tuple) -> Iterator[str]:
    """Message type names inside one rosbags field definition (nested in arrays/sequences)."""
    kind, detail = fielddef
    if kind == Nodetype.NAME:
        yield detail
    elif kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
        yield from _referenced_types(detail[0])


def _bag_qos(qos: QoSProfile) -> Qos:
    """A publisher's offered QoS (as the graph reports it) in rosbags' metadata form."""
    def duration(value) -> QosTime:
        return QosTime(*divmod(value.nanoseconds, 1_000_000_000))

    return Qos(
        history=QosHistory[qos.history.name],
        depth=qos.depth,
        reliability=QosReliability[qos.reliability.name],
        durability=QosDurability[qos.durability.name],
        deadline=duration(qos.deadline),
        lifespan=duration(qos.lifespan),
        liveliness=QosLiveliness[qos.liveliness.name],
        liveliness_lease_duration=duration(qos.liveliness_lease_duration),
        avoid_ros_namespace_conventions=qos.avoid_ros_namespace_conventions,
    )


class BagRecorder(Node):
    """Subscribes (raw) to the wanted topics as their publishers appear and writes each message."""

    def __init__(self, writer: Writer, topics: tuple[str, ...] | None) -> None:
        super().__init__("tsrrt_bag_recorder")
        self.writer = writer
        self.topics = topics                    # None: every topic that is not hidden
        self.definitions = MessageDefinitions()
        self.connections: dict[str, Connection] = {}
        self.counts: dict[str, int] = {}
        self.skipped: set[str] = set()
        self.discover()
        self.create_timer(DISCOVERY_PERIOD_S, self.discover)

    def _wanted(self, topic: str) -> bool:
        if topic in self.connections or topic in self.skipped:
            return False
        if self.topics is None:
            return not is_hidden_name(topic)
        return topic in self.topics

    def discover(self) -> None:
        for topic, types in self.get_topic_names_and_types():
            if not self._wanted(topic):
                continue
            publishers = self.get_publishers_info_by_topic(topic)
            if not publishers:                      # only subscribers so far
                continue
            if len(types) != 1:
                self._skip(topic, f"it has several types {types}")
                continue
            try:
                self._subscribe(topic, types[0], publishers)
            except (GraphToolError, RecorderError, WriterError) as error:
                self._skip(topic, str(error))

    def _skip(self, topic: str, reason: str) -> None:
        self.skipped.add(topic)
        self.get_logger().error(f"not recording {topic}: {reason}")

    def _subscribe(self, topic: str, msgtype: str, publishers: list) -> None:
        message_class = import_interface(msgtype)
        self.definitions.ensure(msgtype)
        digest = self.definitions.rihs01(msgtype)
        offered = str(publishers[0].topic_type_hash)
        if offered.startswith("RIHS01_") and offered != digest:
            self.get_logger().warning(
                f"{topic}: the publisher's {msgtype} hash {offered} differs from the recorded "
                f"definition's {digest}; the installed .msg may be stale")
        self.connections[topic] = self.writer.add_connection(
            topic, msgtype, typestore=self.definitions.typestore,
            offered_qos_profiles=[_bag_qos(p.qos_profile) for p in publishers])
        self.counts[topic] = 0
        self.create_subscription(message_class, topic, partial(self._write, topic),
                                 publisher_matched_qos(self, topic, depth=SUBSCRIPTION_DEPTH),
                                 raw=True)
        self.get_logger().info(f"recording {topic} ({msgtype})")

    def _write(self, topic: str, data: bytes) -> None:
        self.writer.write(self.connections[topic], time.time_ns(), data)
        self.counts[topic] += 1

    def summary(self) -> str:
        lines = [f"  {topic}: {self.counts[topic]}" for topic in sorted(self.counts)]
        waiting = [t for t in self.topics or () if t not in self.counts and t not in self.skipped]
        if waiting:
            lines.append("  never published: " + ", ".join(waiting))
        return "\n".join(lines)


def record(output: Path, topics: tuple[str, ...] | None, storage: StoragePlugin,
           duration: float | None, compress: bool = False) -> None:
    """Record until SIGINT/SIGTERM or `duration` seconds; the bag is closed in every case.

    `compress`: zstd inside the MCAP chunks (CompressionMode.STORAGE, what `ros2 bag record
    --storage-preset-profile zstd_fast` does), not rosbag2's file or message compression, so the
    metadata stays plain and every MCAP reader decodes it.

    The signals only set a flag: rclpy's own handlers would shut the context down under the
    running executor, which then fails instead of ending the loop.
    """
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    writer = Writer(output, version=Writer.VERSION_LATEST, storage_plugin=storage)
    if compress:
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    writer.open()
    recorder = BagRecorder(writer, topics)
    executor = SingleThreadedExecutor()
    executor.add_node(recorder)
    try:
        end = math.inf if duration is None else time.monotonic() + duration
        while not stop.is_set() and time.monotonic() < end:
            executor.spin_once(timeout_sec=0.1)
    finally:
        executor.shutdown()
        writer.close()
        print(f"bag {output} ({storage.name.lower()}{', zstd' if compress else ''}), "
              f"messages per topic:\n"
              f"{recorder.summary()}", file=sys.stderr, flush=True)
        recorder.destroy_node()
        rclpy.try_shutdown()


def _default_output() -> Path:
    return Path(datetime.now().strftime("tsrrt_%Y_%m_%d-%H_%M_%S"))


def _seconds(text: str) -> float:
    value = float(text)
    if not value > 0.0:
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, got {text}")
    return value


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="record_bag.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("topics", nargs="*", metavar="TOPIC",
                        help="topics to record (default: " + " ".join(DEFAULT_TOPICS) + ")")
    parser.add_argument("-a", "--all", action="store_true",
                        help="record every topic that is not hidden")
    parser.add_argument("-o", "--output", type=Path, default=None, metavar="DIR",
                        help="bag directory to create (default ./tsrrt_<date-time>)")
    parser.add_argument("-s", "--storage", choices=["mcap", "sqlite3"], default="mcap",
                        help="storage format (default mcap, as ros2 bag in Jazzy)")
    parser.add_argument("--compression", choices=["none", "zstd"], default="none",
                        help="zstd: compress the MCAP chunks (mcap storage only; default none, "
                             "as ros2 bag)")
    parser.add_argument("--duration", type=_seconds, metavar="S",
                        help="stop after S wall-clock seconds (default: until Ctrl-C/SIGTERM)")
    args = parser.parse_args(argv)
    if args.all and args.topics:
        parser.error("give TOPICs or --all, not both")
    if args.compression == "zstd" and args.storage != "mcap":
        parser.error("--compression zstd compresses MCAP chunks: it needs --storage mcap")
    topics = None if args.all else tuple(
        t if t.startswith("/") else "/" + t for t in args.topics or DEFAULT_TOPICS)
    output = args.output or _default_output()
    if output.exists():
        print(f"record_bag.py: error: {output} exists; the recorder never overwrites a bag",
              file=sys.stderr)
        return 1
    record(output, topics, StoragePlugin[args.storage.upper()], args.duration,
           compress=args.compression == "zstd")
    return 0


if __name__ == "__main__":
    sys.exit(main())
