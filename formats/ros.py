"""ROS logs: ROS1 ``.bag``, ROS2 bag folders (sqlite3 or mcap storage), bare ``.db3`` and
``.mcap`` files through rosbags' ``AnyReader``; MCAP files not written by rosbag2 (e.g. ROS1
messages in MCAP) through the ``mcap`` package with rosbags' type system.

What is read:

* scans: ``sensor_msgs/LaserScan`` on one topic (``--topic``; a bag with several stops with
  a message listing them). Time = ``header.stamp``. Ranges follow REP 117: +inf is "no
  return" (clears free space), NaN, −inf and finite values outside [range_min, range_max]
  are invalid (dropped, counted).
* odometry: ``nav_msgs/Odometry`` (``--odom-topic`` if several), else TF ``odom → base``
  (``base_link``/``base_footprint``), interpolated at each scan's time. With neither, the
  log is said to have no odometry once and runs with the stationary motion prior.
* the laser's mounting pose: (static) TF ``base → <scan frame_id>``, else identity.
* what the scan says of the laser: ``range_min``, ``time_increment`` and ``scan_time``
  travel with each scan (a recording sends them on; one that is negative or not finite is
  unknown).

A ROS 1 bag whose index rosbags cannot use (cut off while recording: no index, a last chunk
cut short; an early writer's index) is read chunk after chunk in file order up to the first
record that cannot be read (``dynslam_formats.rosbag1_chunks``): the index's trouble and
where the data stop being readable are counted warnings. Other bad bags (a pre-2.0
``#ROSRECORD`` bag, a damaged ``.db3``, a damaged message definition) give a one-line error
naming the file and its kind. A LaserScan whose range count contradicts
its angles (``angle_min + (n − 1)·angle_increment`` farther than one increment and 1% of the
span from ``angle_max``) is a counted skip: which of the two is wrong cannot be told. Non-finite
angles or stamps, a zero increment and a bad ``range_max`` are skipped by the common guard
(``dynslam_formats.guard``), which also counts stamps that go backwards or repeat (the scans
are kept in log order).

A ROS 1 bag is sorted by record time; one converted from a log whose clock stepped back is
sorted by the broken stamps, a second of messages shuffled into the second before. Each
publisher numbers its messages (``header.seq``): each topic is read in that order (up to
``REORDER_WINDOW`` messages out of place; a counted warning), and where odometry stamps step
back, scans are paired on the new clock (``dynslam_formats.odometry``).
"""

from __future__ import annotations

import heapq
import math
import struct
from collections import deque
from collections.abc import Callable, Hashable, Iterable, Iterator
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from dynslam_cli.errors import InputError, SeveralTopicsError
from dynslam_cli.types import Pose2D, Scan
from dynslam_formats.base import ReaderOptions, ReadStats, RecordWalk
from dynslam_formats.damage import container_errors, first_line
from dynslam_formats.odometry import OdometryBuffer
from dynslam_formats.source import Source

SCAN_TYPE = "sensor_msgs/msg/LaserScan"
ODOM_TYPE = "nav_msgs/msg/Odometry"
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
BASE_FRAMES = ("base_link", "base_footprint")
ROSBAG1_MAGIC = b"#ROSBAG V2.0"
ROSRECORD_MAGIC = b"#ROSRECORD"
SQLITE_MAGIC = b"SQLite format 3\x00"
MCAP_MAGIC = b"\x89MCAP0\r\n"
REORDER_WINDOW = 512
"""How many messages a ROS 1 bag may hold out of their publication order (``header.seq``)
and still be read in it: a bag converted from a log whose clock stepped back (the
benchmark's Intel bag: up to 27 messages, 0.9 s) is sorted by the broken stamps."""


def sniff(head: bytes) -> bool:
    """ROS1 bags and sqlite3 ROS2 bags; MCAP goes to the mcap entry (which hands ros2-profile
    files back to this reader)."""
    return head.startswith((ROSBAG1_MAGIC, ROSRECORD_MAGIC, SQLITE_MAGIC))


def stamp_of(msg: Any) -> float:
    """A header's stamp in seconds: the float nearest to sec + nanosec/10⁹ (an integer
    division is rounded once, so a stamp written as sec, nanosec reads back as it was)."""
    s = msg.header.stamp
    return (int(s.sec) * 10**9 + int(s.nanosec)) / 10**9


def yaw_of(q: Any) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def span_agrees(msg: Any) -> bool:
    """Whether a LaserScan's range count fits its angles (non-finite ones are the guard's)."""
    lo, hi, inc = float(msg.angle_min), float(msg.angle_max), float(msg.angle_increment)
    n = len(msg.ranges)
    if n < 2 or not (math.isfinite(lo) and math.isfinite(hi) and math.isfinite(inc)):
        return True
    return abs(lo + (n - 1) * inc - hi) <= abs(inc) + 0.01 * abs(hi - lo)


