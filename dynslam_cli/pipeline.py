"""The SLAM loop: a stream of scans in; maps, landmarks and the trajectory out.

Each step follows the paper: localize the robot (Sec. 4), then update the maps from what the
scan observed (Sec. 3). This first version localizes by odometry alone and keeps one
ordinary occupancy grid; the map frame is the odometry frame of the first scan.
"""

from __future__ import annotations

from array import array
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from dynslam_cli.config import Config
from dynslam_cli.geometry import compose
from dynslam_cli.grid import GridStack, Observation, OccupancyMap, logit, update_ordinary
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
        m = config.map
        self.grids = GridStack(m.resolution_m, m.grow_margin_m, ("static", "dynamic"))
        self._l_hit, self._l_miss = logit(m.p_hit), logit(m.p_miss)
        self._l_min, self._l_max = logit(m.p_clamp_min), logit(m.p_clamp_max)
        self._trajectory = array("d")

    def step(self, scan: Scan) -> Pose2D:
        """Process one scan; returns the robot's pose in the map frame."""
        pose = self.localize(scan)
        observation = self.observe(pose, scan)
        self.update_static_map(observation)
        self._trajectory.extend((scan.stamp, pose.x, pose.y, pose.theta))
        return pose

    def localize(self, scan: Scan) -> Pose2D:
        """Robot pose at the scan: odometry alone (map frame = first scan's odometry frame)."""
        return scan.odom

    def observe(self, pose: Pose2D, scan: Scan) -> Observation:
        """Cells the scan saw free and cells it hit, from the laser's pose in the map."""
        laser = self.config.laser
        max_range = laser.max_range_m if laser.max_range_m is not None else scan.max_range
        return self.grids.observe(compose(pose, scan.laser), scan.ranges, scan.angles,
                                  max_range, laser.min_range_m, laser.clear_cap_m)

    def update_static_map(self, observation: Observation) -> None:
        """Ordinary log-odds update of the map (Eq. 12 with a fixed inverse sensor model)."""
        update_ordinary(self.grids.layers["static"], observation, self._l_hit, self._l_miss,
                        self._l_min, self._l_max)

    def result(self) -> SlamResult:
        return SlamResult(
            static=self.grids.snapshot("static"),
            dynamic=self.grids.snapshot("dynamic"),
            trajectory=np.asarray(self._trajectory, dtype=np.float64).reshape(-1, 4),
        )


def run(scans: Iterable[Scan], config: Config,
        on_scan: Callable[[int], None] | None = None) -> SlamResult:
    """Run the whole stream through :class:`DynamicSlam`; ``on_scan(i)`` after each scan."""
    slam = DynamicSlam(config)
    for i, scan in enumerate(scans):
        slam.step(scan)
        if on_scan is not None:
            on_scan(i)
    return slam.result()
