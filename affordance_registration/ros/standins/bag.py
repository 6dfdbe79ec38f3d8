# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""rosbag2 record / play / info through the ``rosbags`` library (rosbag2 is not on PyPI).

Bags are rosbag2 version 9, MCAP storage, CDR serialization, with the type hashes and the
publishers' offered QoS in metadata.yaml -- what ``ros2 bag info`` / ``ros2 bag play`` of a ROS 2
Jazzy install read. Messages are recorded and replayed as serialized CDR (no per-message
conversion), so any message type the typestore knows is supported.

Every decompression of a bag read is bounded (:func:`bounded_decompression`): an MCAP chunk
(zstd or lz4) unpacks to at most the size its record promises, and that size is at most
:data:`MAX_UNPACKED_BYTES`; a message of a bag compressed per message, and a storage file of a
bag compressed per file, unpack to at most :data:`MAX_UNPACKED_BYTES` and
:data:`MAX_UNPACKED_FILE_BYTES`. Past either, the bag is refused in one line (a 262 kB bag whose
chunk was a zstd bomb took 2.6 GB).
"""

from __future__ import annotations

import importlib
import json
import math
import os
import re
import shutil
import stat
import threading
import time
from pathlib import PurePath

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from ...core.errors import AffordanceError
from ...core.files import read_yaml, unreadable
from ..glue.qos import LATCHED

__all__ = [
    "BagError",
    "Recorder",
    "Player",
    "StatusPacer",
    "bag_info",
    "bounded_decompression",
    "check_number",
    "message_class",
    "read_messages",
    "topic_name",
]


class BagError(AffordanceError):
    """A bag cannot be read or written (the message says which and why)."""


#: the most bytes one MCAP chunk, or one message of a bag compressed per message, unpacks to
#: (rosbag2 writes chunks of about 1 MB; one holds at least a whole message, and a 10-million
#: point cloud is 160 MB)
MAX_UNPACKED_BYTES = 1 << 30
#: the most bytes one storage file of a bag compressed per file unpacks to (into a temporary
#: folder, as rosbags does)
MAX_UNPACKED_FILE_BYTES = 16 << 30
#: the largest metadata.yaml read (a bag of thousands of topics and files is well under this)
MAX_METADATA_BYTES = 10_000_000
#: a playback rate outside these plays a bag for ever or all at once (--rate 1e-300 never ended)
RATE_LIMITS = (1e-3, 1e3)


def check_number(name: str, value, positive: bool = False, limits=None) -> float:
    """``value`` as a float that is finite and >= 0 (> 0 with ``positive``; within ``limits``
    (lo, hi) where given); else a :class:`BagError` naming ``name`` (an option such as
    ``--rate``)."""
    try:
        number = float(value)
    except (TypeError, ValueError, OverflowError):
        number = math.nan
    if not math.isfinite(number) or number < 0 or (positive and number == 0):
        raise BagError(
            f"{name} must be a finite number {'> 0' if positive else '>= 0'}, got {value}"
        )
    if limits is not None and not limits[0] <= number <= limits[1]:
        raise BagError(f"{name} must be in [{limits[0]:g}, {limits[1]:g}], got {value}")
    return number


def topic_name(name, node_name: str = "affordance_bag", namespace: str = "/") -> str:
    """``name`` checked by the ROS 2 topic name rules and expanded as a node called
    ``node_name`` in ``namespace`` would (``points`` -> ``/points``); else a :class:`BagError`
    saying why."""
    from rclpy.exceptions import NameValidationException
    from rclpy.expand_topic_name import expand_topic_name
    from rclpy.validate_full_topic_name import validate_full_topic_name
    from rclpy.validate_topic_name import validate_topic_name

    try:
        if not isinstance(name, str):
            raise ValueError("not a string")
        validate_topic_name(name)
        full = expand_topic_name(name, node_name, namespace)
        validate_full_topic_name(full)
        return full
    except (NameValidationException, ValueError, TypeError) as exc:
        text = str(exc).splitlines()[0] if str(exc) else exc.__class__.__name__
        # rclpy's texts: "Invalid topic name: <why>:" or "topic name '..' is invalid: <why>, at
        # <C source>:<line>"
        text = re.sub(
            r"^Invalid topic name: |:$|^topic name .* is invalid: |, at \S+:\d+$", "", text
        )
        raise BagError(f"{name!r} is not a valid ROS 2 topic name ({text})") from None


def _regular_file(path: str) -> None:
    """A BagError naming ``path`` unless it is a regular file (a link is followed): reading a
    FIFO or a device would block or never end."""
    why = unreadable(path, missing_ok=True)  # (missing: rosbags says what is)
    if why is not None:
        raise BagError(f"{path}: {why}, cannot be read as part of a bag")


def _check_bag_files(path: str) -> None:
    """Every file rosbags will read for the bag at ``path`` is a regular file: the bag file
    itself, or a bag folder's metadata.yaml and the storage files it lists."""
    try:
        mode = os.stat(path).st_mode
    except OSError as exc:
        raise BagError(f"{path}: cannot read it ({exc.strerror or exc})") from None
    if not stat.S_ISDIR(mode):
        _regular_file(path)
        return
    meta = os.path.join(path, "metadata.yaml")
    _regular_file(meta)
    if not os.path.exists(meta):
        return
    # read here first by the one YAML loader (aliases bounded), before rosbags reads it
    doc = read_yaml(meta, BagError, max_bytes=MAX_METADATA_BYTES, kind="bag's metadata.yaml")
    try:
        files = doc["rosbag2_bagfile_information"]["relative_file_paths"]
    except (KeyError, TypeError):  # rosbags says what is wrong with the metadata
        return
    for name in files if isinstance(files, list) else ():
        if isinstance(name, str):  # rosbags reads each by its name in the bag folder
            _regular_file(os.path.join(path, PurePath(name).name))


