"""Scan-matched odometry: point-to-line ICP of each scan against a recent key scan.

The EKF's prediction (Sec. 4) needs the robot's motion since the last scan. Wheel odometry
drifts fast (real logs: metres over a run); matching the scan against a key scan taken a
little earlier gives a much better motion estimate, which the EKF then uses as its control
input with a smaller noise. Corner landmarks still correct what drift is left, and close
loops. If a match is poor (too few inliers, large residual) the wheel odometry is used.

Points are in the robot frame; a new key scan is taken after ``key_distance_m`` or
``key_angle_deg`` of motion, so drift grows per key scan, not per scan.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from dynslam_cli import kernels
from dynslam_cli.ekf import NoiseModel, motion_std
from dynslam_cli.geometry import compose, relative
from dynslam_cli.kernels import PointIndex
from dynslam_cli.types import Pose2D, Scan

RESIDUAL_SIGMA_M = 0.02  # expected point-to-line residual of a good match
# Motion prior for logs without odometry: stationary, with this standard deviation per scan
# (x m, y m, θ rad): a still or slowly moving sensor is matched freely within it.
NO_ODOMETRY_SIGMA = (0.3, 0.3, math.radians(15.0))
# When the match from the odometry's guess fails, these turns of that guess are tried too.
RECOVERY_TURNS_DEG = (-30.0, -20.0, -10.0, 10.0, 20.0, 30.0)


@dataclass(frozen=True)
class MatchConfig:
    enabled: bool = True
    """False: the EKF predicts from wheel odometry alone."""
    max_range_m: float = 20.0
    """Readings beyond this are not matched."""
    subsample: int = 2
    """Use every n-th beam of the current scan."""
    iterations: int = 12
    max_correspondence_m: float = 0.5
    """Pairs farther apart than this (at the first iteration) are ignored ..."""
    min_correspondence_m: float = 0.1
    """... shrinking to this by the last iteration."""
    min_inliers: float = 0.5
    """Share of points that must pair up for the match to count."""
    max_rms_m: float = 0.08
    prior_scale: float = 1.0
    """The odometry prior's standard deviations are the motion noise's times this ..."""
    prior_floor_m: float = 0.0
    """... and at least this (translation) ..."""
    prior_floor_deg: float = 5.0
    """... and this (rotation): wheel odometry of real robots slips in fast turns."""
    key_distance_m: float = 1.0
    key_angle_deg: float = 20.0


def scan_points(scan: Scan, max_range: float, step: int = 1) -> np.ndarray:
    """Valid end points (range in (0.05 m, max range)) of every step-th beam, in the robot
    frame (N×2)."""
    laser = scan.laser
    return kernels.end_points(np.ascontiguousarray(scan.ranges, dtype=np.float64),
                              np.ascontiguousarray(scan.angles, dtype=np.float64), step,
                              laser.x, laser.y, laser.theta, 0.05,
                              min(max_range, scan.max_range))


def _normals(pts: np.ndarray) -> np.ndarray:
    """Unit normals from each point's neighbours in scan order."""
    nxt = np.roll(pts, -1, axis=0)
    prv = np.roll(pts, 1, axis=0)
    t = nxt - prv
    t[0], t[-1] = pts[1] - pts[0], pts[-1] - pts[-2]
    n = np.column_stack((-t[:, 1], t[:, 0]))
    norm = np.hypot(n[:, 0], n[:, 1])
    norm[norm < 1e-9] = 1.0
    return n / norm[:, None]


def icp(ref: PointIndex, ref_normals: np.ndarray, pts: np.ndarray, guess: Pose2D,
        cfg: MatchConfig, prior_sigma: Sequence[float] | None = None
        ) -> tuple[Pose2D, float, float]:
    """Point-to-line ICP: the pose of ``pts``' frame in the frame of the reference points
    (indexed by ``ref``, with their normals), starting at ``guess``; returns (pose, share of
    inliers, RMS of inlier residuals).

    Each of ``cfg.iterations`` Gauss-Newton steps pairs every point with the nearest
    reference point within a gate that shrinks from ``max_correspondence_m`` to
    ``min_correspondence_m``, and minimizes the Huber-weighted distances to the reference
    points' tangent lines. ``prior_sigma`` (x, y, θ standard deviations of the guess) adds
    the guess as a prior, so directions the scene does not constrain (along a corridor, in
    open space) stay at the odometry's value instead of sliding. Fewer than 10 pairs: the
    guess, share 0 and RMS ∞."""
    prior = [0.0, 0.0, 0.0]
    if prior_sigma is not None:  # information of the guess, in residual units
        ratios = [RESIDUAL_SIGMA_M / max(float(s), 1e-6) for s in prior_sigma]
        prior = [r * r for r in ratios]
    x, y, th, share, rms, ok = kernels.icp(
        ref, ref_normals, np.ascontiguousarray(pts), guess.x, guess.y, guess.theta,
        cfg.iterations, cfg.max_correspondence_m, cfg.min_correspondence_m, *prior,
        RESIDUAL_SIGMA_M)
    return (Pose2D(x, y, th), share, rms) if ok else (guess, 0.0, math.inf)


