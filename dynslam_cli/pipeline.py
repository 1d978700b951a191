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

from array import array
from collections import Counter
from collections.abc import Callable, Iterable

import numpy as np

from dynslam_cli.config import Config
from dynslam_cli.localization.backend import BackEnd
from dynslam_cli.localization.cornerslam import CornerSlam
from dynslam_cli.localization.frontend import MeasuredScans, ScanMeasurer, match_counts
from dynslam_cli.mapping.dynamic import DynamicMapper
from dynslam_cli.mapping.grid import GridStack
from dynslam_cli.prior import PriorSession
from dynslam_cli.result import Landmark, SlamResult, landmarks_of
from dynslam_cli.scanstore import ScanStore, remap
from dynslam_cli.types import Pose2D, Scan


class DynamicSlam:
    """One run of the algorithm; feed it scans in log order with :meth:`step`. What is
    measured from each scan alone (its motion and corners) comes from ``front`` (a front end
    that has measured it already) or, by default, is measured here."""

    def __init__(self, config: Config, front: MeasuredScans | None = None,
                 online_dynamic: bool = True, prior: PriorSession | None = None) -> None:
        """``prior``: start from an earlier session's map, in its frame."""
        self.config = config
        self._prior = prior
        self._ekf = config.ekf.filtered
        use_graph = config.loop.enabled and self._ekf
        # With the pose graph the maps are made again at the end; while running, the filter
        # needs S alone (Table 3), and D only if someone looks (:meth:`current`).
        self.mapper = self._mapper(changes=not use_graph,  # (else: when the maps are remade)
                                   keep_dynamic=online_dynamic or not use_graph)
        self._trajectory = array("d")
        self._slam: CornerSlam | None = None
        self._measure = (front.measurement if front is not None else
                         ScanMeasurer.configured(config.ekf, config.match, config.corners))
        self._motion_sources: Counter[str] = Counter()
        self._mount_error = (0.0, 0.0)  # the front end's, learned so far (frontend.Motion)
        walls = prior.walls() if prior is not None else None  # (the graph holds to them)
        self._backend = BackEnd(config.loop, config.ekf.noise, walls) if use_graph else None
        self._store = ScanStore() if use_graph else None

    def _mapper(self, changes: bool, keep_dynamic: bool = True) -> DynamicMapper:
        c = self.config
        mapper = DynamicMapper(c.map, c.laser, c.dynamic, c.changes if changes else None,
                               keep_dynamic)
        if self._prior is not None:
            self._prior.seed(mapper.grids, mapper.changes)
        return mapper

    @property
    def pose(self) -> Pose2D:
        """The last scan's pose as estimated at its time (map frame; the recording's TF)."""
        return Pose2D(*self._trajectory[-3:])

    @property
    def grids(self) -> GridStack:
        """The grids as mapped so far (with the pose estimates of their time)."""
        return self.mapper.grids

    def step(self, scan: Scan) -> Pose2D:
        """Process one scan; returns the robot's pose in the map frame."""
        pose = self.localize(scan)
        self.mapper.integrate(pose, scan)
        self._trajectory.extend((scan.stamp, pose.x, pose.y, pose.theta))
        if self._store is not None:
            self._store.add(scan)
        return pose

    def localize(self, scan: Scan) -> Pose2D:
        """Robot pose at the scan in the map frame (= the first scan's odometry frame):
        EKF-SLAM over corners, then the pose graph's correction of its drift."""
        if not self._ekf:
            return self.odometry_pose(scan)
        local, moved = self.track_with_ekf(scan)  # then the graph: a node every so often, a
        # loop closure where the robot is back in a known place, the scan placed by the graph
        return local if self._backend is None else self._backend.place(local, scan, moved)

    def odometry_pose(self, scan: Scan) -> Pose2D:
        """The scan's odometry in the map frame (on a prior map, the prior's)."""
        return scan.odom if self._prior is None else self._prior.to_map(scan)

    def track_with_ekf(self, scan: Scan) -> tuple[Pose2D, tuple[Pose2D, np.ndarray] | None]:
        """Sec. 4: predict from the (scan-matched) motion, detect corners, associate,
        classify landmarks by S^{t-1} (Table 3), correct with the static ones. The motion
        is scan-matched where the match is good, else the odometry's. Returns the pose and
        the motion predicted with (increment, covariance; None at the first scan)."""
        motion, corners = self._measure(scan)
        self._motion_sources[motion.source] += 1
        self._mount_error = motion.mount_error
        if self._slam is None:
            start = self.odometry_pose(scan)
            self._slam = CornerSlam(start, self.config.ekf)
            return start, None
        slam, u = self._slam, motion.increment
        q = slam.motion_covariance(u, motion.cov, scan.has_odometry)  # (once: the EKF's and
        # the graph chain's)
        pose = slam.step(len(self._trajectory) // 4, u, q, scan.has_odometry, corners,
                         lambda xy: self.mapper.classify_landmarks(self.to_map(xy)))
        return pose, (u, q)

    def to_map(self, points: np.ndarray) -> np.ndarray:
        """EKF-frame positions (N×2) into the map frame by the current graph correction."""
        return points if self._backend is None else self._backend.to_map(points)

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
        if self._backend is None or self._store is None or not len(self._store):
            return self._result(self.mapper, trajectory, final=True)
        say = on_phase or (lambda what, done, total: None)
        say("optimizing the pose graph", 0, 0)
        self._backend.finish()
        trajectory = np.column_stack((trajectory[:, 0], self.estimates()))
        mapper = self._mapper(changes=True)
        mapper.grids.reserve_like(self.mapper.grids)
        self.mapper = mapper  # (the online maps are let go before the new ones fill)
        remap(mapper, trajectory[:, 1:], self._store, say)
        return self._result(mapper, trajectory, final=True)

    def estimates(self, scans: np.ndarray | None = None) -> np.ndarray:
        """The current pose estimates (N×3, map frame) of the scans by index (default: every
        scan): with the pose graph, each from its node's pose now and its EKF offset from
        the node (so a loop closure moves the scans before it too), else as tracked."""
        if self._backend is not None:
            return self._backend.estimates(scans)
        poses = np.asarray(self._trajectory, dtype=np.float64).reshape(-1, 4)[:, 1:]
        return poses if scans is None else poses[scans]

    def _result(self, mapper: DynamicMapper, trajectory: np.ndarray, final: bool = False
                ) -> SlamResult:
        closures = self._backend.loop_closures() if final and self._backend is not None else None
        return SlamResult.of(mapper, trajectory, self.landmarks(mapper), self.counts(), final,
                             closures)

    def counts(self) -> dict[str, int]:
        """How localization went, for ``summary.json``."""
        out = match_counts(self._motion_sources) if self.config.match.enabled else {}
        if self._backend is not None:
            out.update(self._backend.counts())
        if self._prior is not None:
            out["prior"] = self._prior.report
        if self.config.match.correlative.calibrate_mount:
            out["laser_mount_error_m"] = [round(v, 4) for v in self._mount_error]
        return out

    def landmarks(self, mapper: DynamicMapper | None = None) -> list[Landmark]:
        """The landmark map: every landmark the EKF confirmed (those it has let go of
        included), placed by the graph, classed static or dynamic by Table 3 against the
        S of ``mapper`` (default: the maps so far), with its position covariance."""
        mapper = self.mapper if mapper is None else mapper
        if self._slam is None:
            return []
        correction = (self._backend.scan_correction
                      if self._backend is not None and self._trajectory else None)
        return landmarks_of(self._slam.landmark_map(correction, self.config.map.resolution_m),
                            mapper.classify_landmarks)


def run(scans: Iterable[Scan], config: Config,
        on_scan: Callable[[int, Scan, DynamicSlam], None] | None = None,
        front: MeasuredScans | None = None, online_dynamic: bool = True,
        on_phase: Callable[[str, int, int], None] | None = None,
        prior: PriorSession | None = None) -> SlamResult:
    """Run the whole stream through :class:`DynamicSlam`; ``on_scan(i, scan, slam)`` is called
    after each scan (progress, snapshots: those need ``online_dynamic``), ``on_phase`` in
    the final work (see :meth:`DynamicSlam.result`); ``prior``: on an earlier session's
    map."""
    slam = DynamicSlam(config, front, online_dynamic, prior)
    for i, scan in enumerate(scans):
        slam.step(scan)
        if on_scan is not None:
            on_scan(i, scan, slam)
    return slam.result(on_phase)