def frame(name: str) -> str:
    return name.lstrip("/")


def known(value: float) -> float | None:
    """A LaserScan's ``range_min``, ``time_increment`` or ``scan_time`` as a :class:`Scan`
    holds it: None (unknown) when negative or not finite."""
    value = float(value)
    return value if math.isfinite(value) and value >= 0 else None


def choose_topic(kind: str, option: str, candidates: dict[str, int], requested: str | None,
                 source: str, required: bool) -> str | None:
    """The one topic of a kind: the requested one, the only one, or an error listing them
    (:class:`SeveralTopicsError`)."""
    if requested is not None:
        if requested not in candidates:
            listing = ", ".join(sorted(candidates)) or "none"
            raise InputError(source, f"no {kind} topic {requested!r} (found: {listing})")
        return requested
    if len(candidates) == 1:
        return next(iter(candidates))
    if not candidates:
        if required:
            raise InputError(source, f"no {kind} messages in this log")
        return None
    raise SeveralTopicsError(source, kind, option, candidates)


def choose_topics(channels: dict[str, tuple[str, int]], options: ReaderOptions, source: str
                  ) -> tuple[str, str | None]:
    """(scan topic, odometry topic or None) from {topic: (message type, message count)}."""
    scans = {t: n for t, (m, n) in channels.items() if m == SCAN_TYPE}
    odoms = {t: n for t, (m, n) in channels.items() if m == ODOM_TYPE}
    scan = choose_topic("LaserScan", "--topic", scans, options.topic, source, True)
    odom = choose_topic("Odometry", "--odom-topic", odoms, options.odom_topic, source, False)
    return scan or "", odom


def container_kind(path: str) -> str:
    """What to call a file the rosbags reader reads, in its errors."""
    if path.endswith(".mcap"):
        return "MCAP file"
    if path.endswith(".db3"):
        return "ROS 2 bag (.db3)"
    return "bag"