def _unpack(make, data: bytes, size: int, what: str, promised: bool = True) -> bytes:
    """``data`` (zstd or lz4 frames) unpacked by decompressors ``make()`` makes (each one
    frame: ``decompress(data, max_length)``, ``eof``, ``needs_input``, ``unused_data``) to at
    most ``size`` bytes -- what the chunk's header ``promised``, else a cap --, never more:
    past it (or past :data:`MAX_UNPACKED_BYTES`), or cut short, a BagError."""
    if size > MAX_UNPACKED_BYTES:
        raise BagError(
            f"{what} claims {size:,} bytes unpacked, more than the {MAX_UNPACKED_BYTES:,} "
            f"this reads (MAX_UNPACKED_BYTES)"
        )
    pieces, left = [], size
    while True:
        decompressor = make()
        piece = decompressor.decompress(data, max_length=left)
        pieces.append(piece)
        left -= len(piece)
        if not decompressor.eof:
            if getattr(decompressor, "needs_input", True):
                raise BagError(f"{what} is cut short (corrupt)")
            raise BagError(
                f"{what} unpacks to more than the {size:,} bytes "
                + ("its header promises" if promised else "this reads (MAX_UNPACKED_BYTES)")
            )
        data = decompressor.unused_data
        if not data:
            return b"".join(pieces)


class _BoundedZstd:
    """What rosbags' reader uses of its zstd module, bounded: ``decompress`` (a message of a
    bag compressed per message) and ``open`` (a storage file of a bag compressed per file)."""

    def __init__(self, zstd):
        self.zstd = zstd

    def decompress(self, data: bytes) -> bytes:
        return _unpack(
            self.zstd.ZstdDecompressor, data, MAX_UNPACKED_BYTES, "a message", promised=False
        )

    def open(self, fileobj, mode: str = "rb"):
        return _CappedReader(self.zstd.open(fileobj, mode), MAX_UNPACKED_FILE_BYTES)


