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
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from dynslam_cli.config import Config
from dynslam_cli.dynamic import (
    OCCUPIED,
    TABLE_1,
    TABLE_2,
    UNKNOWN,
    InverseModel,
    classify_neighbourhood,
    classify_static,
    neighbourhood_offsets,
    radius_cells,
)
from dynslam_cli.geometry import compose, relative
from dynslam_cli.grid import GridStack, Observation, OccupancyMap
from dynslam_cli.localization import CornerSlam
from dynslam_cli.scanmatch import ScanMatcher
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


class DynamicSlam:
    """One run of the algorithm; feed it scans in log order with :meth:`step`."""

    def __init__(self, config: Config) -> None:
        self.config = config
        m, d = config.map, config.dynamic
        self._radius = radius_cells(d.neighbourhood_m, m.resolution_m) if d.enabled else 0
        self.grids = GridStack(m.resolution_m, m.grow_margin_m, ("static", "dynamic"),
                               pad_cells=self._radius)
        static_model = InverseModel.from_probabilities(m.p_hit, m.p_miss, m.p_clamp_min,
                                                       m.p_clamp_max)
        self._static = static_model
        self._dynamic = InverseModel.from_probabilities(d.p_high, d.p_low, d.p_clamp_min,
                                                        d.p_clamp_max)
        if d.enabled:
            self._table_1 = static_model.table(TABLE_1)
            self._table_2 = self._dynamic.table(TABLE_2)
        else:  # an ordinary grid: every hit raises S, D is never touched
            self._table_1 = static_model.table({k: "high" if k[1] == OCCUPIED else "low"
                                                for k in TABLE_1})
            self._table_2 = None
        self._free_rows_uniform = all(np.ptp(t[:, 0]) == 0 for t in (self._table_1,
                                                                      self._table_2)
                                      if t is not None)
        self._trajectory = array("d")
        self._slam: CornerSlam | None = None
        self._last_odom: Pose2D | None = None
        self._matcher = (ScanMatcher(config.match, config.ekf.noise) if config.match.enabled
                         else None)

    def step(self, scan: Scan) -> Pose2D:
        """Process one scan; returns the robot's pose in the map frame."""
        pose = self.localize(scan)
        observation = self.observe(pose, scan)
        free_prev, hit_prev = self.classify_against_static_map(observation)
        self.update_static_map(observation, free_prev, hit_prev)
        self.update_dynamic_map(observation, free_prev, hit_prev)
        self._trajectory.extend((scan.stamp, pose.x, pose.y, pose.theta))
        return pose

    def localize(self, scan: Scan) -> Pose2D:
        """Robot pose at the scan in the map frame (= the first scan's odometry frame)."""
        if self.config.ekf.localization == "odometry":
            return scan.odom
        increment, matched = self.motion_since_last_scan(scan)
        if self._slam is None:
            self._slam = CornerSlam(scan.odom, self.config.ekf, self.config.corners)
            return scan.odom
        slam = self._slam
        slam.predict(increment, matched, scan.has_odometry)
        observations = slam.detect(scan)
        pairs, not_new = slam.associate(observations)
        slam.classify(self.classify_landmarks(slam.landmark_positions()))
        slam.correct(pairs)
        slam.add_new(observations, not_new)
        slam.prune()
        slam.scan_index += 1
        return slam.pose

    def motion_since_last_scan(self, scan: Scan) -> tuple[Pose2D, bool]:
        """The control input: scan-matched motion where the match is good, else odometry."""
        if self._matcher is not None:
            return self._matcher.increment(scan)
        last, self._last_odom = self._last_odom, scan.odom
        return (relative(last, scan.odom) if last is not None else Pose2D()), False

    def classify_landmarks(self, positions: np.ndarray) -> np.ndarray:
        """State of S^{t-1} around each landmark (neighbourhood rule), for Table 3. Without
        S/D separation every landmark counts as Occupied (static)."""
        if self._table_2 is None or len(positions) == 0:
            return np.full(len(positions), OCCUPIED, np.int8)
        g, m = self.grids, self.config.map
        cells, inside = g.flat_index_inside(positions[:, 0], positions[:, 1], self._radius)
        states = np.full(len(positions), UNKNOWN, np.int8)  # outside the grid
        states[inside] = classify_neighbourhood(
            g.layers["static"].reshape(-1), cells, neighbourhood_offsets(self._radius, g.shape[1]),
            m.free_threshold, m.occupied_threshold)
        return states

    def observe(self, pose: Pose2D, scan: Scan) -> Observation:
        """Cells the scan saw free and cells it hit, from the laser's pose in the map."""
        laser = self.config.laser
        max_range = laser.max_range_m if laser.max_range_m is not None else scan.max_range
        return self.grids.observe(compose(pose, scan.laser), scan.ranges, scan.angles,
                                  max_range, laser.min_range_m, laser.clear_cap_m)

    def classify_against_static_map(self, obs: Observation) -> tuple[np.ndarray, np.ndarray]:
        """State of S^{t-1} (Free/Unknown/Occupied) at the cells seen free, and over the
        neighbourhood of each cell hit (Sec. 5)."""
        if self._table_2 is None:  # an ordinary grid: the state does not matter
            return (np.zeros(len(obs.free), np.int8), np.zeros(len(obs.hit), np.int8))
        m = self.config.map
        s = self.grids.layers["static"].reshape(-1)
        if self._free_rows_uniform:  # Tables 1 and 2 give "low" whatever S^{t-1} was
            free_prev = np.zeros(len(obs.free), np.int8)
        else:
            free_prev = classify_static(s[obs.free], m.free_threshold, m.occupied_threshold)
        offsets = neighbourhood_offsets(self._radius, self.grids.shape[1])
        hit_prev = classify_neighbourhood(s, obs.hit, offsets, m.free_threshold,
                                          m.occupied_threshold)
        return free_prev, hit_prev

    def update_static_map(self, obs: Observation, free_prev: np.ndarray,
                          hit_prev: np.ndarray) -> None:
        """Eq. 12 with Table 1 as the inverse sensor model."""
        _apply_inverse_model(self.grids.layers["static"], obs, free_prev, hit_prev,
                             self._table_1, self._static)

    def update_dynamic_map(self, obs: Observation, free_prev: np.ndarray,
                           hit_prev: np.ndarray) -> None:
        """Eq. 13 with Table 2 as the inverse sensor model."""
        if self._table_2 is not None:
            _apply_inverse_model(self.grids.layers["dynamic"], obs, free_prev, hit_prev,
                                 self._table_2, self._dynamic)

    def result(self) -> SlamResult:
        return SlamResult(
            static=self.grids.snapshot("static"),
            dynamic=self.grids.snapshot("dynamic"),
            trajectory=np.asarray(self._trajectory, dtype=np.float64).reshape(-1, 4),
            landmarks=self.landmarks(),
        )

    def landmarks(self) -> list[Landmark]:
        """The landmark map, with each landmark's position covariance."""
        if self._slam is None:
            return []
        slam = self._slam
        out = []
        for i, (track, (x, y)) in enumerate(zip(slam.tracks, slam.landmark_positions(),
                                                strict=True)):
            j = 3 + 2 * i
            c = slam.ekf.cov[j:j + 2, j:j + 2]
            out.append(Landmark(track.id, float(x), float(y),
                                "convex" if track.convex else "concave", track.cls,
                                track.observations, float(c[0, 0]), float(c[0, 1]),
                                float(c[1, 1])))
        return out


