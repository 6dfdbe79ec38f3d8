# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""rosbag2 record / play / info through the ``rosbags`` library (rosbag2 is not on PyPI).

Bags are rosbag2 version 9, MCAP storage, CDR serialization, with the type hashes and the
publishers' offered QoS in metadata.yaml -- what ``ros2 bag info`` / ``ros2 bag play`` of a ROS 2
Jazzy install read. Messages are recorded and replayed as serialized CDR (no per-message
conversion), so any message type the typestore knows is supported.
"""
from __future__ import annotations

import importlib
import json
import os
import threading
import time

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from ...core.errors import AffordanceError
from ..glue.qos import LATCHED

__all__ = ["BagError", "Recorder", "Player", "StatusPacer", "bag_info", "message_class",
           "read_messages"]


class BagError(AffordanceError):
    """A bag cannot be read or written (the message says which and why)."""


def message_class(type_name: str):
    """'sensor_msgs/msg/PointCloud2' -> the rclpy message class."""
    try:
        pkg, kind, name = type_name.split("/")
        return getattr(importlib.import_module(f"{pkg}.{kind}"), name)
    except (ValueError, ImportError, AttributeError):
        raise BagError(f"message type {type_name!r} is not available in this Python") from None


def _typestore():
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY)


def _to_rosbags_qos(profile: QoSProfile):
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
    zero = QosTime(sec=0, nsec=0)
    return Qos(history=QosHistory(int(profile.history.value)), depth=int(profile.depth),
               reliability=QosReliability(int(profile.reliability.value)),
               durability=QosDurability(int(profile.durability.value)), deadline=zero,
               lifespan=zero, liveliness=QosLiveliness(int(profile.liveliness.value)),
               liveliness_lease_duration=zero, avoid_ros_namespace_conventions=False)


def _from_rosbags_qos(qos_list) -> QoSProfile:
    """A publisher QoS for replay: reliability and durability as recorded (latched stays
    latched), keep-last with at least depth 10."""
    if not qos_list:
        return QoSProfile(depth=10)
    q = qos_list[0]
    reliability = ReliabilityPolicy(q.reliability.value)
    durability = DurabilityPolicy(q.durability.value)
    if reliability not in (ReliabilityPolicy.RELIABLE, ReliabilityPolicy.BEST_EFFORT):
        reliability = ReliabilityPolicy.RELIABLE
    if durability not in (DurabilityPolicy.TRANSIENT_LOCAL, DurabilityPolicy.VOLATILE):
        durability = DurabilityPolicy.VOLATILE
    return QoSProfile(depth=max(10, int(q.depth or 0)), history=HistoryPolicy.KEEP_LAST,
                      reliability=reliability, durability=durability)


class Recorder:
    """Records topics into a new bag. Each topic is subscribed when a publisher appears, with a
    QoS that matches every publisher (reliable / transient local only if all of them are)."""

    def __init__(self, node, out: str, topics):
        from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
        self.node = node
        self.topics = list(topics)
        if not self.topics:
            raise BagError("name at least one topic to record")
        try:
            self.writer = Writer(out, version=9, storage_plugin=StoragePlugin.MCAP)
            self.writer.open()
        except (WriterError, OSError) as exc:
            raise BagError(f"cannot create bag {out}: {exc}") from None
        self.out = out
        self.typestore = _typestore()
        self.connections: dict[str, object] = {}
        self.counts: dict[str, int] = {t: 0 for t in self.topics}
        self._lock = threading.Lock()
        self._closed = False
        self._timer = node.create_timer(0.1, self._discover)
        self._discover()

    def _discover(self) -> None:
        for topic in self.topics:
            if topic in self.connections:
                continue
            infos = self.node.get_publishers_info_by_topic(topic)
            if not infos:
                continue
            type_name = infos[0].topic_type
            reliable = all(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in infos)
            latched = all(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
                          for i in infos)
            qos = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST,
                             reliability=ReliabilityPolicy.RELIABLE if reliable
                             else ReliabilityPolicy.BEST_EFFORT,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL if latched
                             else DurabilityPolicy.VOLATILE)
            cls = message_class(type_name)
            with self._lock:
                conn = self.writer.add_connection(
                    topic, type_name, typestore=self.typestore,
                    offered_qos_profiles=[_to_rosbags_qos(infos[0].qos_profile)])
                self.connections[topic] = conn
            self.node.create_subscription(cls, topic, self._writer_for(topic, conn), qos,
                                          raw=True)
            self.node.get_logger().info(f"recording {topic} ({type_name})")

    def _writer_for(self, topic, conn):
        def write(data: bytes) -> None:
            stamp = self.node.get_clock().now().nanoseconds
            with self._lock:
                if not self._closed:
                    self.writer.write(conn, stamp, data)
                    self.counts[topic] += 1
        return write

    def close(self) -> dict:
        with self._lock:
            if not self._closed:
                self._closed = True
                self.writer.close()
        return dict(self.counts)


def _open_reader(path: str):
    from rosbags.rosbag2 import Reader
    if not os.path.exists(path):
        raise BagError(f"{path}: no such bag")
    try:
        reader = Reader(path)
        reader.open()
        return reader
    except Exception as exc:   # rosbags raises several types for truncated/corrupt bags
        raise BagError(f"{path}: not a readable rosbag2 bag ({exc.__class__.__name__}: "
                       f"{str(exc).splitlines()[0] if str(exc) else 'corrupt'})") from None


def bag_info(path: str) -> dict:
    """Topics, types, message counts and duration of a bag."""
    reader = _open_reader(path)
    try:
        return {"path": path, "duration_s": reader.duration / 1e9,
                "start_ns": reader.start_time, "end_ns": reader.end_time,
                "messages": reader.message_count,
                "topics": [{"topic": c.topic, "type": c.msgtype, "count": c.msgcount}
                           for c in reader.connections]}
    finally:
        reader.close()


def read_messages(path: str, topic: str):
    """Yield the messages recorded on ``topic``, decoded into rclpy message objects."""
    from rclpy.serialization import deserialize_message
    reader = _open_reader(path)
    try:
        conns = [c for c in reader.connections if c.topic == topic]
        for conn, _, data in reader.messages(connections=conns):
            yield deserialize_message(bytes(data), message_class(conn.msgtype))
    except BagError:
        raise
    except Exception as exc:
        raise BagError(f"{path}: reading {topic} failed ({exc.__class__.__name__}: {exc}); "
                       f"the bag is truncated or corrupt") from None
    finally:
        reader.close()


class StatusPacer:
    """Paces a replay by the receiving node's progress: before a message is published, wait
    until the node has handled everything published so far and is idle.

    The node publishes a JSON status on ``status_topic`` (transient local) whose ``node`` entry
    has ``handled`` (resolved topic name -> messages handled) and ``idle`` (nothing queued,
    nothing running, no refit waiting) -- what ``affordance_engine`` publishes on ``~/status``,
    listing each of its input topics from the start. Topics the node does not list are not
    waited for."""

    def __init__(self, node, status_topic: str = "/affordance_engine/status",
                 timeout: float = 60.0):
        self.timeout = float(timeout)
        self.status_topic = status_topic
        self._cv = threading.Condition()
        self._status: dict | None = None
        self._baseline: dict | None = None
        qos = LATCHED
        from std_msgs.msg import String
        node.create_subscription(String, status_topic, self._on_status, qos)

    def _on_status(self, msg) -> None:
        try:
            status = json.loads(msg.data).get("node") or {}
        except (ValueError, AttributeError):
            return
        with self._cv:
            self._status = status
            self._cv.notify_all()

    def _ready(self, published: dict) -> bool:
        st = self._status
        if st is None or not st.get("idle"):
            return False
        handled = st.get("handled") or {}
        if self._baseline is None:        # what the node had handled before this replay
            self._baseline = dict(handled)
        return all(handled[t] - self._baseline.get(t, 0) >= n for t, n in published.items()
                   if t in handled)

    def wait(self, published: dict, stop: threading.Event) -> None:
        """Block until the node has handled ``published`` (topic -> count since the first
        wait) and is idle."""
        deadline = time.monotonic() + self.timeout
        with self._cv:
            while not self._ready(published) and not stop.is_set():
                left = deadline - time.monotonic()
                if left <= 0:
                    st = self._status
                    raise BagError(f"the node on {self.status_topic} did not finish with the "
                                   f"messages played so far within {self.timeout:.0f} s "
                                   f"(played {published}, its status: "
                                   f"{'none' if st is None else st.get('handled')}, idle "
                                   f"{None if st is None else st.get('idle')})")
                self._cv.wait(timeout=min(left, 0.2))


class Player:
    """Republishes a bag with its original timing (scaled by ``rate``).

    With a ``pace`` (:class:`StatusPacer`), each message waits until the receiving node has
    finished with the ones before it, except within a burst -- a message on the same topic as
    the one before it, recorded at most ``burst_gap`` s after it (a SpaceMouse push at 30 Hz) --
    whose recorded relative timing is kept. The replay then does not depend on how fast the
    node or the machine is."""

    def __init__(self, node, path: str, rate: float = 1.0, start_offset: float = 0.0,
                 topics=None, loop: bool = False, pace: "StatusPacer | None" = None,
                 burst_gap: float = 0.1):
        if not rate > 0:
            raise BagError("--rate must be positive")
        self.node, self.path = node, path
        self.rate, self.start_offset, self.loop = rate, start_offset, loop
        self.pace, self.burst_gap = pace, float(burst_gap)
        self.counts: dict[str, int] = {}         # messages published per topic
        reader = _open_reader(path)
        try:
            self.connections = [c for c in reader.connections
                                if topics is None or c.topic in topics]
            missing = set(topics or ()) - {c.topic for c in reader.connections}
            if missing:
                raise BagError(f"{path}: no topic(s) {', '.join(sorted(missing))} in the bag")
            self.start = reader.start_time
        finally:
            reader.close()
        self.publishers = {}
        for c in self.connections:
            if c.topic not in self.publishers:
                qos = _from_rosbags_qos(getattr(c.ext, "offered_qos_profiles", []))
                self.publishers[c.topic] = node.create_publisher(message_class(c.msgtype),
                                                                 c.topic, qos)
        self.published = 0

    def wait_for_subscribers(self, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if all(p.get_subscription_count() > 0 for p in self.publishers.values()):
                return True
            time.sleep(0.05)
        return False

    def play(self, stop: threading.Event | None = None) -> int:
        """Publish every message at its time (or paced); returns the number published."""
        stop = stop or threading.Event()
        while True:
            reader = _open_reader(self.path)
            try:
                self._play_once(reader, stop)
            except BagError:
                raise
            except Exception as exc:
                raise BagError(f"{self.path}: reading failed ({exc.__class__.__name__}: "
                               f"{exc}); the bag is truncated or corrupt") from None
            finally:
                reader.close()
            if not self.loop or stop.is_set():
                return self.published

    def _play_once(self, reader, stop: threading.Event) -> None:
        t_bag0 = self.start + int(self.start_offset * 1e9)
        t_wall0 = time.monotonic()
        previous = None                 # (topic, stamp) of the message published before
        for conn, stamp, data in reader.messages(connections=self.connections):
            if stamp < t_bag0:
                continue
            if self.pace is not None:
                in_burst = previous is not None and previous[0] == conn.topic and \
                    (stamp - previous[1]) / 1e9 <= self.burst_gap
                if not in_burst:
                    self.pace.wait(self.counts, stop)
                    # the node is ready: this message starts a new time line
                    t_wall0, t_bag0 = time.monotonic(), stamp
            due = t_wall0 + (stamp - t_bag0) / 1e9 / self.rate
            while not stop.is_set() and time.monotonic() < due:
                time.sleep(min(0.01, max(0.0, due - time.monotonic())))
            if stop.is_set():
                return
            self.publishers[conn.topic].publish(bytes(data))
            self.published += 1
            self.counts[conn.topic] = self.counts.get(conn.topic, 0) + 1
            previous = (conn.topic, stamp)