class _CappedReader:
    """A file object that refuses to be read past ``cap`` bytes."""

    def __init__(self, inner, cap: int):
        self.inner, self.left = inner, cap

    def read(self, n: int = -1) -> bytes:
        want = self.left + 1 if n is None or n < 0 else min(n, self.left + 1)
        data = self.inner.read(want)
        self.left -= len(data)
        if self.left < 0:
            raise BagError(
                f"a storage file unpacks to more than {MAX_UNPACKED_FILE_BYTES:,} bytes "
                f"(MAX_UNPACKED_FILE_BYTES)"
            )
        return data

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.inner.close()


def bounded_decompression() -> None:
    """Make every decompression rosbags does while reading a bag bounded (idempotent): its
    MCAP chunk decompressors (by the size each chunk record promises) and the zstd module its
    reader unpacks messages and files with."""
    import lz4.frame
    from rosbags.rosbag2 import reader, storage_mcap

    zstd = storage_mcap.zstd  # the module rosbags chose (compression.zstd or its backport)
    storage_mcap.DECOMPRESSORS["zstd"] = lambda data, size: _unpack(
        zstd.ZstdDecompressor, data, size, "an MCAP chunk (zstd)"
    )
    storage_mcap.DECOMPRESSORS["lz4"] = lambda data, size: _unpack(
        lz4.frame.LZ4FrameDecompressor, data, size, "an MCAP chunk (lz4)"
    )
    if not isinstance(reader.zstd, _BoundedZstd):
        reader.zstd = _BoundedZstd(reader.zstd)


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
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )

    zero = QosTime(sec=0, nsec=0)
    return Qos(
        history=QosHistory(int(profile.history.value)),
        depth=int(profile.depth),
        reliability=QosReliability(int(profile.reliability.value)),
        durability=QosDurability(int(profile.durability.value)),
        deadline=zero,
        lifespan=zero,
        liveliness=QosLiveliness(int(profile.liveliness.value)),
        liveliness_lease_duration=zero,
        avoid_ros_namespace_conventions=False,
    )


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
    return QoSProfile(
        depth=max(10, int(q.depth or 0)),
        history=HistoryPolicy.KEEP_LAST,
        reliability=reliability,
        durability=durability,
    )


def _first_missing(path: str) -> str | None:
    """The outermost folder that creating ``path`` (with its parents) would create; None when
    ``path`` exists."""
    path = os.path.abspath(path)
    if os.path.lexists(path):
        return None
    while not os.path.lexists(os.path.dirname(path)) and os.path.dirname(path) != path:
        path = os.path.dirname(path)
    return path


