"""Corner landmarks from one scan (paper Sec. 4: corners, with a convex/concave flag).

1. Split the scan into clusters at range jumps and invalid / no-return beams (an occlusion
   edge is a jump, so no corner is ever formed across one).
2. Split each cluster into straight runs (recursive split at the point farthest from the
   chord), then fit each run by total least squares.
3. Two adjacent runs that are both long and well supported and meet at a real angle make a
   corner at the intersection of their lines. It is *convex* if it points toward the sensor
   (a pillar's edge), *concave* if it points away (a room corner).

Corners at the end of the laser's range (where readings are sparse and noisy) are dropped.
Everything is in the laser frame, metres and radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dynslam_cli.localization import _corners
from dynslam_cli.sections import CornerConfig

MAX_BEAMS_BETWEEN_SIDES = 3  # beams at the very corner may form a run of their own


@dataclass(frozen=True)
class Corner:
    """A corner in the laser frame."""

    x: float
    y: float
    convex: bool


def detect_corners(ranges: np.ndarray, angles: np.ndarray, max_range: float,
                   cfg: CornerConfig) -> list[Corner]:
    """Corners of one scan (see the module docstring)."""
    found = _corners.detect_corners(
        np.ascontiguousarray(ranges, dtype=np.float64),
        np.ascontiguousarray(angles, dtype=np.float64), min(cfg.max_range_m, 0.95 * max_range),
        cfg.jump_m, cfg.jump_ratio, cfg.split_tolerance_m, cfg.min_points, cfg.min_length_m,
        cfg.max_fit_rms_m, math.cos(math.radians(cfg.min_angle_deg)), cfg.max_gap_m,
        MAX_BEAMS_BETWEEN_SIDES)
    return [Corner(x, y, convex) for x, y, convex in found]
