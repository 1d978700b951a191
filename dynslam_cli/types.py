"""The records that flow between readers, the SLAM core and the writers."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np


@dataclass(frozen=True, slots=True)
class Pose2D:
    """A planar pose: position in metres, heading in radians (counter-clockwise from +x)."""

    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0

    def __reduce__(self) -> tuple[type, tuple[float, float, float]]:
        # Pickled by the constructor: a third of the time of a slotted dataclass's default
        # state hooks (four poses a scan cross the read-ahead pipe).
        return Pose2D, (self.x, self.y, self.theta)


@dataclass(frozen=True, slots=True, eq=False)
class Scan:
    """One laser sweep with the robot's odometry at the sweep's time stamp.

    ``ranges`` and ``angles`` are float64 arrays of equal length (metres, radians in the laser
    frame). Readings ``>= max_range`` or ``+inf`` mean "no return"; NaN marks an invalid beam.
    ``odom`` is the robot's pose in the odometry frame; ``laser`` is the laser's mounting pose
    on the robot. ``source_line`` (1-based, 0 if not a text format) points back into the log.
    """

    stamp: float
    ranges: np.ndarray
    angles: np.ndarray
    max_range: float
    odom: Pose2D
    laser: Pose2D = field(default_factory=Pose2D)
    source_line: int = 0
    has_odometry: bool = True
    """False for logs without odometry (laser-only bags): ``odom`` is then the origin and
    the motion prior is "stationary, with wide noise" (see dynslam_cli.localization.scanmatch)."""
    range_min: float | None = None
    """The laser's minimum range (metres) where the log says it (a LaserScan's
    ``range_min``); None where it does not (Carmen, Player)."""
    time_increment: float | None = None
    """Time between two beams (seconds) where the log says it (LaserScan); else None."""
    scan_time: float | None = None
    """Time between two sweeps (seconds) where the log says it (LaserScan); else None."""

    def respaced(self, step: float) -> Scan:
        """The scan with its beams ``step`` radians apart from the first (which stays)."""
        return replace(self, angles=self.angles[:1] + step * np.arange(len(self.angles),
                                                                      dtype=np.float64))