class Recorder:
    """Records topics into a new bag. Each topic is subscribed when a publisher appears, with a
    QoS that matches every publisher (reliable / transient local only if all of them are).

    The topic names are checked (and expanded: ``points`` -> ``/points``) before anything is
    created. A recording that fails -- here, or later in :attr:`error` (a topic whose type
    cannot be recorded, a write that failed) -- leaves no partial bag: :meth:`close` keeps the
    bag only when it is whole and, after such a failure, holds messages; else the folders this
    recorder created are removed."""

    def __init__(self, node, out: str, topics):
        from rosbags.rosbag2 import StoragePlugin, Writer, WriterError

        self.node = node
        self.topics = list(
            dict.fromkeys(topic_name(t, node.get_name(), node.get_namespace()) for t in topics)
        )
        if not self.topics:
            raise BagError("name at least one topic to record")
        #: one line saying why the recording failed in the background, else None
        self.error: str | None = None
        self.kept = False  # close() left a whole bag
        self._created = _first_missing(out)  # what to remove if the recording fails
        self._write_failed = False
        self.out = out
        try:
            self.writer = Writer(out, version=9, storage_plugin=StoragePlugin.MCAP)
            self.writer.open()
        except (WriterError, OSError) as exc:
            self._remove()
            raise BagError(f"cannot create bag {out}: {exc}") from None
        self.connections: dict[str, object] = {}
        self.counts: dict[str, int] = {t: 0 for t in self.topics}
        self._lock = threading.Lock()
        self._closed = False
        self._timer = None
        try:
            self.typestore = _typestore()
            self._discover()
            # after the first look: the timer's and this one must not add a topic twice
            self._timer = node.create_timer(0.1, self._discover_in_background)
        except BaseException:
            self.abort()
            raise

    def _discover(self) -> None:
        for topic in self.topics:
            if topic in self.connections or self._closed:
                continue
            infos = self.node.get_publishers_info_by_topic(topic)
            if not infos:
                continue
            type_name = infos[0].topic_type
            reliable = all(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in infos)
            latched = all(
                i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos
            )
            qos = QoSProfile(
                depth=100,
                history=HistoryPolicy.KEEP_LAST,
                reliability=ReliabilityPolicy.RELIABLE
                if reliable
                else ReliabilityPolicy.BEST_EFFORT,
                durability=DurabilityPolicy.TRANSIENT_LOCAL
                if latched
                else DurabilityPolicy.VOLATILE,
            )
            cls = message_class(type_name)
            with self._lock:
                if self._closed:
                    return
                try:
                    conn = self.writer.add_connection(
                        topic,
                        type_name,
                        typestore=self.typestore,
                        offered_qos_profiles=[_to_rosbags_qos(infos[0].qos_profile)],
                    )
                except Exception as exc:  # a type rosbags' typestore does not know
                    why = str(exc).splitlines()[0] if str(exc) else ""
                    raise BagError(
                        f"cannot record {topic} ({type_name}) into {self.out}: "
                        f"{exc.__class__.__name__}: {why}"
                    ) from None
                self.connections[topic] = conn
            self.node.create_subscription(cls, topic, self._writer_for(topic, conn), qos, raw=True)
            self.node.get_logger().info(f"recording {topic} ({type_name})")

    def _discover_in_background(self) -> None:
        """The timer's look for publishers: a failure is kept in :attr:`error` (an exception
        would end the node's spin thread) and stops the looking."""
        try:
            self._discover()
        except Exception as exc:
            if self.error is None:
                self.error = (
                    str(exc)
                    if isinstance(exc, BagError)
                    else f"cannot record into {self.out}: {exc.__class__.__name__}: "
                    f"{str(exc).splitlines()[0] if str(exc) else ''}"
                )
            if self._timer is not None:
                self._timer.cancel()

    def _writer_for(self, topic, conn):
        def write(data: bytes) -> None:
            stamp = self.node.get_clock().now().nanoseconds
            with self._lock:
                if self._closed or self._write_failed:
                    return
                try:
                    self.writer.write(conn, stamp, data)
                except Exception as exc:  # a full disk: the bag is broken from here on
                    self._write_failed = True
                    if self.error is None:
                        self.error = (
                            f"writing {self.out} failed ({exc.__class__.__name__}: "
                            f"{str(exc).splitlines()[0] if str(exc) else ''})"
                        )
                    return
                self.counts[topic] += 1

        return write

    def close(self) -> dict:
        """Finish the bag (its metadata.yaml written); returns the messages recorded per topic.
        After a failure (:attr:`error`) the bag is kept only if it is whole and holds messages,
        else removed; :attr:`kept` says which. A bag that cannot be finished is removed and
        raises :class:`BagError`."""
        with self._lock:
            if self._closed:
                return dict(self.counts)
            self._closed = True
            if self._timer is not None:
                self._timer.cancel()
            try:
                self.writer.close()
            except Exception as exc:
                self._remove()
                raise BagError(
                    f"cannot finish bag {self.out} ({exc.__class__.__name__}: "
                    f"{str(exc).splitlines()[0] if str(exc) else ''}); "
                    f"it is removed"
                ) from None
            if self._write_failed or (self.error is not None and not sum(self.counts.values())):
                self._remove()
            else:
                self.kept = True
        return dict(self.counts)

    def abort(self) -> None:
        """Stop recording and remove the bag (and the folders created for it)."""
        with self._lock:
            self._closed = True
            if self._timer is not None:
                self._timer.cancel()
            try:
                self.writer.close()  # lets go of the storage file
            except Exception:
                pass
            self.kept = False
            self._remove()

    def _remove(self) -> None:
        if (
            self._created is not None
            and os.path.isdir(self._created)
            and not os.path.islink(self._created)
        ):
            shutil.rmtree(self._created, ignore_errors=True)