def reference(points: np.ndarray) -> tuple[PointIndex, np.ndarray]:
    """A key scan's points (N×2, in scan order) indexed for ICP, and their normals."""
    return PointIndex(points), _normals(points)


class ScanMatcher:
    """Turns (scan, wheel odometry) into a scan-matched motion increment."""

    def __init__(self, cfg: MatchConfig, noise: NoiseModel) -> None:
        self.cfg = cfg
        self.noise = noise
        self._key: tuple[PointIndex, np.ndarray] | None = None
        self._pose_in_key = Pose2D()  # matched pose of the last scan in the key frame
        self._last_odom = Pose2D()
        self._last_increment = Pose2D()

    def increment(self, scan: Scan) -> tuple[Pose2D, str]:
        """Motion since the previous scan, in the previous robot frame, and where it came
        from: "matched", "recovered" (matched after retrying other guesses), "fallback" (no
        good match: the wheel odometry's) or "odometry" (no key scan to match against)."""
        cfg = self.cfg
        wheel = relative(self._last_odom, scan.odom)
        self._last_odom = scan.odom
        pts = scan_points(scan, cfg.max_range_m, cfg.subsample)
        if self._key is None:
            self._set_key(scan, Pose2D())
            return wheel, "odometry"
        ref, normals = self._key
        guess = compose(self._pose_in_key, wheel)
        if scan.has_odometry:
            st, sr = motion_std(wheel.x, wheel.y, wheel.theta, self.noise)
            st = max(st * cfg.prior_scale, cfg.prior_floor_m)
            sigma = (st, st, max(sr * cfg.prior_scale, math.radians(cfg.prior_floor_deg)))
        else:
            sigma = NO_ODOMETRY_SIGMA
        pose, share, rms = icp(ref, normals, pts, guess, cfg, sigma)
        source = "matched" if self._good(share, rms, pts) else "fallback"
        if source == "fallback" and scan.has_odometry:  # odometry glitches (a doubled turn)
            pose, share, rms = self._recover(pts, guess, sigma)
            source = "recovered" if self._good(share, rms, pts) else "fallback"
        if source == "fallback":
            pose = guess
        inc = relative(self._pose_in_key, pose)
        self._pose_in_key = pose
        self._last_increment = inc
        if (math.hypot(pose.x, pose.y) > cfg.key_distance_m
                or abs(pose.theta) > math.radians(cfg.key_angle_deg)):
            self._set_key(scan, Pose2D())
        return inc, source

    def _good(self, share: float, rms: float, pts: np.ndarray) -> bool:
        return share >= self.cfg.min_inliers and rms <= self.cfg.max_rms_m and len(pts) >= 20

    def _recover(self, pts: np.ndarray, guess: Pose2D, sigma: Sequence[float]
                 ) -> tuple[Pose2D, float, float]:
        """Match again from the constant-velocity guess and from the odometry's guess turned
        by each of RECOVERY_TURNS_DEG, each with the same prior around itself; the best match
        wins."""
        assert self._key is not None
        ref, normals = self._key
        guesses = [compose(self._pose_in_key, self._last_increment)]
        guesses += [Pose2D(guess.x, guess.y, guess.theta + math.radians(d))
                    for d in RECOVERY_TURNS_DEG]
        best = (guess, 0.0, math.inf)
        for g in guesses:
            pose, share, rms = icp(ref, normals, pts, g, self.cfg, sigma)
            if self._good(share, rms, pts) and (share, -rms) > (best[1], -best[2]):
                best = (pose, share, rms)
        return best

    def _set_key(self, scan: Scan, pose: Pose2D) -> None:
        ref = scan_points(scan, self.cfg.max_range_m)
        if len(ref) < 20:
            self._key = None
            return
        self._key = reference(ref)
        self._pose_in_key = pose