def typestore_of(definitions: dict[str, str], ros2: bool = False) -> Any:
    """A rosbags type store holding the types a log's own message definitions give
    ({message type: definition text, ``.msg`` form with its dependencies}), and the types of
    ROS 1 Noetic (ROS 2 Humble) they use but do not define: an early bag defines
    ``roslib/Header``, and its LaserScan's ``Header`` is read as ``std_msgs/Header``."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.EMPTY)
    for msgtype, text in definitions.items():
        store.register(get_types_from_msg(text, msgtype))
    known = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC).fielddefs
    store.register({t: d for t, d in known.items() if t not in store.fielddefs})
    return store


def tally(channels: dict[str, tuple[str, int]], topic: str, msgtype: str, count: int = 1
          ) -> None:
    """Count ``count`` more messages of ``msgtype`` on ``topic`` in ``channels`` ({topic:
    (message type, message count)}, as :func:`log_scans` takes it): a topic may come on
    several connections or channels."""
    channels[topic] = (msgtype, channels.get(topic, ("", 0))[1] + count)


def header_seq(typestore: Any, msgtype: str, raw: bytes) -> int | None:
    """A ROS 1 message's ``header.seq`` (its publisher's count, the first field of the
    serialized message) if its type begins with a ``std_msgs/Header``; else None."""
    fields = typestore.fielddefs.get(msgtype, ((), ()))[1]
    if not fields or fields[0][1][1] != "std_msgs/msg/Header" or len(raw) < 4:
        return None
    return int(struct.unpack_from("<I", raw)[0])


def publication_order(messages: Iterable[tuple[Hashable, int | None, Any]], stats: ReadStats,
                      window: int = REORDER_WINDOW) -> Iterator[Any]:
    """The items of (connection, seq, item) triples given in log order, each connection's
    in the order its publisher numbered them (``seq``; None: as logged). An item comes out
    ``window`` messages late, in the place the log gives its connection's next message, so
    the connections stay interleaved as logged and a log in order comes out as it is. A seq
    that falls back by more than ``window`` is a publisher that restarted: its count begins
    anew after what came before. Messages logged before ones sent earlier are a counted
    warning."""
    heaps: dict[Hashable, list[tuple[tuple[int, int], int, Any]]] = {}
    top: dict[Hashable, tuple[int, int]] = {}  # (restarts, highest seq) of each connection
    slots: deque[Hashable] = deque()  # the connection of each message not yet given out
    early = 0
    for n, (stream, seq, item) in enumerate(messages):
        if seq is None:
            key = (0, n)
        else:
            restarts, high = top.get(stream, (0, -1))
            if seq + window < high:
                restarts, high = restarts + 1, -1
            early += seq < high
            key = (restarts, seq)
            top[stream] = (restarts, max(high, seq))
        heapq.heappush(heaps.setdefault(stream, []), (key, n, item))
        slots.append(stream)
        if len(slots) > window:
            yield heapq.heappop(heaps[slots.popleft()])[2]
    while slots:
        yield heapq.heappop(heaps[slots.popleft()])[2]
    if early:
        stats.warn("messages logged before ones their publisher sent earlier (ROS 1 "
                   "header.seq): read in the order they were sent", count=early)


def log_scans(reader: Any, channels: dict[str, tuple[str, int]],
              messages: Callable[[set[str]], Iterable[tuple[str, str, Any]]]) -> Iterator[Scan]:
    """A log's scans, for every ROS reader: counts the topics (``channels``: {topic: (message
    type, message count)}) in ``reader.stats``, chooses the scan and odometry topics (kept in
    ``reader.topics``), and turns the messages that ``messages`` gives for the topics wanted
    (scan, odometry, TF) into scans."""
    name = reader.source.name
    for topic, (msgtype, count) in channels.items():
        reader.stats.records[f"{topic} ({msgtype})"] += count
    scan_topic, odom_topic = choose_topics(channels, reader.options, name)
    reader.topics = (scan_topic, odom_topic)
    handler = RosMessages(reader.stats, scan_topic, odom_topic, name)
    wanted = {t for t, (m, _) in channels.items()
              if t in (scan_topic, odom_topic) or m in TF_TYPES}
    for topic, msgtype, msg in messages(wanted):
        yield from handler.feed(topic, msgtype, msg)
    yield from handler.finish()
    if reader.stats.scans == 0:
        raise InputError(name, f"no scans on {scan_topic}")


class RosMessages:
    """Turns deserialized messages, in log order, into :class:`Scan` records. Shared by the
    rosbags reader and the plain-MCAP reader."""

    def __init__(self, stats: ReadStats, scan_topic: str, odom_topic: str | None,
                 source: str) -> None:
        self.stats = stats
        self.source = source
        self.scan_topic = scan_topic
        self.odom_topic = odom_topic
        self.buffer = OdometryBuffer(stats)
        self.mounts: dict[str, Pose2D] = {}
        self.base: str | None = None
        self.tf_odometry = odom_topic is None

    def feed(self, topic: str, msgtype: str, msg: Any) -> Iterator[Scan]:
        """The scans ``msg`` completes. A message without the fields of its type (a log's own
        damaged message definition) is an :class:`InputError` naming the source."""
        try:
            yield from self._feed(topic, msgtype, msg)
        except AttributeError as e:
            raise InputError(self.source, f"a {msgtype} message on {topic} has no field "
                             f"{e.name!r}: is the log's message definition damaged?") from None

    def _feed(self, topic: str, msgtype: str, msg: Any) -> Iterator[Scan]:
        if topic == self.scan_topic:
            if not span_agrees(msg):
                self.stats.skip("LaserScan range count contradicts angle_min/max/increment")
                return
            yield from self._ready(self.buffer.add_scan(stamp_of(msg), self._scan(msg)))
        elif topic == self.odom_topic:
            p = msg.pose.pose
            self.base = self.base or frame(msg.child_frame_id) or None
            yield from self._ready(self.buffer.add_odometry(
                stamp_of(msg), Pose2D(float(p.position.x), float(p.position.y),
                                      yaw_of(p.orientation))))
        elif msgtype in TF_TYPES:
            for tf in msg.transforms:
                yield from self._transform(tf)

    def _transform(self, tf: Any) -> Iterator[Scan]:
        parent, child = frame(tf.header.frame_id), frame(tf.child_frame_id)
        t = tf.transform
        pose = Pose2D(float(t.translation.x), float(t.translation.y), yaw_of(t.rotation))
        if parent in BASE_FRAMES or parent == self.base:
            self.mounts[child] = pose
        if self.tf_odometry and child in BASE_FRAMES and parent.endswith("odom"):
            self.base = self.base or child
            if child == self.base:
                yield from self._ready(self.buffer.add_odometry(stamp_of(tf), pose))

    def _scan(self, msg: Any) -> tuple[float, np.ndarray, np.ndarray, float, str,
                                       tuple[float | None, ...]]:
        with np.errstate(invalid="ignore", over="ignore"):  # damaged payloads: counted below
            r = np.asarray(msg.ranges, dtype=np.float64)
        lo, hi = float(msg.range_min), float(msg.range_max)
        with np.errstate(invalid="ignore"):
            invalid = np.isnan(r) | np.isneginf(r) | (np.isfinite(r) & ((r < lo) | (r > hi)))
        if invalid.any():
            self.stats.warn("invalid ranges (NaN, -inf or outside [range_min, range_max]): "
                            "beam dropped", count=int(invalid.sum()))
            r[invalid] = np.nan
        n = len(r)
        angles = float(msg.angle_min) + float(msg.angle_increment) * np.arange(n)
        sweep = (known(msg.range_min), known(msg.time_increment), known(msg.scan_time))
        return stamp_of(msg), r, angles, hi, frame(msg.header.frame_id), sweep

    def finish(self) -> Iterator[Scan]:
        yield from self._ready(self.buffer.finish())

    def _ready(self, ready: Iterable[tuple[object, Pose2D | None, int]]) -> Iterator[Scan]:
        for payload, pose, _ in ready:
            stamp, ranges, angles, max_range, frame_id, sweep = payload  # type: ignore[misc]
            if pose is None:
                self.stats.warn("no odometry (nav_msgs/Odometry or TF odom → base) in the "
                                "log: stationary motion prior")
            self.stats.scans += 1
            yield Scan(stamp, ranges, angles, max_range, pose or Pose2D(),
                       self.mounts.get(frame_id, Pose2D()), 0, pose is not None, *sweep)


class RosbagsReader:
    """ROS1/ROS2 bags through ``rosbags.highlevel.AnyReader``."""

    format_name: ClassVar[str] = "ros"

    def __init__(self, source: Source, options: ReaderOptions) -> None:
        self.source = source
        self.options = options
        self.stats = ReadStats()
        self.topics: tuple[str | None, str | None] | None = None
        if source.path == "-":
            raise InputError(source.name, "bags cannot be read from standard input")
        if source.head.startswith(ROSRECORD_MAGIC):
            raise InputError(source.name, "pre-2.0 ROS bag (#ROSRECORD V1.2) is not supported; "
                             "convert it with 'rosbag fix' first")

    def scans(self) -> Iterator[Scan]:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore

        name, kind = self.source.name, container_kind(self.source.path)
        with container_errors(name, kind):
            bag = AnyReader([Path(self.source.path)],
                            default_typestore=get_typestore(Stores.ROS2_HUMBLE))
            try:
                bag.open()
            except Exception as e:  # (rosbags': AnyReaderError, AssertionError, struct.error)
                if not self.source.head.startswith(ROSBAG1_MAGIC):
                    raise InputError(name, f"cannot read this {kind}: {first_line(e)}"
                                     ) from None
                yield from self._chunk_scans(first_line(e))
                return
            try:
                yield from self._read(bag)
            finally:
                bag.close()

    def _read(self, bag: Any) -> Iterator[Scan]:
        channels: dict[str, tuple[str, int]] = {}
        for c in bag.connections:
            tally(channels, c.topic, c.msgtype, c.msgcount)

        def messages(wanted: set[str]) -> Iterator[tuple[str, str, Any]]:
            chosen = [c for c in bag.connections if c.topic in wanted]
            found = ((c.id, None if bag.is2 else header_seq(bag.typestore, c.msgtype, raw),
                      (c, raw)) for c, _, raw in bag.messages(connections=chosen))
            for conn, raw in publication_order(found, self.stats):
                yield conn.topic, conn.msgtype, bag.deserialize(raw, conn.msgtype)

        yield from log_scans(self, channels, messages)

    def _chunk_scans(self, index_trouble: str) -> Iterator[Scan]:
        """A ROS 1 bag's scans from its chunks read one after another (its index cannot be
        used: ``index_trouble`` says why): a first walk finds the topics, a second decodes."""
        from dynslam_formats.rosbag1_chunks import chunk_messages

        name, path = self.source.name, Path(self.source.path)
        survey = RecordWalk()
        channels: dict[str, tuple[str, int]] = {}
        definitions: dict[str, str] = {}
        for conn, _ in chunk_messages(path, survey):
            tally(channels, conn.topic, conn.msgtype)
            definitions[conn.msgtype] = conn.msgdef
        if survey.messages == 0 and survey.damage is not None:
            raise InputError(name, f"cannot read this bag: neither its index ({index_trouble}) "
                             f"nor its chunks (from byte {survey.stop}: {survey.damage})")
        self.stats.warn(f"bag index not usable ({index_trouble}): its chunks were read one "
                        "after another ('rosbag reindex' would rebuild the index)")
        survey.report(self.stats, self.source.size)
        store = typestore_of(definitions)

        def messages(wanted: set[str]) -> Iterator[tuple[str, str, Any]]:
            found = ((conn, header_seq(store, conn.msgtype, raw), (conn, raw))
                     for conn, raw in chunk_messages(path, RecordWalk()) if conn.topic in wanted)
            for conn, raw in publication_order(found, self.stats):
                yield conn.topic, conn.msgtype, store.deserialize_ros1(raw, conn.msgtype)

        yield from log_scans(self, channels, messages)
