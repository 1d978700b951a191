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

import itertools
import math
from dataclasses import dataclass

import numpy as np

MAX_BEAMS_BETWEEN_SIDES = 3  # beams at the very corner may form a run of their own


@dataclass(frozen=True)
class CornerConfig:
    """Corner detector parameters (units in the names)."""

    jump_m: float = 0.25
    """Range jump between neighbouring beams that splits a cluster (plus jump_ratio · r)."""
    jump_ratio: float = 0.05
    split_tolerance_m: float = 0.04
    """A run is straight while no point is farther than this from its chord."""
    min_points: int = 7
    """Each side of a corner must hold at least this many beams."""
    min_length_m: float = 0.35
    """... and be at least this long."""
    max_fit_rms_m: float = 0.03
    """... and fit its line with at most this RMS residual."""
    min_angle_deg: float = 50.0
    """Angle between the two sides: a corner is between min and 180 − min degrees."""
    max_gap_m: float = 0.15
    """The lines' intersection must lie this close to the last point of each side."""
    max_range_m: float = 7.0
    """No corners beyond this range (or within 5% of the laser's max range)."""


@dataclass(frozen=True)
class Corner:
    """A corner in the laser frame."""

    x: float
    y: float
    convex: bool


def _clusters(r: np.ndarray, ok: np.ndarray, cfg: CornerConfig) -> list[np.ndarray]:
    """Index runs of consecutive valid beams without range jumps."""
    idx = np.flatnonzero(ok)
    if len(idx) == 0:
        return []
    gap = np.diff(idx) > 1
    jump = np.abs(np.diff(r[idx])) > cfg.jump_m + cfg.jump_ratio * np.minimum(r[idx][:-1],
                                                                             r[idx][1:])
    cuts = np.flatnonzero(gap | jump) + 1
    return [c for c in np.split(idx, cuts) if len(c) >= 2 * cfg.min_points]


def _split(pts: np.ndarray, lo: int, hi: int, tol: float, out: list[tuple[int, int]]) -> None:
    """Recursive split of pts[lo:hi+1] into straight runs (inclusive index pairs)."""
    stack = [(lo, hi)]
    while stack:
        a, b = stack.pop()
        if b - a < 2:
            out.append((a, b))
            continue
        p, q = pts[a], pts[b]
        d = q - p
        n = math.hypot(d[0], d[1])
        seg = pts[a + 1:b]
        if n < 1e-9:
            dist = np.hypot(seg[:, 0] - p[0], seg[:, 1] - p[1])
        else:
            dist = np.abs(d[0] * (seg[:, 1] - p[1]) - d[1] * (seg[:, 0] - p[0])) / n
        k = int(np.argmax(dist))
        if dist[k] > tol:
            m = a + 1 + k
            stack.append((m, b))
            stack.append((a, m))
        else:
            out.append((a, b))


def fit_line(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Total least squares: (point on line, unit direction, RMS residual)."""
    c = pts.mean(axis=0)
    _u, s, vt = np.linalg.svd(pts - c, full_matrices=False)
    direction = vt[0]
    rms = float(s[1] / math.sqrt(len(pts))) if len(s) > 1 else 0.0
    return c, direction, rms


def _intersect(c1: np.ndarray, d1: np.ndarray, c2: np.ndarray, d2: np.ndarray
               ) -> np.ndarray | None:
    den = d1[0] * d2[1] - d1[1] * d2[0]
    if abs(den) < 1e-9:
        return None
    w = c2 - c1
    t = (w[0] * d2[1] - w[1] * d2[0]) / den
    return c1 + t * d1


def detect_corners(ranges: np.ndarray, angles: np.ndarray, max_range: float,
                   cfg: CornerConfig) -> list[Corner]:
    """Corners of one scan (see the module docstring)."""
    limit = min(cfg.max_range_m, 0.95 * max_range)
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(ranges) & (ranges > 0.05) & (ranges < limit)
    r = np.where(ok, ranges, 0.0)
    pts_all = np.column_stack((r * np.cos(angles), r * np.sin(angles)))
    corners: list[Corner] = []
    cos_max = math.cos(math.radians(cfg.min_angle_deg))
    for cluster in _clusters(r, ok, cfg):
        pts = pts_all[cluster]
        runs: list[tuple[int, int]] = []
        _split(pts, 0, len(pts) - 1, cfg.split_tolerance_m, runs)
        runs.sort()
        fits = []
        for a, b in runs:
            seg = pts[a:b + 1]
            length = float(np.hypot(*(seg[-1] - seg[0])))
            good = len(seg) >= cfg.min_points and length >= cfg.min_length_m
            fit = fit_line(seg) if good else None
            fits.append(fit if fit is not None and fit[2] <= cfg.max_fit_rms_m else None)
        good = [k for k, f in enumerate(fits) if f is not None]
        for k, k2 in itertools.pairwise(good):
            f1, f2 = fits[k], fits[k2]
            if runs[k2][0] - runs[k][1] > MAX_BEAMS_BETWEEN_SIDES:
                continue  # something else lies between the two sides
            if abs(float(f1[1] @ f2[1])) > cos_max:
                continue  # nearly collinear: not a real angle
            c = _intersect(f1[0], f1[1], f2[0], f2[1])
            if c is None:
                continue
            end1, start2 = pts[runs[k][1]], pts[runs[k2][0]]
            if (np.hypot(*(c - end1)) > cfg.max_gap_m or np.hypot(*(c - start2)) > cfg.max_gap_m
                    or np.hypot(c[0], c[1]) > limit):
                continue
            a_end, b_end = pts[runs[k][0]], pts[runs[k2][1]]
            corners.append(Corner(float(c[0]), float(c[1]), _convex(c, a_end, b_end)))
    return corners


def _convex(c: np.ndarray, a: np.ndarray, b: np.ndarray) -> bool:
    """Convex (pointing at the sensor at the origin) iff the corner and the origin lie on
    the same side of the line through the two far ends."""
    d = b - a
    side_c = d[0] * (c[1] - a[1]) - d[1] * (c[0] - a[0])
    side_o = d[0] * (0 - a[1]) - d[1] * (0 - a[0])
    return bool(side_c * side_o > 0)
