"""The SLAM loop: a stream of scans in; maps, landmarks and the trajectory out.

Each step follows the paper: localize the robot by EKF-SLAM over corner landmarks (Sec. 4:
predict from odometry, detect corners, associate, classify landmarks by S^{t-1} with Table 3,
update with the static ones), then classify what the scan saw against S^{t-1} and update S
(Eq. 12, Table 1) and D (Eq. 13, Table 2) from the corrected pose. The map frame is the
odometry frame of the first scan.

Ablations (paper Fig. 3): ``ekf.localization = "odometry"`` uses odometry alone;
``dynamic.enabled = false`` keeps one ordinary grid, D stays empty and every landmark
counts as static.
"""

from __future__ import annotations

import math
from array import array
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from dynslam_cli.config import Config
from dynslam_cli.geometry import compose, relative, transform_points, wrap_angles
from dynslam_cli.localization.cornerslam import CornerSlam
from dynslam_cli.localization.frontend import Measure, Measurement
from dynslam_cli.localization.loops import LoopCloser
from dynslam_cli.localization.scanmatch import scan_points
from dynslam_cli.mapping.changes import ChangeEvent, change_events
from dynslam_cli.mapping.dynamic import (
    TABLE_3,
    DynamicMapper,
)
from dynslam_cli.mapping.grid import GridStack, OccupancyMap
from dynslam_cli.types import Pose2D, Scan


@dataclass(frozen=True)
class Landmark:
    """A corner landmark in the map frame."""

    id: int
    x: float
    y: float
    kind: str  # "convex" | "concave"
    cls: str  # "static" | "dynamic"
    observations: int
    cov_xx: float = 0.0
    cov_xy: float = 0.0
    cov_yy: float = 0.0


@dataclass
class SlamResult:
    """Everything the writers need."""

    static: OccupancyMap
    dynamic: OccupancyMap
    trajectory: np.ndarray  # N×4: stamp (s), x (m), y (m), theta (rad)
    landmarks: list[Landmark] = field(default_factory=list)
    localization: dict[str, int] = field(default_factory=dict)
    """Counts for the summary: scan matches, fallbacks, graph nodes, loop closures."""
    grid_memory: dict[str, float] = field(default_factory=dict)
    """What the final grids hold: tiles, cells stored and seen, bytes per cell seen."""
    changes: list[ChangeEvent] = field(default_factory=list)
    """What changed in the world during the run (final results only)."""


