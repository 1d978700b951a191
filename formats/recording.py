"""A recording of the run for playback (Foxglove, RViz through ``ros2 bag play``): an MCAP
file in the ROS 2 profile, CDR-encoded standard messages (rosbags' serializer, the ``mcap``
package's writer; no ROS install). Every stamp is log time.

====================  ===================================  =================================
topic                 type                                 sent
====================  ===================================  =================================
``/tf_static``        tf2_msgs/TFMessage                   base_link → laser, at the first
                                                           scan (the readers' guard holds a
                                                           mount steady within 10 µm, 10 µrad)
``/tf``               tf2_msgs/TFMessage                   every scan: map → odom (the
                                                           correction), odom → base_link
                                                           (the log's odometry), REP 105
                                                           (a log without odometry: map →
                                                           base_link);
                                                           base_link → laser too when the
                                                           mount really moved
``/scan``             sensor_msgs/LaserScan                every scan, as read (+inf: no
                                                           return, REP 117); range_min,
                                                           time_increment and scan_time
                                                           the log's (see below)
``/map``              nav_msgs/OccupancyGrid               S, every ``period_s`` of log time
``/dynamic_map``      nav_msgs/OccupancyGrid               D, the same
``/path``             nav_msgs/Path                        the estimate so far, the same
``/odometry_path``    nav_msgs/Path                        the log's odometry, the same
``/landmarks``        visualization_msgs/MarkerArray       corners, static green, dynamic
                                                           orange, the same
``/changes``          visualization_msgs/MarkerArray       changes.csv's events: at each
                                                           event's first sighting, every
                                                           event seen by then (a disc of
                                                           its size and a label, colours
                                                           of map.png); then the final list
====================  ===================================  =================================

The events are known once the run is over (with the pose graph they are read from the maps
rebuilt on the optimized trajectory), so ``/changes`` is written at the end, each message
stamped with the log time its event was first seen: played back, each event appears when
it happened.

Grids and landmarks are sent only when they changed, and all of them once more at the end,
after the pose graph's final optimization: that last ``/map`` is ``static.pgm`` cell for cell
(OccupancyGrid −1 unknown, 0 free, 100 occupied: the trinary classes), that last ``/path``
is ``trajectory.tum``. While the run goes on, the paths hold a pose every ``PATH_STEP_M`` or
``PATH_STEP_RAD`` of the robot's motion, and never more than ``PATH_MAX_POSES``: when the
path reaches that, every other pose goes and the steps double (a path of every scan, sent
every period, would grow with the square of the log's length). The map frame is the
odometry frame of the first scan, so ``/odometry_path`` (frame ``map``) shows the log's
odometry where it drifts from the estimate.

A ``/scan``'s ``range_min``, ``time_increment`` and ``scan_time`` are the log's where it
says them (a bag's LaserScan). Carmen and Player logs do not: no record holds a minimum
range or a sweep's timing (ROBOTLASER's ``accuracy`` is the range resolution; a laser type
code names no model's timing), so ``range_min`` is then ``laser.min_range_m``, below which
the run drops readings, and the two times are 0, LaserScan's "not known".
"""

from __future__ import annotations

import math
from array import array
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from dynslam_cli import __version__
from dynslam_cli.geometry import compose, inverse, moved_far
from dynslam_cli.mapping.changes import ChangeEvent
from dynslam_cli.mapping.grid import GridStack, OccupancyMap, probability
from dynslam_cli.result import Landmark, SlamResult
from dynslam_cli.sections import MapConfig
from dynslam_cli.types import Pose2D, Scan
from dynslam_formats.guard import beam_geometry
from dynslam_formats.mapfile import class_masks
from dynslam_formats.picture import CHANGE_RGB, LANDMARK_RGB

MAP_FRAME, ODOM_FRAME, BASE_FRAME, LASER_FRAME = "map", "odom", "base_link", "laser"
UNKNOWN, FREE, OCCUPIED = -1, 0, 100  # nav_msgs/OccupancyGrid cell values
PATH_STEP_M, PATH_STEP_RAD = 0.1, math.radians(5.0)
PATH_MAX_POSES = 1000  # in a running /path (the last one holds every scan)
LANDMARK_DIAMETER_M = 0.2
EVENT_MIN_DIAMETER_M = 0.3  # an event's disc is as wide as its size, and at least this
PATH_WIDTH_M = 0.05  # a mover's path: a line this wide