def _open_reader(path: str):
    from rosbags.rosbag2 import Reader

    if not os.path.exists(path):
        raise BagError(f"{path}: no such bag")
    inner = [
        name
        for name in (sorted(os.listdir(path)) if os.path.isdir(path) else [])
        if os.path.isfile(os.path.join(path, name, "metadata.yaml"))
    ]
    if not os.path.isfile(os.path.join(path, "metadata.yaml")) and inner:
        # a folder holding a bag (a recorded session: the bag and its truth)
        raise BagError(
            f"{path}: not a bag but a folder holding one: give {os.path.join(path, inner[0])}"
        )
    _check_bag_files(path)
    bounded_decompression()
    try:
        reader = Reader(path)
        reader.open()
        return reader
    except BagError as exc:  # a bound (a compressed bomb)
        raise BagError(f"{path}: {exc}") from None
    except Exception as exc:  # rosbags raises several types for truncated/corrupt bags
        raise BagError(
            f"{path}: not a readable rosbag2 bag ({exc.__class__.__name__}: "
            f"{str(exc).splitlines()[0] if str(exc) else 'corrupt'})"
        ) from None


def bag_info(path: str) -> dict:
    """Topics, types, message counts and duration of a bag."""
    reader = _open_reader(path)
    try:
        return {
            "path": path,
            "duration_s": reader.duration / 1e9,
            "start_ns": reader.start_time,
            "end_ns": reader.end_time,
            "messages": reader.message_count,
            "topics": [
                {"topic": c.topic, "type": c.msgtype, "count": c.msgcount}
                for c in reader.connections
            ],
        }
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
    except BagError as exc:
        raise BagError(f"{path}: {exc}" if not str(exc).startswith(path) else str(exc)) from None
    except Exception as exc:
        raise BagError(
            f"{path}: reading {topic} failed ({exc.__class__.__name__}: {exc}); "
            f"the bag is truncated or corrupt"
        ) from None
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

    def __init__(
        self, node, status_topic: str = "/affordance_engine/status", timeout: float = 60.0
    ):
        self.timeout = check_number("the pace timeout", timeout, positive=True)
        self.status_topic = topic_name(status_topic, node.get_name(), node.get_namespace())
        self._cv = threading.Condition()
        self._status: dict | None = None
        self._baseline: dict | None = None
        qos = LATCHED
        from std_msgs.msg import String

        node.create_subscription(String, self.status_topic, self._on_status, qos)

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
        if self._baseline is None:  # what the node had handled before this replay
            self._baseline = dict(handled)
        return all(
            handled[t] - self._baseline.get(t, 0) >= n
            for t, n in published.items()
            if t in handled
        )

    def wait(self, published: dict, stop: threading.Event) -> None:
        """Block until the node has handled ``published`` (topic -> count since the first
        wait) and is idle."""
        deadline = time.monotonic() + self.timeout
        with self._cv:
            while not self._ready(published) and not stop.is_set():
                left = deadline - time.monotonic()
                if left <= 0:
                    st = self._status
                    raise BagError(
                        f"the node on {self.status_topic} did not finish with the "
                        f"messages played so far within {self.timeout:.0f} s "
                        f"(played {published}, its status: "
                        f"{'none' if st is None else st.get('handled')}, idle "
                        f"{None if st is None else st.get('idle')})"
                    )
                self._cv.wait(timeout=min(left, 0.2))