class ScanStore:
    """The scans of the run, kept compactly so the maps can be rebuilt from the optimized
    trajectory at the end: the ranges as float32 (what the rebuild reads), and as 16-bit
    whole millimetres or centimetres where that gives back exactly those float32 values
    (text logs are written to the mm or cm: 2 bytes a reading); the beam angles and mounting
    poses shared; no Python object per scan (a 4 h log has 144 000 scans). Scans are coded
    ``BATCH`` at a time, so the coding costs next to nothing a scan."""

    UNITS_M = (0.001, 0.01)  # the 16-bit codes count these
    NO_RETURN, INVALID = 65534, 65535  # codes of +inf and NaN
    BATCH = 256

    def __init__(self) -> None:
        self._codes = array("H")  # the 16-bit scans' readings, one after another ...
        self._floats = array("f")  # ... and the others'
        self._where = array("q")  # per scan: its first reading (negative: -1 - index in _floats)
        self._kind = array("b")  # per scan: index in UNITS_M, or -1 for float32
        self._stamps = array("d")
        self._max_range = array("d")
        self._geometry = array("i")  # per scan: index into _shapes
        self._shapes: list[tuple[np.ndarray, Pose2D]] = []  # (angles, laser) met so far
        self._shape_ids: dict[tuple, int] = {}
        self._batch: list[np.ndarray] = []  # float32 ranges of scans not coded yet

    def add(self, scan: Scan) -> None:
        a, laser = scan.angles, scan.laser
        key = ((len(a), float(a[0]), float(a[-1])) if len(a) else (0, 0.0, 0.0),
               (laser.x, laser.y, laser.theta))
        shape = self._shape_ids.setdefault(key, len(self._shapes))
        if shape == len(self._shapes):
            self._shapes.append((a, laser))
        if self._batch and len(self._batch[0]) != len(a):
            self._code_batch()  # (a batch is one beam count)
        self._batch.append(scan.ranges.astype(np.float32))
        self._stamps.append(scan.stamp)
        self._max_range.append(scan.max_range)
        self._geometry.append(shape)
        if len(self._batch) == self.BATCH:
            self._code_batch()

    def _code_batch(self) -> None:
        """Code the waiting scans: each in the first unit of ``UNITS_M`` that gives back
        exactly its float32 readings, or kept as float32."""
        ranges = np.stack(self._batch)
        self._batch = []
        finite = np.isfinite(ranges)
        special_ok = ~finite & ~np.isneginf(ranges)  # +inf and NaN have codes
        kind = np.full(len(ranges), -1, np.int8)
        codes = np.full(ranges.shape, self.INVALID, np.uint16)
        codes[np.isposinf(ranges)] = self.NO_RETURN
        wide = np.where(finite, ranges, 0.0).astype(np.float64)
        for u in range(len(self.UNITS_M)):
            k = np.rint(wide / self.UNITS_M[u])
            exact = (self._decode_finite(k, u) == ranges) & (k >= 0) & (k < self.NO_RETURN)
            fits = (exact | special_ok).all(axis=1) & (kind < 0)
            kind[fits] = u
            codes[fits] = np.where(finite[fits], k[fits], codes[fits])
        for row, u in enumerate(kind.tolist()):
            if u < 0:
                self._where.append(-1 - len(self._floats))
                self._floats.frombytes(ranges[row].tobytes())
            else:
                self._where.append(len(self._codes))
                self._codes.frombytes(codes[row].tobytes())
        self._kind.frombytes(kind.tobytes())

    def _decode_finite(self, k: np.ndarray, unit: int) -> np.ndarray:
        return (k * self.UNITS_M[unit]).astype(np.float32)

    def _ranges(self, i: int, n: int) -> np.ndarray:
        """Scan i's n readings, as float32."""
        at = self._where[i]
        if at < 0:
            return np.frombuffer(self._floats, np.float32, n, (-1 - at) * 4)
        codes = np.frombuffer(self._codes, np.uint16, n, at * 2)
        out = self._decode_finite(codes.astype(np.float64), self._kind[i])
        out[codes == self.NO_RETURN] = np.inf
        out[codes == self.INVALID] = np.nan
        return out

    def __len__(self) -> int:
        return len(self._stamps)

    def scans(self) -> Iterable[Scan]:
        if self._batch:
            self._code_batch()
        for i, (stamp, max_range, shape) in enumerate(zip(self._stamps, self._max_range,
                                                          self._geometry, strict=True)):
            angles, laser = self._shapes[shape]
            yield Scan(stamp, self._ranges(i, len(angles)).astype(np.float64), angles,
                       max_range, Pose2D(), laser)


class Measurements(Protocol):
    def measurement(self, scan: Scan) -> Measurement: ...