TF, SCAN, GRID, PATH, MARKERS = ("tf2_msgs/msg/TFMessage", "sensor_msgs/msg/LaserScan",
                                 "nav_msgs/msg/OccupancyGrid", "nav_msgs/msg/Path",
                                 "visualization_msgs/msg/MarkerArray")
TOPICS: tuple[tuple[str, str, bool], ...] = (  # (topic, type, latched: transient local)
    ("/tf_static", TF, True), ("/tf", TF, False), ("/scan", SCAN, False),
    ("/map", GRID, True), ("/dynamic_map", GRID, True), ("/path", PATH, False),
    ("/odometry_path", PATH, False), ("/landmarks", MARKERS, False),
    ("/changes", MARKERS, True))


def occupancy_values(prob: np.ndarray, free_thresh: float, occupied_thresh: float
                     ) -> np.ndarray:
    """OccupancyGrid values (int8: −1, 0, 100) of probabilities, classed as the PGM is."""
    free, occupied = class_masks(prob, free_thresh, occupied_thresh)
    values = np.full(prob.shape, UNKNOWN, np.int8)
    values[free] = FREE
    values[occupied] = OCCUPIED
    return values


class StoredClasses:
    """:func:`occupancy_values` of a grid layer's stored values (int16 steps), by two
    comparisons: the steps where the classes change are found once, over every value a cell
    can hold, with the probabilities the map writers use (so the classes are theirs)."""

    def __init__(self, free_thresh: float, occupied_thresh: float) -> None:
        stored = np.arange(-(1 << 15), 1 << 15, dtype=np.int32).astype(np.int16)
        values = occupancy_values(probability(stored), free_thresh, occupied_thresh)
        self.free_max = int(stored[values == FREE].max())  # (probability rises with steps)
        self.occupied_min = int(stored[values == OCCUPIED].min())

    def __call__(self, stored: np.ndarray) -> np.ndarray:
        occupied = stored >= self.occupied_min
        values = occupied.view(np.int8) * np.int8(OCCUPIED)
        values -= ((stored > self.free_max) & ~occupied).view(np.int8)  # unknown: −1
        return values


def qos_profiles(latched: bool) -> str:
    """The ``offered_qos_profiles`` channel metadata rosbag2 writes: reliable, keep last;
    transient local for latched topics (a late subscriber gets the last map)."""
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )
    from rosbags.rosbag2.metadata import dump_qos_v8

    forever = QosTime(2147483647, 4294967295)
    return dump_qos_v8([Qos(
        QosHistory.KEEP_LAST, 1 if latched else 10, QosReliability.RELIABLE,
        QosDurability.TRANSIENT_LOCAL if latched else QosDurability.VOLATILE, forever, forever,
        QosLiveliness.AUTOMATIC, forever, False)])


