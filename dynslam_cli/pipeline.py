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
from typing import Protocol

import numpy as np

from dynslam_cli.config import Config
from dynslam_cli.geometry import compose, relative, transform_points, wrap_angles
from dynslam_cli.localization.cornerslam import CornerSlam, one_per_corner
from dynslam_cli.localization.frontend import Measure, Measurement
from dynslam_cli.localization.loops import LoopCloser
from dynslam_cli.localization.scanmatch import scan_points
from dynslam_cli.mapping.changes import change_events
from dynslam_cli.mapping.dynamic import DynamicMapper
from dynslam_cli.mapping.grid import GridStack, OccupancyMap
from dynslam_cli.result import Landmark, SlamResult
from dynslam_cli.scanstore import ScanStore
from dynslam_cli.types import Pose2D, Scan


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
        self.mapper = self._mapper(changes=not use_graph,  # (else: when the maps are remade)
                                   keep_dynamic=online_dynamic or not use_graph)
        self._trajectory = array("d")
        self._slam: CornerSlam | None = None
        self._measure = front.measurement if front is not None else Measure(config)
        self._motion_sources: Counter[str] = Counter()
        self._loops = LoopCloser(config.loop, config.match, config.ekf.noise) if use_graph else None
        self._store = ScanStore() if use_graph else None
        self._nodes = array("i")  # per scan: its graph node ...
        self._node_offsets = array("d")  # ... and its pose in that node's EKF frame
        self._count = 0

    def _mapper(self, changes: bool, keep_dynamic: bool = True) -> DynamicMapper:
        c = self.config
        return DynamicMapper(c.map, c.laser, c.dynamic, c.changes if changes else None,
                             keep_dynamic)

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
        node = len(loops.local_poses) - 1
        offset = relative(loops.local_poses[node], local)
        self._nodes.append(node)
        self._node_offsets.extend((offset.x, offset.y, offset.theta))
        return compose(loops.pose(node), offset)

    def to_map(self, points: np.ndarray) -> np.ndarray:
        """EKF-frame positions (N×2) into the map frame by the current graph correction."""
        if self._loops is None or not self._loops.local_poses or len(points) == 0:
            return points
        return transform_points(self._loops.correction(len(self._loops.local_poses) - 1), points)

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
        mapper = self._mapper(changes=True)
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
            out.update(graph_nodes=len(self._loops.local_poses),
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
        covs = []
        for r, a in zip(records, angles, strict=True):
            c, s = math.cos(a), math.sin(a)
            rot = np.array([[c, -s], [s, c]])
            covs.append(rot @ r.cov @ rot.T)
        corners = one_per_corner(
            [(r.id, r.convex, r.observations) for r in records], xy, np.array(covs),
            self.config.ekf.gate_chi2)
        places = np.array([[x, y] for _, _, _, x, y, _ in corners]).reshape(-1, 2)
        classes = mapper.classify_landmarks(places)
        return [Landmark(i, x, y, "convex" if convex else "concave", cls, seen,
                         float(cov[0, 0]), float(cov[0, 1]), float(cov[1, 1]))
                for (i, convex, seen, x, y, cov), cls in zip(corners, classes, strict=True)]


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


def snapshots_at(scans: Iterable[Scan], config: Config, times: list[float]
                 ) -> tuple[SlamResult, list[tuple[float, OccupancyMap, OccupancyMap]]]:
    """Run the pipeline and take (time, S, D) just before the first scan at or after each of
    ``times``, and at the end (for dynslam_cli.evaluate.score_events: the benches)."""
    slam = DynamicSlam(config)
    pending = sorted(times)
    snaps: list[tuple[float, OccupancyMap, OccupancyMap]] = []
    last = 0.0
    for scan in scans:
        while pending and scan.stamp >= pending[0]:
            snaps.append((pending.pop(0), slam.grids.snapshot("static").dense(),
                          slam.grids.snapshot("dynamic").dense()))
        slam.step(scan)
        last = scan.stamp
    snaps.append((last + 1.0, slam.grids.snapshot("static"), slam.grids.snapshot("dynamic")))
    return slam.result(), snaps