class DynamicSlam:
    """One run of the algorithm; feed it scans in log order with :meth:`step`. What is
    measured from each scan alone (its motion and corners) comes from ``front`` (a front end
    that has measured it already) or, by default, is measured here."""

    def __init__(self, config: Config, front: Measurements | None = None,
                 online_dynamic: bool = True) -> None:
        self.config = config
        use_graph = config.loop.enabled and config.ekf.localization == "ekf"
        # With the pose graph the maps are made again at the end; while running, the filter
        # needs S alone (Table 3), and D only if someone looks (:meth:`current`).
        self.mapper = DynamicMapper(config, dynamic=online_dynamic or not use_graph,
                                    changes=not use_graph)  # (else: when the maps are remade)
        self._trajectory = array("d")
        self._slam: CornerSlam | None = None
        self._measure = front.measurement if front is not None else Measure(config)
        self._motion_sources: Counter[str] = Counter()
        self._loops = LoopCloser(config.loop, config.match, config.ekf) if use_graph else None
        self._store = ScanStore() if use_graph else None
        self._nodes = array("i")  # per scan: its graph node ...
        self._node_offsets = array("d")  # ... and its pose in that node's EKF frame
        self._count = 0

    @property
    def pose(self) -> Pose2D:
        """The last scan's pose as estimated at its time (map frame)."""
        x, y, theta = self._trajectory[-3:]
        return Pose2D(x, y, theta)

    @property
    def grids(self) -> GridStack:
        """The grids as mapped so far (with the pose estimates of their time)."""
        return self.mapper.grids

    def step(self, scan: Scan) -> Pose2D:
        """Process one scan; returns the robot's pose in the map frame."""
        scan = self.config.laser.limit(scan)  # (a front end has done it already)
        pose = self.localize(scan)
        self.mapper.integrate(pose, scan)
        self._trajectory.extend((scan.stamp, pose.x, pose.y, pose.theta))
        if self._store is not None:
            self._store.add(scan)
        self._count += 1
        return pose

    def localize(self, scan: Scan) -> Pose2D:
        """Robot pose at the scan in the map frame (= the first scan's odometry frame):
        EKF-SLAM over corners, then the pose graph's correction of its drift."""
        if self.config.ekf.localization == "odometry":
            return scan.odom
        local = self.track_with_ekf(scan)
        return self.close_loops(local, scan)

    def track_with_ekf(self, scan: Scan) -> Pose2D:
        """Sec. 4: predict from the (scan-matched) motion, detect corners, associate,
        classify landmarks by S^{t-1} (Table 3), correct with the static ones."""
        motion, observations = self.measure(scan)
        if self._slam is None:
            self._slam = CornerSlam(scan.odom, self.config.ekf)
            return scan.odom
        slam = self._slam
        slam.scan_index = self._count
        slam.predict(motion.increment, motion.cov, scan.has_odometry)
        pairs, not_new = slam.associate(observations)
        seen = [i for i, _ in pairs]  # only these can correct the pose: classify them
        if seen:
            places = self.to_map(slam.landmark_positions()[seen])
            slam.classify(seen, self.mapper.classify_landmarks(places))
        slam.correct(pairs)
        slam.add_new(observations, not_new)
        slam.prune()
        return slam.pose

    def close_loops(self, local: Pose2D, scan: Scan) -> Pose2D:
        """A graph node every so often, a loop closure where the robot is back in a known
        place; returns the scan's pose with the graph's correction."""
        loops = self._loops
        if loops is None:
            return local
        if loops.wants_node(local):
            loops.add_node(local, scan_points(scan, self.config.match.max_range_m,
                                              self.config.match.subsample))
        node = len(loops.front) - 1
        offset = relative(loops.front[node], local)
        self._nodes.append(node)
        self._node_offsets.extend((offset.x, offset.y, offset.theta))
        return compose(loops.pose(node), offset)

    def to_map(self, points: np.ndarray) -> np.ndarray:
        """EKF-frame positions (N×2) into the map frame by the current graph correction."""
        if self._loops is None or not self._loops.front or len(points) == 0:
            return points
        return transform_points(self._loops.correction(len(self._loops.front) - 1), points)

    def measure(self, scan: Scan) -> Measurement:
        """The control input (scan-matched motion where the match is good, else odometry)
        and the corners seen."""
        measured = self._measure(scan)
        self._motion_sources[measured.motion.source] += 1
        return measured

    def current(self) -> SlamResult:
        """The state so far, as mapped online (for snapshots: with the pose graph, D is kept
        while running only if this object was made with ``online_dynamic``)."""
        trajectory = np.asarray(self._trajectory, dtype=np.float64).reshape(-1, 4)
        return self._result(self.mapper, trajectory)

    def result(self, on_phase: Callable[[str, int, int], None] | None = None) -> SlamResult:
        """The final result: with the pose graph, the maps are rebuilt from the optimized
        trajectory, so places seen before and after a loop closure agree. ``on_phase(what,
        done, total)`` tells how the final work goes."""
        trajectory = np.asarray(self._trajectory, dtype=np.float64).reshape(-1, 4)
        if self._loops is None or self._store is None or not len(self._store):
            return self._result(self.mapper, trajectory, final=True)
        say = on_phase or (lambda what, done, total: None)
        say("optimizing the pose graph", 0, 0)
        self._loops.finish()
        trajectory = np.column_stack((trajectory[:, 0], self.estimates()))
        mapper = DynamicMapper(self.config, changes=True)
        mapper.grids.reserve_like(self.mapper.grids)
        self.mapper = mapper  # (the online maps are let go before the new ones fill)
        n = len(trajectory)
        for i, ((_, x, y, th), scan) in enumerate(zip(trajectory, self._store.scans(),
                                                      strict=True)):
            if i % 256 == 0:
                say("rebuilding the maps", i, n)
            mapper.integrate(Pose2D(float(x), float(y), float(th)), scan)
        return self._result(mapper, trajectory, final=True)

    def estimates(self, scans: np.ndarray | None = None) -> np.ndarray:
        """The current pose estimates (N×3, map frame) of the scans by index (default: every
        scan): with the pose graph, each from its node's pose now and its EKF offset from
        the node (so a loop closure moves the scans before it too), else as tracked."""
        if self._loops is None:
            poses = np.asarray(self._trajectory, dtype=np.float64).reshape(-1, 4)[:, 1:]
            return poses if scans is None else poses[scans]
        node = np.asarray(self._nodes, dtype=np.int64)
        off = np.asarray(self._node_offsets, dtype=np.float64).reshape(-1, 3)
        if scans is not None:
            node, off = node[scans], off[scans]
        base = self._loops.graph.poses[node]
        c, s = np.cos(base[:, 2]), np.sin(base[:, 2])
        return np.column_stack((base[:, 0] + c * off[:, 0] - s * off[:, 1],
                                base[:, 1] + s * off[:, 0] + c * off[:, 1],
                                wrap_angles(base[:, 2] + off[:, 2])))

    def _result(self, mapper: DynamicMapper, trajectory: np.ndarray, final: bool = False
                ) -> SlamResult:
        landmarks = self.landmarks(mapper)
        changes = []
        if final and mapper.changes is not None:
            changes = change_events(mapper.changes, [(lm.id, lm.x, lm.y) for lm in landmarks])
        return SlamResult(
            static=mapper.grids.snapshot("static"),
            dynamic=mapper.grids.snapshot("dynamic"),
            trajectory=trajectory,
            landmarks=landmarks,
            localization=self.counts(),
            grid_memory=mapper.grids.memory(),
            changes=changes,
        )

    def counts(self) -> dict[str, int]:
        """How localization went, for ``summary.json``."""
        out: dict[str, int] = {}
        if self.config.match.enabled:
            m = self._motion_sources
            out.update(scan_matches=m["matched"] + m["recovered"],
                       scan_match_recoveries=m["recovered"], odometry_fallbacks=m["fallback"])
        if self._loops is not None:
            out.update(graph_nodes=len(self._loops.front),
                       loop_closure_attempts=self._loops.attempts,
                       loop_closures=self._loops.closures)
        return out

    def landmarks(self, mapper: DynamicMapper) -> list[Landmark]:
        """The landmark map: every landmark the EKF confirmed (those it has let go of
        included), placed by the graph, classed static or dynamic by Table 3 against the
        final S, with its position covariance."""
        if self._slam is None:
            return []
        records = self._slam.landmark_records()
        if not records:
            return []
        xy = np.array([[r.x, r.y] for r in records])
        angles = np.zeros(len(records))
        if self._loops is not None and self._nodes:
            nodes = np.asarray(self._nodes)[[min(r.last_seen, len(self._nodes) - 1)
                                              for r in records]]
            for k, n in enumerate(nodes):
                corr = self._loops.correction(int(n))
                p = compose(corr, Pose2D(xy[k, 0], xy[k, 1], 0.0))
                xy[k] = (p.x, p.y)
                angles[k] = corr.theta
        classes = [TABLE_3[int(s)] for s in mapper.classify_landmarks(xy)]
        out = []
        for r, (x, y), a, cls in zip(records, xy, angles, classes, strict=True):
            c, s = math.cos(a), math.sin(a)
            rot = np.array([[c, -s], [s, c]])
            cov = rot @ r.cov @ rot.T
            out.append(Landmark(r.id, float(x), float(y), "convex" if r.convex else "concave",
                                cls, r.observations, float(cov[0, 0]), float(cov[0, 1]),
                                float(cov[1, 1])))
        return out


def run(scans: Iterable[Scan], config: Config,
        on_scan: Callable[[int, Scan, DynamicSlam], None] | None = None,
        front: Measurements | None = None, online_dynamic: bool = True,
        on_phase: Callable[[str, int, int], None] | None = None) -> SlamResult:
    """Run the whole stream through :class:`DynamicSlam`; ``on_scan(i, scan, slam)`` is called
    after each scan (progress, snapshots: those need ``online_dynamic``), ``on_phase`` in
    the final work (see :meth:`DynamicSlam.result`)."""
    slam = DynamicSlam(config, front, online_dynamic)
    for i, scan in enumerate(scans):
        slam.step(scan)
        if on_scan is not None:
            on_scan(i, scan, slam)
    return slam.result(on_phase)