def _apply_inverse_model(layer: np.ndarray, obs: Observation, free_prev: np.ndarray,
                         hit_prev: np.ndarray, table: np.ndarray, model: InverseModel) -> None:
    """Add the table's log-odds (indexed [S^{t-1} state, o^t]) to the observed cells, clamped.
    Written by assignment, so a cell listed twice is updated once."""
    flat = layer.reshape(-1)
    if model.low <= model.clamp_min - model.clamp_max and np.all(table[:, 0] == model.low):
        flat[obs.free] = model.clamp_min  # one "low" clamps any cell: no need to read it
    else:
        flat[obs.free] = np.clip(flat[obs.free] + table[free_prev, 0], model.clamp_min,
                                 model.clamp_max)
    flat[obs.hit] = np.clip(flat[obs.hit] + table[hit_prev, 1], model.clamp_min,
                            model.clamp_max)


def run(scans: Iterable[Scan], config: Config,
        on_scan: Callable[[int, Scan, DynamicSlam], None] | None = None) -> SlamResult:
    """Run the whole stream through :class:`DynamicSlam`; ``on_scan(i, scan, slam)`` is called
    after each scan (progress, snapshots)."""
    slam = DynamicSlam(config)
    for i, scan in enumerate(scans):
        slam.step(scan)
        if on_scan is not None:
            on_scan(i, scan, slam)
    return slam.result()