def stamps(seconds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """builtin_interfaces/Time (sec, nanosec) of stamps in seconds, to the nearest
    nanosecond: whole seconds apart, as ``seconds · 10⁹`` would round a log's epoch stamps
    to 256 ns (and the ROS reader's ``stamp_of`` gives each stamp back as it was)."""
    sec = np.floor(seconds)
    nanosec = np.rint((seconds - sec) * 1e9).astype(np.int64)  # (seconds − sec is exact)
    carry = nanosec == 10**9
    return sec.astype(np.int64) + carry, np.where(carry, 0, nanosec)


def _or(known: float | None, otherwise: float) -> float:
    """A value the log says (not None), else ``otherwise``."""
    return otherwise if known is None else known


def _stamp(stamp: float) -> tuple[int, int]:
    sec, nanosec = stamps(np.array([stamp]))
    return int(sec[0]), int(nanosec[0])


def path_cdr(stamp: float, frame: str, rows: np.ndarray) -> bytes:
    """A nav_msgs/Path (every pose in ``frame``) from N×4 (stamp, x, y, θ) rows, CDR-encoded
    as rosbags' serializer does it (a test holds them byte for byte equal) but by whole
    arrays: made of message objects, a path of 2 000 poses takes 15 ms.

    CDR (little endian, after a 4-byte encapsulation header) aligns each number to its
    size: a pose's header (sec, nanosec, frame_id's length and bytes with its NUL) is 4-byte
    aligned, its 7 float64 (position, orientation) 8-byte aligned."""
    name = frame.encode() + b"\0"
    length = len(name)

    def header_bytes(t: float) -> bytes:
        return np.array([*_stamp(t), length], np.uint32).tobytes() + name

    def aligned(n: int, k: int) -> int:
        return -(-n // k) * k

    head = header_bytes(stamp)
    head += bytes(aligned(len(head), 4) - len(head)) + np.uint32(len(rows)).tobytes()
    first = len(head)  # the first pose's offset; every later one starts 8-byte aligned
    doubles = [aligned(s + 12 + length, 8) - s for s in (first, aligned(first + 1, 8))]
    sizes = [d + 56 for d in doubles]
    n = len(rows)
    out = np.zeros(first + (sizes[0] + (n - 1) * sizes[1] if n else 0), np.uint8)
    out[:first] = np.frombuffer(head, np.uint8)
    sec, nsec = stamps(rows[:, 0])
    half = 0.5 * rows[:, 3]
    pose = np.zeros((n, 7))
    pose[:, 0], pose[:, 1], pose[:, 5], pose[:, 6] = rows[:, 1], rows[:, 2], np.sin(half), \
        np.cos(half)
    parts = ((0, min(n, 1), first, sizes[0], doubles[0]),  # (poses lo:hi, byte offset,
             (1, n, first + sizes[0], sizes[1], doubles[1]))  # pose size, doubles at)
    for lo, hi, start, size, at in parts:
        k, take = hi - lo, slice(lo, hi)
        if k <= 0:
            continue
        cells = out[start:start + k * size].reshape(k, size)
        cells[:, 0:4] = sec[take].astype(np.int32).view(np.uint8).reshape(k, 4)
        cells[:, 4:8] = nsec[take].astype(np.uint32).view(np.uint8).reshape(k, 4)
        cells[:, 8:12] = np.frombuffer(np.uint32(length).tobytes(), np.uint8)
        cells[:, 12:12 + length] = np.frombuffer(name, np.uint8)
        cells[:, at:at + 56] = pose[take].view(np.uint8).reshape(k, 56)
    return b"\0\x01\0\0" + out.tobytes()


class RunningSlam(Protocol):
    """What the recording reads of a run while it goes on (dynslam_cli.pipeline.DynamicSlam
    is one): the last pose, the grids, the current estimates of given scans and the
    landmark map so far."""

    @property
    def pose(self) -> Pose2D: ...

    @property
    def grids(self) -> GridStack: ...

    def estimates(self, scans: np.ndarray | None = None) -> np.ndarray: ...

    def landmarks(self) -> list[Landmark]: ...


class Recording:
    """Writes the recording of one run into ``path`` (inside the run's temporary output
    folder, so it appears with the other outputs or not at all): :meth:`add` after each
    scan, :meth:`finish` with the result, :meth:`close` in every case."""

    def __init__(self, path: Path, period_s: float, m: MapConfig, min_range_m: float) -> None:
        """``period_s``: the maps, paths and landmarks at most this often (log time);
        ``m``: the maps' thresholds; ``min_range_m``: a scan's range_min where its log
        gives none."""
        from mcap.writer import CompressionType, Writer
        from rosbags.typesys import Stores, get_typestore

        self.path = path
        self.period = period_s
        self._map = m
        self._min_range_m = min_range_m
        self.store = get_typestore(Stores.ROS2_HUMBLE)
        self.t = self.store.types
        self.classes = StoredClasses(m.free_threshold, m.occupied_threshold)
        self._file = open(path, "wb")  # noqa: SIM115 - closed by close()
        self.writer = Writer(self._file, compression=CompressionType.ZSTD)
        self.writer.start(profile="ros2", library=f"dynslam {__version__}")
        self.channels: dict[str, int] = {}
        schemas: dict[str, int] = {}
        for topic, msgtype, latched in TOPICS:
            if msgtype not in schemas:
                text = self.store.generate_msgdef(msgtype, ros_version=2)[0]
                schemas[msgtype] = self.writer.register_schema(msgtype, "ros2msg", text.encode())
            self.channels[topic] = self.writer.register_channel(
                topic, "cdr", schemas[msgtype], {"offered_qos_profiles": qos_profiles(latched)})
        self.counts = dict.fromkeys(self.channels, 0)
        self._mount: Pose2D | None = None
        self._next_s = -math.inf
        self._last_sent: dict[str, Any] = {}
        self._keys = array("q")  # the scans the paths hold while running
        self._key_pose: Pose2D | None = None
        self._step_m, self._step_rad = PATH_STEP_M, PATH_STEP_RAD
        self._odometry = array("d")  # (stamp, x, y, θ) of every scan
        self._has_odometry = False
        self._time_of, self._time_value = math.nan, (0, 0)

    # -- per scan -------------------------------------------------------------------------
    def add(self, scan: Scan, slam: RunningSlam) -> None:
        """Record one scan the run has processed (as the run saw it: its max range the
        configuration's): its TF, the scan, and every ``period_s`` of log time the grids,
        paths and landmarks."""
        stamp, pose, odom = scan.stamp, slam.pose, scan.odom
        if self._mount is None:
            self._mount = scan.laser
            self._send("/tf_static", stamp, self._tf_message(
                stamp, [(BASE_FRAME, LASER_FRAME, scan.laser)]))
        links = ([(MAP_FRAME, ODOM_FRAME, compose(pose, inverse(odom))),
                  (ODOM_FRAME, BASE_FRAME, odom)] if scan.has_odometry
                 else [(MAP_FRAME, BASE_FRAME, pose)])  # (no odom frame: none in the log)
        if scan.laser != self._mount:  # (a mount held steady: see guard.SteadyMount)
            self._mount = scan.laser
            links.append((BASE_FRAME, LASER_FRAME, scan.laser))
        self._send("/tf", stamp, self._tf_message(stamp, links))
        self._send("/scan", stamp, self._laser_scan(scan))
        self._odometry.extend((stamp, odom.x, odom.y, odom.theta))
        self._has_odometry = self._has_odometry or scan.has_odometry
        if self._key_pose is None or moved_far(self._key_pose, pose, self._step_m,
                                               self._step_rad):
            self._keys.append(len(self._odometry) // 4 - 1)
            self._key_pose = pose
            if len(self._keys) > PATH_MAX_POSES:
                self._keys = self._keys[::2]
                self._step_m, self._step_rad = 2 * self._step_m, 2 * self._step_rad
        if stamp >= self._next_s:
            self._next_s = stamp + self.period
            self._send_state(stamp, slam)

    def _send_state(self, stamp: float, slam: RunningSlam) -> None:
        """The grids (if changed), the paths so far, the landmarks (if changed)."""
        grids = slam.grids
        for topic, layer in (("/map", "static"), ("/dynamic_map", "dynamic")):
            values, ox, oy = grids.mapped(layer, self.classes)
            self._send_grid(topic, stamp, values, ox, oy, grids.resolution)
        odometry = self._odometry_rows()
        keys = np.frombuffer(self._keys, np.int64)
        if keys[-1] != len(odometry) - 1:  # (and the latest scan)
            keys = np.append(keys, len(odometry) - 1)
        self._send_paths(stamp, np.column_stack((odometry[keys, 0], slam.estimates(keys))),
                         odometry[keys])
        self._send_landmarks(stamp, slam.landmarks())

    # -- at the end -----------------------------------------------------------------------
    def finish(self, result: SlamResult) -> dict[str, Any]:
        """The final state (the maps and landmarks as written, the optimized trajectory),
        then the file's index; returns what the summary says of the recording."""
        odometry = self._odometry_rows()
        stamp = float(result.trajectory[-1, 0]) if len(result.trajectory) else 0.0
        m = self._map
        for topic, grid in (("/map", result.static), ("/dynamic_map", result.dynamic)):
            self._send_grid(topic, stamp, self._grid_values(grid, m), grid.origin_x,
                            grid.origin_y, grid.resolution)
        self._send_paths(stamp, result.trajectory, odometry)
        self._send_landmarks(stamp, result.landmarks)
        self._send_changes(stamp, result.changes)
        self.close()
        return {"file": self.path.name, "bytes": self.path.stat().st_size,
                "period_s": self.period, "messages": dict(sorted(self.counts.items()))}

    def _odometry_rows(self) -> np.ndarray:
        """Every scan's (stamp, x, y, θ) so far, N×4: a view, no copy of the growing log
        (let go before the next scan: an array lending its buffer cannot grow)."""
        return np.frombuffer(self._odometry, np.float64).reshape(-1, 4)

    @staticmethod
    def _grid_values(grid: OccupancyMap, m: MapConfig) -> np.ndarray:
        return np.concatenate([occupancy_values(prob, m.free_threshold, m.occupied_threshold)
                               for _, prob in grid.bands()]) if grid.shape[0] else \
            np.zeros(grid.shape, np.int8)

    def close(self) -> None:
        """End the file (its summary and index); safe to call twice."""
        if self._file.closed:
            return
        try:
            self.writer.finish()
        finally:
            self._file.close()

    # -- messages -------------------------------------------------------------------------
    def _send(self, topic: str, stamp: float, msg: Any) -> None:
        self._send_data(topic, stamp, self.store.serialize_cdr(msg, msg.__msgtype__))

    def _time(self, stamp: float) -> tuple[int, int]:
        """:func:`_stamp`, once per stamp (a scan's messages share it)."""
        if stamp != self._time_of:
            self._time_of, self._time_value = stamp, _stamp(stamp)
        return self._time_value

    def _send_data(self, topic: str, stamp: float, data: bytes) -> None:
        sec, nanosec = self._time(stamp)
        ns = max(0, sec * 10**9 + nanosec)
        self.writer.add_message(self.channels[topic], log_time=ns, data=data, publish_time=ns,
                                sequence=self.counts[topic])
        self.counts[topic] += 1

    def _header(self, stamp: float, frame: str) -> Any:
        sec, nanosec = self._time(stamp)
        return self.t["std_msgs/msg/Header"](
            stamp=self.t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec),
            frame_id=frame)

    def _pose(self, x: float, y: float, theta: float) -> Any:
        t = self.t
        return t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0),
            orientation=self._quaternion(theta))

    def _quaternion(self, theta: float) -> Any:
        return self.t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(0.5 * theta),
                                                       w=math.cos(0.5 * theta))

    def _tf_message(self, stamp: float, links: list[tuple[str, str, Pose2D]]) -> Any:
        t = self.t
        return t[TF](transforms=[t["geometry_msgs/msg/TransformStamped"](
            header=self._header(stamp, parent), child_frame_id=child,
            transform=t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](x=p.x, y=p.y, z=0.0),
                rotation=self._quaternion(p.theta)))
            for parent, child, p in links])

    def _laser_scan(self, scan: Scan) -> Any:
        start, step = beam_geometry(scan.angles)
        ranges = np.where(scan.ranges >= scan.max_range, np.inf, scan.ranges)
        return self.t[SCAN](
            header=self._header(scan.stamp, LASER_FRAME), angle_min=start,
            angle_max=float(scan.angles[-1]), angle_increment=step,
            time_increment=_or(scan.time_increment, 0.0), scan_time=_or(scan.scan_time, 0.0),
            range_min=_or(scan.range_min, self._min_range_m),
            range_max=float(scan.max_range), ranges=ranges.astype(np.float32),
            intensities=np.zeros(0, np.float32))

    def _send_grid(self, topic: str, stamp: float, values: np.ndarray, origin_x: float,
                   origin_y: float, resolution: float) -> None:
        key = (values.shape, origin_x, origin_y)
        last = self._last_sent.get(topic)
        if last is not None and last[0] == key and np.array_equal(last[1], values):
            return
        self._last_sent[topic] = (key, values)
        rows, cols = values.shape
        t = self.t
        info = t["nav_msgs/msg/MapMetaData"](
            map_load_time=self._header(stamp, "").stamp, resolution=float(resolution),
            width=cols, height=rows, origin=self._pose(origin_x, origin_y, 0.0))
        self._send(topic, stamp, t[GRID](header=self._header(stamp, MAP_FRAME), info=info,
                                         data=values.reshape(-1)))

    def _send_paths(self, stamp: float, estimate: np.ndarray, odometry: np.ndarray) -> None:
        """``/path`` and ``/odometry_path`` from N×4 (stamp, x, y, θ) rows."""
        paths = [("/path", estimate)] + ([("/odometry_path", odometry)]
                                         if self._has_odometry else [])
        for topic, rows in paths:
            self._send_data(topic, stamp, path_cdr(stamp, MAP_FRAME, rows))

    def _send_landmarks(self, stamp: float, landmarks: list[Landmark]) -> None:
        """One sphere list per class (static, dynamic); sent when a landmark moved, came or
        changed class."""
        state = tuple((lm.id, round(lm.x, 3), round(lm.y, 3), lm.cls) for lm in landmarks)
        if self._last_sent.get("/landmarks") == state:
            return
        self._last_sent["/landmarks"] = state
        markers = []
        for k, cls in enumerate(("static", "dynamic")):
            points = [self.t["geometry_msgs/msg/Point"](x=lm.x, y=lm.y, z=0.0)
                      for lm in landmarks if lm.cls == cls]
            d = LANDMARK_DIAMETER_M
            markers.append(self._marker(stamp, f"{cls} landmarks", k, "SPHERE_LIST",
                                        (0.0, 0.0), (d, d, d), LANDMARK_RGB[cls],
                                        points=points, add=bool(points)))
        self._send("/landmarks", stamp, self.t[MARKERS](markers=markers))

    def _send_changes(self, stamp: float, events: list[ChangeEvent]) -> None:
        """At each event's first sighting, every event seen by then; at ``stamp`` (the
        run's end) the final list (an empty one if nothing changed)."""
        events = sorted(events, key=lambda e: (e.first_s, e.id))
        for k, e in enumerate(events):
            if k + 1 < len(events) and events[k + 1].first_s == e.first_s:
                continue  # (one message for events first seen together)
            self._send("/changes", min(e.first_s, stamp), self._event_markers(
                min(e.first_s, stamp), events[:k + 1]))
        self._send("/changes", stamp, self._event_markers(stamp, events))

    def _event_markers(self, stamp: float, events: list[ChangeEvent]) -> Any:
        """A disc and a label per event, in changes.csv's colours of map.png; a mover with
        a path is its path (a thin line, as map.png draws it), about its centre."""
        markers = []
        point = self.t["geometry_msgs/msg/Point"]
        for e in events:
            rgb = CHANGE_RGB[e.kind]
            if len(e.path) >= 2:
                path = [point(x=x - e.x, y=y - e.y, z=0.0) for x, y in e.path]
                markers.append(self._marker(stamp, e.kind, e.id, "LINE_STRIP", (e.x, e.y),
                                            (PATH_WIDTH_M, 0.0, 0.0), rgb, points=path))
            else:
                d = max(math.sqrt(e.size_m2), EVENT_MIN_DIAMETER_M)
                markers.append(self._marker(stamp, e.kind, e.id, "CYLINDER", (e.x, e.y),
                                            (d, d, 0.02), rgb, alpha=0.5))
            markers.append(self._marker(stamp, f"{e.kind} labels", e.id, "TEXT_VIEW_FACING",
                                        (e.x, e.y), (0.0, 0.0, 0.3), rgb,
                                        text=f"{e.id} {e.kind}"))
        return self.t[MARKERS](markers=markers)

    def _marker(self, stamp: float, ns: str, ident: int, kind: str, at: tuple[float, float],
                scale: tuple[float, float, float], rgb: tuple[int, int, int],
                points: list[Any] | None = None, add: bool = True, alpha: float = 1.0,
                text: str = "") -> Any:
        """A visualization_msgs/Marker of type ``kind`` (the message's constant's name) in
        the map frame, for ever (lifetime 0)."""
        t = self.t
        Marker = t["visualization_msgs/msg/Marker"]  # noqa: N806 - a message class
        r, g, b = (c / 255.0 for c in rgb)
        return Marker(
            header=self._header(stamp, MAP_FRAME), ns=ns, id=ident,
            type=getattr(Marker, kind), action=Marker.ADD if add else Marker.DELETE,
            pose=self._pose(at[0], at[1], 0.0),
            scale=t["geometry_msgs/msg/Vector3"](x=scale[0], y=scale[1], z=scale[2]),
            color=t["std_msgs/msg/ColorRGBA"](r=r, g=g, b=b, a=alpha),
            lifetime=t["builtin_interfaces/msg/Duration"](sec=0, nanosec=0),
            frame_locked=False, points=points or [], colors=[], texture_resource="",
            texture=t["sensor_msgs/msg/CompressedImage"](
                header=self._header(stamp, ""), format="", data=np.zeros(0, np.uint8)),
            uv_coordinates=[], text=text, mesh_resource="",
            mesh_file=t["visualization_msgs/msg/MeshFile"](
                filename="", data=np.zeros(0, np.uint8)),
            mesh_use_embedded_materials=False)
