"""The front end: what the filter measures from each scan alone, the motion since the
previous scan and the corners seen.

The motion of a scan is the wheel odometry's, or, where the scan matches the local map well,
the scan-matched one (:class:`dynslam_cli.localization.scanmatch.ScanMatcher`); the corners
are the landmark observations (:func:`dynslam_cli.localization.cornerslam.observe_corners`).
Measuring depends on nothing the filter, the pose graph or the maps compute, so it can run
ahead of them in another process (dynslam_cli.readahead).
"""

from __future__ import annotations

from collections import Counter
from typing import Any, NamedTuple, Protocol

import numpy as np

from dynslam_cli.localization.cornerslam import observe_corners
from dynslam_cli.localization.scanmatch import ScanMatcher, WheelOdometry
from dynslam_cli.sections import CornerConfig, EkfConfig, MatchConfig, NoiseModel
from dynslam_cli.types import Pose2D, Scan


class Motion(NamedTuple):
    """Motion since the previous scan, in the previous robot frame, and where it came from:
    ``matched`` (a good scan match), ``recovered`` (a good match after retrying other
    guesses), ``fallback`` (no good match: wheel odometry), or ``odometry`` (no match tried:
    the first scan, a sparse local map, or scan matching switched off); with the covariance
    of a matched increment (its information from the match, fused with the odometry's), or
    None (the odometry's noise model applies); and the laser mount's error learned so far
    (``[match.correlative] calibrate_mount``; for the summary)."""

    increment: Pose2D
    source: str
    cov: np.ndarray | None = None
    mount_error: tuple[float, float] = (0.0, 0.0)

    @property
    def matched(self) -> bool:
        return self.source in ("matched", "recovered")


def match_counts(sources: Counter[str]) -> dict[str, Any]:
    """How the scan matching went, from how many motions came from each source, for
    ``summary.json``."""
    return {"scan_matches": sources["matched"] + sources["recovered"],
            "scan_match_recoveries": sources["recovered"],
            "odometry_fallbacks": sources["fallback"]}


class Measurement(NamedTuple):
    """What the filter measures from one scan alone: its motion and its corners ((range,
    bearing) from the robot, convex); no corners when localization is odometry alone."""

    motion: Motion
    corners: list[tuple[np.ndarray, bool]]


class MeasuredScans(Protocol):
    """Scans measured already (a front end that reads ahead): the last one's measurement."""

    def measurement(self, scan: Scan) -> Measurement: ...


class ScanMeasurer:
    """Each scan's :class:`Measurement`, from the scans in log order: the motion scan-matched
    by ``match`` (None: the wheel odometry's), the corners detected by ``corners`` (None:
    none, as a filter that corrects with none needs)."""

    def __init__(self, match: MatchConfig | None, motion_noise: NoiseModel,
                 corners: CornerConfig | None) -> None:
        self._matcher = ScanMatcher(match, motion_noise) if match is not None else None
        self._wheel = WheelOdometry()
        self._corners = corners

    @classmethod
    def configured(cls, ekf: EkfConfig, match: MatchConfig, corners: CornerConfig
                   ) -> ScanMeasurer:
        """What the filter measures under these sections: with the EKF, the corners and
        (where scan matching is on) the scan-matched motion; with odometry alone, neither."""
        filtered = ekf.filtered
        return cls(match if filtered and match.enabled else None, ekf.noise,
                   corners if filtered else None)

    @property
    def matches(self) -> bool:
        """Whether the motion is scan-matched (not the wheel odometry's)."""
        return self._matcher is not None

    def __call__(self, scan: Scan) -> Measurement:
        corners = observe_corners(scan, self._corners) if self._corners is not None else []
        return Measurement(self.motion(scan), corners)

    def motion(self, scan: Scan) -> Motion:
        if self._matcher is not None:
            return Motion(*self._matcher.increment(scan), self._matcher.mount_error)
        return Motion(self._wheel.increment(scan.odom), "odometry")