class Player:
    """Republishes a bag with its original timing (scaled by ``rate``).

    With a ``pace`` (:class:`StatusPacer`), each message waits until the receiving node has
    finished with the ones before it, except within a burst -- a message on the same topic as
    the one before it, recorded at most ``burst_gap`` s after it (a SpaceMouse push at 30 Hz) --
    whose recorded relative timing is kept. The replay then does not depend on how fast the
    node or the machine is."""

    def __init__(
        self,
        node,
        path: str,
        rate: float = 1.0,
        start_offset: float = 0.0,
        topics=None,
        loop: bool = False,
        pace: "StatusPacer | None" = None,
        burst_gap: float = 0.1,
    ):
        rate = check_number("the rate", rate, positive=True, limits=RATE_LIMITS)
        start_offset = check_number("the start offset", start_offset)
        self.node, self.path = node, path
        self.rate, self.start_offset, self.loop = rate, start_offset, loop
        self.pace, self.burst_gap = pace, check_number("the burst gap", burst_gap)
        self.counts: dict[str, int] = {}  # messages published per topic
        reader = _open_reader(path)
        try:
            self.connections = [
                c for c in reader.connections if topics is None or c.topic in topics
            ]
            missing = set(topics or ()) - {c.topic for c in reader.connections}
            if missing:
                raise BagError(f"{path}: no topic(s) {', '.join(sorted(missing))} in the bag")
            self.start = reader.start_time
            duration_s = reader.duration / 1e9 if reader.message_count else 0.0
        finally:
            reader.close()
        if start_offset > 0 and start_offset >= duration_s:
            raise BagError(
                f"the start offset {start_offset:g} s is past the end of {path} "
                f"({duration_s:.2f} s long)"
            )
        self.publishers = {}
        for c in self.connections:
            if c.topic not in self.publishers:
                qos = _from_rosbags_qos(getattr(c.ext, "offered_qos_profiles", []))
                self.publishers[c.topic] = node.create_publisher(
                    message_class(c.msgtype), c.topic, qos
                )
        self.published = 0

    def wait_for_subscribers(self, timeout: float, stop: threading.Event | None = None) -> bool:
        """Wait up to ``timeout`` s (or until ``stop`` is set) for a subscriber on every topic;
        whether there is one."""
        deadline = time.monotonic() + check_number("the subscriber wait", timeout)
        while time.monotonic() < deadline and not (stop is not None and stop.is_set()):
            if all(p.get_subscription_count() > 0 for p in self.publishers.values()):
                return True
            time.sleep(0.05)
        return False

    def play(self, stop: threading.Event | None = None) -> int:
        """Publish every message at its time (or paced); returns the number published."""
        stop = stop or threading.Event()
        while True:
            reader = _open_reader(self.path)
            before = self.published
            try:
                self._play_once(reader, stop)
            except BagError:
                raise
            except Exception as exc:
                raise BagError(
                    f"{self.path}: reading failed ({exc.__class__.__name__}: "
                    f"{exc}); the bag is truncated or corrupt"
                ) from None
            finally:
                reader.close()
            if not self.loop or stop.is_set() or self.published == before:
                return self.published  # (a loop over nothing would never end)

    def _play_once(self, reader, stop: threading.Event) -> None:
        t_bag0 = self.start + int(self.start_offset * 1e9)
        t_wall0 = time.monotonic()
        previous = None  # (topic, stamp) of the message published before
        for conn, stamp, data in reader.messages(connections=self.connections):
            if stamp < t_bag0:
                continue
            if self.pace is not None:
                in_burst = (
                    previous is not None
                    and previous[0] == conn.topic
                    and (stamp - previous[1]) / 1e9 <= self.burst_gap
                )
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
