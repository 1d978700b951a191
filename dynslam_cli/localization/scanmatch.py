"""Scan-matched odometry: each scan matched against a local map of key scans, by a
correlative search refined by ICP (the default) or by point-to-line ICP alone.

The EKF's prediction (Sec. 4) needs the robot's motion since the last scan. Wheel odometry
drifts fast (real logs: metres over a run); matching the scan against the last few key scans
gives a much better motion estimate, which the EKF then uses as its control input with a
smaller noise. Corner landmarks still correct what drift is left, and close loops. If a
match is poor (too few inliers, large residual) the wheel odometry is used.

The local map is the points of the last ``local_map_scans`` key scans, placed by their
matched poses in the matcher's own frame (Karto's running scan buffer, Cartographer's
submap in miniature): each scan is matched against several earlier views of the same walls,
so an error of one key scan is averaged out instead of handed on to the next. A new key scan
is taken after ``key_distance_m`` or ``key_angle_deg`` of motion.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from dynslam_cli.geometry import (
    compose,
    compound_covariance,
    moved_far,
    relative,
    rotated_covariance,
    transform_points,
)
from dynslam_cli.localization import _loops, _match
from dynslam_cli.localization._match import PointIndex, first_in_cells
from dynslam_cli.localization.correlative import (
    MIN_SEEN_SHARE,
    LogField,
    OdometryCalibration,
    OdometryScale,
    Posterior,
    View,
    climbed,
    log_field,
    mark_seen,
    reach_cells,
    sampled_walls,
    scan_share,
    search,
    seen_cells,
    seen_matrix,
    with_points,
)
from dynslam_cli.localization.ekf import motion_std
from dynslam_cli.sections import IcpConfig, MatchConfig, NoiseModel
from dynslam_cli.types import Pose2D, Scan

RESIDUAL_SIGMA_M = 0.02  # expected point-to-line residual of a good match
MIN_RESIDUAL_SIGMA_M = 0.005  # the least a fit's own residuals are taken to scatter (m)
# ICP has converged when a step moves the pose less than this (|x| + |y| m, |θ| rad): a
# millimetre, a tenth of a good match's own error (1-2 cm and 0.1-0.3° a scan on real logs).
CONVERGED_STEP = (1e-3, 1e-4)
# Motion prior for logs without odometry: stationary, with this standard deviation per scan
# (x m, y m, θ rad): a still or slowly moving sensor is matched freely within it.
NO_ODOMETRY_SIGMA = (0.3, 0.3, math.radians(15.0))
# When the match from the odometry's guess fails, these turns of that guess are tried too.
RECOVERY_TURNS_DEG = (-30.0, -20.0, -10.0, 10.0, 20.0, 30.0)
# ICP may move a correlative match this far (χ², 3 dof, 1%) under the match's covariance.
REFINE_CHI2 = 11.34
MAX_TURN_SIGMAS = 3.0  # a match may turn this many prior standard deviations from its start
# The correlative table is made anew from the local map's key scans after this many new ones
# (between, each is added to it): a table of 64 key scans costs as much as matching ten scans.
REBUILD_KEYS = 16
MIN_POINTS = 20  # fewer end points than this are not matched


def scan_points(scan: Scan, max_range: float, step: int = 1) -> np.ndarray:
    """Valid end points (range in (0.05 m, max range)) of every step-th beam, in the robot
    frame (N×2)."""
    laser = scan.laser
    return _match.end_points(np.ascontiguousarray(scan.ranges, dtype=np.float64),
                              np.ascontiguousarray(scan.angles, dtype=np.float64), step,
                              laser.x, laser.y, laser.theta, 0.05,
                              min(max_range, scan.max_range))


class Placed(NamedTuple):
    """A scan placed in the matcher's frame: its pose, where that came from, its covariance
    (None: the odometry's noise model applies), whether it agreed with the scan's wheel
    odometry (the next retry's anchor), and the match's own pose where the odometry was
    fused into it."""

    pose: Pose2D
    source: str
    cov: np.ndarray | None = None
    agrees: bool = True
    measured: Pose2D | None = None  # the scan's own pose, before the odometry was fused in


class IcpResult(NamedTuple):
    """A match: the pose, the share of points paired, the RMS of their residuals (m), and the
    information (3×3 over x, y, θ in the reference frame) the pairs alone give the pose."""

    pose: Pose2D
    share: float
    rms: float
    information: np.ndarray


def icp(ref: PointIndex, pts: np.ndarray, guess: Pose2D, cfg: IcpConfig,
        prior_sigma: Sequence[float] | None = None) -> IcpResult:
    """Point-to-line ICP: the pose of ``pts``' frame in the frame of the reference points
    (indexed by ``ref``, which gives their normals), starting at ``guess``.

    Each of ``cfg.iterations`` Gauss-Newton steps pairs every point with the nearest
    reference point within a gate that shrinks from ``max_correspondence_m`` to
    ``min_correspondence_m``, and minimizes the Huber-weighted distances to the reference
    points' tangent lines; converged at a wider gate, the steps go on at the narrowest until
    they converge there (the pose is then the narrow gate's, without its outliers).
    ``prior_sigma`` (x, y, θ standard deviations of the guess) adds the guess as a prior,
    so directions the scene does not constrain (along a corridor, in open space) stay at
    the odometry's value instead of sliding (``cfg.prior_as_pairs``: weighed against the
    pairs as they count in the information). Fewer than 10 pairs: the guess, share 0,
    RMS ∞ and no information.

    With ``cfg.thickness_weights`` each pair is weighed by σ² / (σ² + the variance of
    its reference point's neighbours along its normal), in the solve and the information.

    The information is the pairs' Σ J Jᵀ / σ² (σ = RESIDUAL_SIGMA_M, or with
    ``cfg.residual_sigma = "fit"`` the pairs' own RMS, at least MIN_RESIDUAL_SIGMA_M) counted as
    ``cfg.effective_pairs`` independent pairs (fewer pairs: as themselves, never as more
    than there are): a direction no tangent line constrains (along a corridor's walls) has
    none."""
    prior = [0.0, 0.0, 0.0]
    if prior_sigma is not None:  # information of the guess, in residual units
        ratios = [RESIDUAL_SIGMA_M / max(float(s), 1e-6) for s in prior_sigma]
        prior = [r * r for r in ratios]
        if cfg.prior_as_pairs:  # (the pairs count as effective_pairs in the information)
            prior = [p * max(len(pts) / cfg.effective_pairs, 1.0) for p in prior]
    x, y, th, share, rms, ok, h = _match.icp(
        ref, np.ascontiguousarray(pts), guess.x, guess.y, guess.theta,
        cfg.iterations, cfg.max_correspondence_m, cfg.min_correspondence_m, *prior,
        RESIDUAL_SIGMA_M, *CONVERGED_STEP, cfg.thickness_weights, cfg.segments)
    if not ok:
        return IcpResult(guess, 0.0, math.inf, np.zeros((3, 3)))
    used = max(share * len(pts), 1.0)
    sigma = (max(rms, MIN_RESIDUAL_SIGMA_M) if cfg.residual_sigma == "fit"
             else RESIDUAL_SIGMA_M)
    return IcpResult(Pose2D(x, y, th), share, rms,
                     h * (min(cfg.effective_pairs, used) / used) / sigma ** 2)


SURFACE_STEPS = 30  # Gauss-Newton steps at most (a few from ICP's pose)
SURFACE_CONVERGED = (1e-6, 1e-7)  # a step under this (|x| + |y| m, |θ| rad): converged


def surface_fit(ref: PointIndex, pts: np.ndarray, start: Pose2D, center: Pose2D,
                prior_sigma: Sequence[float], radius: float) -> Pose2D | None:
    """The pose of ``pts``' frame, from ``start``, where its points lie best on the smooth
    surface of the reference points (indexed by ``ref``) within ``radius`` of each
    (_match.surface_fit), with a Gaussian prior about ``center`` (``prior_sigma``: x, y,
    θ) weighed against the points as ICP weighs its guess against its pairs. None where
    fewer than ten points reach the surface."""
    w = [(RESIDUAL_SIGMA_M / max(float(s), 1e-6)) ** 2 for s in prior_sigma]
    x, y, th, ok = _match.surface_fit(
        ref, np.ascontiguousarray(pts, dtype=np.float64), start.x, start.y, start.theta,
        center.x, center.y, center.theta, *w, radius, RESIDUAL_SIGMA_M, SURFACE_STEPS,
        *SURFACE_CONVERGED)
    return Pose2D(x, y, th) if ok else None


def fused_covariance(information: np.ndarray, prior_sigma: Sequence[float]) -> np.ndarray:
    """Covariance of a match fused with its prior: (Ω_match + diag(σ_prior)⁻²)⁻¹."""
    return np.linalg.inv(information + np.diag([1.0 / max(s, 1e-6) ** 2 for s in prior_sigma]))


def sigma_covariance(sigma: Sequence[float]) -> np.ndarray:
    """The diagonal covariance of independent standard deviations (floored at 1e-6)."""
    return np.diag([max(float(s), 1e-6) ** 2 for s in sigma])


def pose_difference(a: Pose2D, b: Pose2D) -> np.ndarray:
    """a − b as (x, y, θ), the angle wrapped."""
    return np.array([a.x - b.x, a.y - b.y, math.remainder(a.theta - b.theta, math.tau)])


def fused_pose(match: Pose2D, information: np.ndarray, odometry: Pose2D,
               prior_sigma: Sequence[float], glitch: float | None,
               prior_cov: np.ndarray | None = None) -> tuple[Pose2D, np.ndarray] | None:
    """The match fused with the odometry's pose by their information, x_m + Σ Ω_o (x_o −
    x_m) with Σ = (Ω_m + Ω_o)⁻¹ and Ω_o = diag(``prior_sigma``)⁻² (or ``prior_cov``⁻¹
    where the odometry pose's full covariance is known), and Σ. Where the scan constrains
    nothing (along a corridor) the odometry's value remains; where it constrains
    everything, the match's. None where the odometry slipped: its prior is a Gaussian
    with a floor of ``glitch`` times its peak (:func:`odometry_log_prior`), whose
    posterior peaks at the match alone where the two disagree by more than
    χ² = 2 ln(1/glitch) under their combined covariance (Σ_o + Ω_m⁻¹)⁻¹ = Ω_m − Ω_m Σ Ω_m
    (no inverse of a match that leaves a direction free). ``glitch`` None: the odometry
    is known not to have slipped (the two are fused however far apart)."""
    d = pose_difference(odometry, match)
    if prior_cov is None:
        cov = fused_covariance(information, prior_sigma)
        weighted = d / np.maximum(np.asarray(prior_sigma, dtype=float), 1e-6) ** 2
    else:
        prior_information = np.linalg.inv(prior_cov)
        cov = np.linalg.inv(information + prior_information)
        weighted = prior_information @ d
    if glitch is not None and float(
            d @ (information - information @ cov @ information) @ d) > 2.0 * math.log(
            1.0 / glitch):
        return None
    step = cov @ weighted
    return Pose2D(match.x + step[0], match.y + step[1], match.theta + step[2]), cov


def increment_covariance(cov: np.ndarray, previous: Pose2D) -> np.ndarray:
    """A pose covariance (matcher frame) as the covariance of the increment from
    ``previous``, in the previous robot frame (its rotation undone)."""
    return rotated_covariance(cov, -previous.theta)


# A key scan's range view: the nearest end point in each bearing bin of this width ...
VIEW_BIN_RAD = math.radians(1.0)
VIEW_BINS = math.ceil(math.tau / VIEW_BIN_RAD)
SEEN_THROUGH_M = 0.1  # ... which an earlier key scan's end point must lie this far inside


class RangeView(NamedTuple):
    """What a key scan saw: its laser's position and the robot's heading (matcher frame),
    and per bearing bin about the laser (robot frame, from −π) the shortest beam's range in
    that bin and the two beside it (a beam with no return: the laser's reach; 0 where one
    of them holds no beam: nothing seen there)."""

    x: float
    y: float
    heading: float
    nearest: np.ndarray


def range_view(pose: Pose2D, scan: Scan, reach: float) -> RangeView:
    """The range view of a scan seen from ``pose``, its beams with no return (or beyond
    ``reach``) free as far as ``reach``."""
    laser = scan.laser
    r = np.asarray(scan.ranges, dtype=np.float64)
    seen = r > 0.05  # (a dropped beam is NaN; one with no return may be +inf or max range)
    nearest = np.full(VIEW_BINS, np.inf)
    np.minimum.at(nearest, bearing_bins(np.asarray(scan.angles, dtype=np.float64)[seen]
                                        + laser.theta), np.minimum(r[seen], reach))
    nearest[np.isinf(nearest)] = 0.0
    nearest = np.minimum(nearest, np.minimum(np.roll(nearest, 1), np.roll(nearest, -1)))
    at = transform_points(pose, np.array([[laser.x, laser.y]]))[0]
    return RangeView(float(at[0]), float(at[1]), pose.theta, nearest)


def bearing_bins(bearing: np.ndarray) -> np.ndarray:
    """The range view's bin of each bearing (radians, robot frame)."""
    return np.floor((bearing + math.pi) / VIEW_BIN_RAD).astype(int) % VIEW_BINS


def _rear_bins() -> np.ndarray:
    """The bins that reach more than a microradian past ±90° from a view's heading: where a
    180° laser saw nothing."""
    low = np.arange(VIEW_BINS) * VIEW_BIN_RAD - math.pi  # (a bin's bearings: [low, low + bin))
    return (low < -math.pi / 2 - 1e-6) | (low + VIEW_BIN_RAD > math.pi / 2 + 1e-6)


REAR_BINS = _rear_bins()


class ViewStack(NamedTuple):
    """Range views as arrays (their positions, headings and per-bin ranges, V×VIEW_BINS),
    with what each cannot have seen beyond: its reach (its longest range less
    SEEN_THROUGH_M, a part in 10⁹ to spare for rounding: no point farther lies inside what
    it saw) and whether it is blind behind (every bin of REAR_BINS empty: no point more
    than a microradian behind it lies in a bin it saw)."""

    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    nearest: np.ndarray
    reach: np.ndarray
    rear_blind: np.ndarray


def stacked_views(views: Sequence[RangeView]) -> ViewStack:
    """``views`` as one :class:`ViewStack`."""
    x, y, heading, nearest = (np.ascontiguousarray(v, dtype=np.float64)
                              for v in zip(*views, strict=True))
    reach = (nearest.max(axis=1) - SEEN_THROUGH_M) * (1.0 + 1e-9)
    rear_blind = ~(nearest[:, REAR_BINS] > 0.0).any(axis=1)
    return ViewStack(x, y, heading, nearest, reach, rear_blind.astype(np.uint8))


def seen_through_counts(stack: ViewStack, points: np.ndarray) -> np.ndarray:
    """For each point (N×2, matcher frame), how many of the views saw more than
    SEEN_THROUGH_M beyond it in its direction: where their beams passed, nothing stood."""
    return _match.seen_through_counts(np.ascontiguousarray(points, dtype=np.float64),
                                      *stack, math.pi, VIEW_BIN_RAD, SEEN_THROUGH_M)


def seen_through(view: RangeView, points: np.ndarray) -> np.ndarray:
    """Which points (N×2, matcher frame) lie more than SEEN_THROUGH_M inside what the view
    saw in their direction: where its beams passed, nothing stands."""
    return seen_through_counts(stacked_views([view]), points) > 0


ORIGIN_CELL = np.zeros(1, dtype=np.intp)  # (one offset of no cells, for mean_scores)


class LocalMap:
    """The last ``local_map_scans`` key scans' points in the matcher's frame, thinned to one
    point per ``local_map_cell_m`` square, indexed for ICP with their normals (the spread
    of each point's ``normal_neighbours`` nearest, with ``normal_gap`` this side of a gap)."""

    def __init__(self, cfg: MatchConfig) -> None:
        self._keys: deque[np.ndarray] = deque(maxlen=cfg.local_map_scans)
        self._seen_from: deque[tuple[float, float, float]] = deque(maxlen=cfg.local_map_scans)
        """Each key scan's position and its laser's reach (x, y, metres)."""
        self._cfg = cfg
        self.reference: PointIndex | None = None
        self._field: LogField | None = None
        self._walls: deque[np.ndarray] = deque(maxlen=cfg.local_map_scans)  # ... sampled
        self._fresh: list[np.ndarray] = []  # key scans not in the field yet
        self._fans: deque[View] = deque(maxlen=cfg.local_map_scans)
        """Each key scan's laser and end points (matcher frame), where ``seen_only`` or
        ``inliers_over = "seen"`` asks."""
        self._looked: LogField | None = None  # the field ``_looked_grid`` was drawn for
        self._looked_grid = np.zeros((0, 0))  # ... where the fans looked (1) or not (0)
        self._stale = 0  # key scans added to the field since it was made anew
        self._views: deque[RangeView] = deque(maxlen=cfg.local_map_scans)
        self._stacked: ViewStack | None = None  # the views, stacked when first asked
        # after a key scan

    def add(self, pose: Pose2D, points: np.ndarray, reach: float = math.inf,
            view: RangeView | None = None, laser: tuple[float, float] = (0.0, 0.0)) -> None:
        """A key scan's points (robot frame, in beam order) seen from ``pose`` (matcher
        frame) by a laser at ``laser`` (robot frame) whose end points reach ``reach``
        metres (``view``: its range view, where the local map clears what it saw
        through)."""
        if view is not None:
            if self._cfg.clear_seen_through and self._keys:
                self._clear(view)
            self._views.append(view)
            self._stacked = None
        self._keys.append(transform_points(pose, points))
        self._seen_from.append((pose.x, pose.y, reach))
        if self._cfg.method == "correlative":  # (ICP matches against the points alone)
            if self._cfg.correlative.seen_only or self._cfg.inliers_over == "seen":
                self._fans.append(View(transform_points(pose, np.array([laser]))[0],
                                       self._keys[-1]))
                self._looked = None  # (a new fan: drawn again when next asked)
            half = self._cfg.correlative.resolution_m / 2
            walls = transform_points(pose, sampled_walls(points, half))
            self._walls.append(self._thinned(walls, half))
            self._fresh.append(self._walls[-1])
        pts = np.concatenate(self._keys)
        if len(pts) < MIN_POINTS:
            self.reference = None
            return
        self.reference = PointIndex(self._thinned(pts, self._cfg.local_map_cell_m),
                                    neighbours=self._cfg.normal_neighbours,
                                    gap=self._cfg.normal_gap or math.inf)

    def _thinned(self, points: np.ndarray, cell: float) -> np.ndarray:
        """One point per ``cell`` square, as ``thin_to`` says."""
        if self._cfg.thin_to == "mean":
            return cell_means(points, cell)
        return points[thin(points, cell)]

    def _clear(self, view: RangeView) -> None:
        """Takes the key scans' points and walls that ``view`` saw through out of them (the
        lookup table keeps them until it is made anew)."""
        for keys in (self._keys, self._walls):
            for k, pts in enumerate(keys):
                passed = seen_through(view, pts)
                if passed.any():
                    keys[k] = pts[~passed]

    def seen_free(self, points: np.ndarray, views: int) -> np.ndarray:
        """Which points (N×2, matcher frame) at least ``views`` key scans of the local map
        saw through (:func:`seen_through`): where nothing stood when they looked."""
        if len(self._views) < views:
            return np.zeros(len(points), dtype=bool)
        if self._stacked is None:
            self._stacked = stacked_views(self._views)
        return seen_through_counts(self._stacked, points) >= views

    def within_reach(self, points: np.ndarray, margin: float) -> np.ndarray:
        """Which points (N×2, matcher frame) lie within a key scan's reach, less
        ``margin``: where the local map could have seen a wall."""
        keys = np.array(self._seen_from).reshape(-1, 3)
        d2 = ((points[:, None, :] - keys[None, :, :2]) ** 2).sum(-1)
        return np.any(d2 <= np.maximum(keys[None, :, 2] - margin, 0.0) ** 2, axis=1)

    def looked_share(self, pose: Pose2D, points: np.ndarray) -> float:
        """The share of ``points`` (N×2, robot frame) that land, seen from ``pose`` (matcher
        frame), on the lookup table's cells where the key scans looked (their fans, widened
        by a wall's reach): the search's own mean over a 0/1 grid."""
        field = self.field()
        looked = field.seen  # (``seen_only`` keeps it marked)
        if looked is None:
            if self._looked is not field:  # (a key scan added since, or the table grown)
                cfg = self._cfg.correlative
                self._looked_grid = seen_cells(list(self._fans), field.origin,
                                               field.grid.shape, cfg.resolution_m,
                                               reach_cells(cfg))
                self._looked = field
            looked = self._looked_grid
        share = _loops.mean_scores(looked, float(field.origin[0]), float(field.origin[1]),
                                   field.resolution, np.ascontiguousarray(points, np.float64),
                                   pose.x, pose.y, np.array([pose.theta]), ORIGIN_CELL,
                                   ORIGIN_CELL)
        return float(share[0, 0, 0])

    def field(self) -> LogField:
        """The correlative search's lookup table of the local map. Made anew from the local
        map's points every REBUILD_KEYS key scans (when first asked after them); between,
        each new key scan's points are added to it, and the key scans that left the local
        map stay in it."""
        cfg = self._cfg.correlative
        fresh = len(self._fresh)  # (the last key scans, whose fans are not marked yet)
        if self._field is None or self._stale >= REBUILD_KEYS:
            walls = np.concatenate(self._walls)
            self._field = log_field(self._thinned(walls, cfg.resolution_m / 2), cfg)
            self._stale = 0
        elif self._fresh:
            self._field = with_points(self._field, np.concatenate(self._fresh), cfg)
            self._stale += len(self._fresh)
        self._fresh = []
        if cfg.seen_only:
            self._mark_seen(self._field, fresh)
        return self._field

    def _mark_seen(self, field: LogField, fresh: int) -> None:
        """Where the key scans looked, into ``field.seen``: the ``fresh`` last ones' fans
        added to it, or all of them where the field is new (made anew, or grown)."""
        if field.seen is None:
            field.seen = np.zeros(field.grid.shape)
            fresh = len(self._fans)
        elif not fresh:
            return
        fans = list(self._fans)[-fresh:]
        cfg = self._cfg.correlative
        mark_seen(field.seen, fans, field.origin, cfg.resolution_m, reach_cells(cfg))


def thin(points: np.ndarray, cell: float) -> np.ndarray:
    """Indices of the first point in each ``cell`` square (in order of first appearance)."""
    return first_in_cells(np.ascontiguousarray(points, dtype=np.float64), cell)


def cell_means(points: np.ndarray, cell: float) -> np.ndarray:
    """The mean of the points (N×2) in each ``cell`` square, in order of each square's
    first point."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    group, first = _match.cell_groups(points, cell)
    sums = np.column_stack([np.bincount(group, weights=points[:, k], minlength=len(first))
                            for k in (0, 1)])
    return sums / np.bincount(group, minlength=len(first))[:, None]


class WheelOdometry:
    """The wheel odometry's motion since the previous scan, in the previous robot frame,
    from each scan's odometry pose in turn (the first scan's: from the origin)."""

    def __init__(self) -> None:
        self._last = Pose2D()

    def increment(self, odom: Pose2D) -> Pose2D:
        step = relative(self._last, odom)
        self._last = odom
        return step


class ScanMatcher:
    """Turns (scan, wheel odometry) into a scan-matched motion increment."""

    def __init__(self, cfg: MatchConfig, noise: NoiseModel) -> None:
        self.cfg = cfg
        self.noise = noise
        self._map = LocalMap(cfg)
        self._pose = Pose2D()  # matched pose of the last scan in the matcher's frame
        self._key_pose: Pose2D | None = None  # ... and of the last key scan
        self._wheel = WheelOdometry()
        self._last_increment = Pose2D()
        self._odometry = OdometryScale(cfg.correlative.learn_odometry)
        self._calibration = OdometryCalibration(cfg.correlative.calibrate_odometry,
                                                cfg.correlative.calibrate_rotation,
                                                cfg.correlative.calibrate_mount)
        # the last scan placed where its wheel odometry agrees (matched within the
        # odometry's window, or at its guess where nothing fitted): its pose and odometry
        self._anchor: tuple[Pose2D, Pose2D] | None = None
        # fusion "filter": the covariance of self._pose about the local map (matcher frame)
        self._cov = np.zeros((3, 3))
        self.fit_rms: float | None = None
        """The last scan's refined match: its rms distance to the local map (m); None where
        it was not refined (no match, or the search's pose stood)."""

    def increment(self, scan: Scan) -> tuple[Pose2D, str, np.ndarray | None]:
        """Motion since the previous scan, in the previous robot frame, where it came from,
        and its covariance where the scan was matched (else None: the odometry's noise model
        applies). Sources: "matched", "recovered" (matched after retrying other guesses),
        "fallback" (no good match: the wheel odometry's) or "odometry" (no local map to
        match against)."""
        cfg = self.cfg
        self.fit_rms = None
        raw = self._wheel.increment(scan.odom)
        wheel = self._calibration.correct(raw)
        guess = compose(self._pose, wheel)
        predicted = self._predicted(wheel)
        pts = scan_points(scan, cfg.max_range_m, cfg.subsample)
        reference = self._map.reference
        pose, source, cov, agrees, measured = (
            Placed(guess, "odometry") if reference is None
            else self._match(scan, pts, reference, guess, wheel, predicted))
        if predicted is not None:
            self._cov = predicted if cov is None else cov
        if agrees:
            self._anchor = (pose, scan.odom)
        inc = relative(self._pose, pose)
        if cov is not None:
            cov = increment_covariance(cov, self._pose)
        if source == "matched" and cfg.method == "correlative":
            if measured is not None and self._calibration.enabled:  # (a match the odometry
                # was fused into, weighed against the prior it was fused with)
                sigma = self._odometry.std(wheel, cfg.correlative.odometry)
                self._calibration.learn(relative(self._pose, measured), raw,
                                        scan_share(cov, wheel, sigma),
                                        seen_matrix(cov, sigma[0]))
            self._odometry.learn(inc, wheel, cfg.correlative.odometry)
        self._pose = pose
        self._last_increment = inc
        key = self._key_pose
        if key is None or moved_far(key, pose, cfg.key_distance_m,
                                    math.radians(cfg.key_angle_deg)):
            reach = min(cfg.max_range_m, scan.max_range)
            self._map.add(pose, pts if cfg.subsample == 1 else scan_points(scan, cfg.max_range_m),
                          reach, range_view(pose, scan, reach)
                          if cfg.clear_seen_through or cfg.skip_seen_free else None,
                          (scan.laser.x, scan.laser.y))
            self._key_pose = pose
        return inc, source, cov

    @property
    def mount_error(self) -> tuple[float, float]:
        """The laser mount's error learned so far (OdometryCalibration.mount_error; 0 where
        it is not learned)."""
        return self._calibration.mount_error

    def _predicted(self, wheel: Pose2D) -> np.ndarray | None:
        """Fusion "filter": the covariance of the odometry's guess, the last pose's
        covariance moved on by the wheel increment with the filter's odometry noise
        (``filter_odometry``); else None (each match is fused with the increment alone)."""
        correlative = self.cfg.correlative
        if correlative.fusion != "filter":
            return None
        st, sr = motion_std(wheel.x, wheel.y, wheel.theta, correlative.filter_odometry)
        return compound_covariance(self._pose, self._cov, wheel,
                                   sigma_covariance((st, st, sr)))

    def _prior_sigma(self, scan: Scan, wheel: Pose2D) -> tuple[float, float, float]:
        """Standard deviations (x, y, θ) of the odometry's guess."""
        cfg = self.cfg
        if not scan.has_odometry:
            return NO_ODOMETRY_SIGMA
        st, sr = motion_std(wheel.x, wheel.y, wheel.theta, self.noise)
        st = max(st * cfg.prior_scale, cfg.prior_floor_m)
        return st, st, max(sr * cfg.prior_scale, math.radians(cfg.prior_floor_deg))

    def _match(self, scan: Scan, pts: np.ndarray, reference: PointIndex,
               guess: Pose2D, wheel: Pose2D, predicted: np.ndarray | None) -> Placed:
        """The scan's points placed in the matcher's frame (``predicted``: the guess's full
        covariance, where the filter carries it)."""
        if self.cfg.within_reach:
            seen = self._map.within_reach(transform_points(guess, pts), self.cfg.reach_margin_m)
            if np.count_nonzero(seen) >= MIN_POINTS:
                pts = pts[seen]
        if self.cfg.method == "correlative" and scan.has_odometry:
            return self._correlative(pts, reference, guess, wheel, scan.odom, predicted)
        sigma = self._prior_sigma(scan, wheel)
        match = icp(reference, pts, guess, self.cfg.icp, sigma)
        if self._good(match, pts, guess, sigma):
            self.fit_rms = match.rms
            return Placed(match.pose, "matched", fused_covariance(match.information, sigma))
        if scan.has_odometry:  # odometry glitches (a doubled turn)
            recovered = self._recover(reference, pts, guess, wheel, sigma)
            if recovered is not None:
                return Placed(recovered.pose, "recovered",
                              fused_covariance(recovered.information, sigma))
        return Placed(guess, "fallback")

    def _correlative(self, pts: np.ndarray, reference: PointIndex, guess: Pose2D,
                     wheel: Pose2D, odom: Pose2D, predicted: np.ndarray | None) -> Placed:
        """The correlative search's best pose around the odometry's guess (prior: the
        wheel odometry's noise model), refined by ICP within the search's own uncertainty.
        Its covariance: the refined match's information fused with the odometry's prior
        (as ICP's own matches), or the search's posterior where ICP did not refine it.
        Where too few end points land on the local map's walls, or the best pose lies
        beyond the odometry's window, the search is run again around each of
        :meth:`_retry_guesses`, and the best-scoring wins ("recovered" if it is not the
        first); nothing good: the odometry. No match turns further from the odometry's
        guess than :meth:`_widest_turn`."""
        cfg = self.cfg
        if len(pts) < MIN_POINTS:
            return Placed(guess, "fallback")
        window = self._search_sigma(wheel)
        field = self._map.field()
        voxel = cfg.correlative.voxel_m
        searched = pts[thin(pts, voxel)] if voxel > 0 else pts
        turn = self._widest_turn(wheel)
        post = search(field, searched, guess, window, cfg.correlative,
                      self._lost_below(guess, searched), turn)
        source = "matched"
        agrees = not _outside(post.pose, guess, window, cfg.correlative.window_sigmas)
        if not self._fits(post.score, post.pose, searched, agrees) or not agrees or (
                cfg.confirm_jumps and self._jumped()):
            for retry_guess, sigma, is_anchored in self._retry_guesses(odom, window):
                retry = search(field, searched, retry_guess, sigma, cfg.correlative,
                               cfg.min_inliers, turn)
                if retry.score > post.score and self._plausible_turn(retry.pose, guess, wheel):
                    post, source = retry, "recovered"
                    agrees = is_anchored and not _outside(retry.pose, retry_guess, sigma,
                                                          cfg.correlative.window_sigmas)
        relax = agrees and source == "matched"  # (a retry's match must fit as all do)
        if not self._fits(post.score, post.pose, searched, relax):
            return Placed(guess, "fallback")  # (at the odometry's guess: it agrees with it)
        if cfg.skip_seen_free:  # (where the search placed the scan)
            standing = ~self._map.seen_free(transform_points(post.pose, pts),
                                            cfg.seen_free_views)
            if np.count_nonzero(standing) >= MIN_POINTS:
                pts = pts[standing]
        refined = icp(reference, pts, post.pose, cfg.icp, np.sqrt(np.diag(post.cov)))
        d = pose_difference(refined.pose, post.pose)
        relax = relax and not _outside(refined.pose, guess, window,  # (and it stays there)
                                       cfg.correlative.window_sigmas)
        if (not self._fits(refined.share, refined.pose, pts, relax) or refined.rms > cfg.max_rms_m
                or d @ np.linalg.solve(post.cov, d) > REFINE_CHI2):
            if post.score < cfg.min_inliers:  # (taken for what the local map saw: only
                return Placed(guess, "fallback")  # as refined within the window)
            return Placed(post.pose, source, post.cov, agrees)
        self.fit_rms = refined.rms
        if cfg.correlative.polish != "none":
            refined = self._polished(field, reference, pts, refined, post)
        st, sr = self._odometry.std(wheel, cfg.correlative.odometry)
        slipped_only_if_searched = agrees and cfg.correlative.slip_test == "search"
        fused = (fused_pose(refined.pose, refined.information, guess, (st, st, sr),
                            None if slipped_only_if_searched
                            else cfg.correlative.odometry_glitch, predicted)
                 if source == "matched" else None)
        if fused is not None:
            return Placed(fused[0], source, fused[1], agrees, refined.pose)
        return Placed(refined.pose, source, fused_covariance(refined.information, (st, st, sr)),
                      agrees)

    def _polished(self, field: LogField, reference: PointIndex, pts: np.ndarray,
                  refined: IcpResult, post: Posterior) -> IcpResult:
        """ICP's match ``refined`` of ``pts`` moved as ``polish`` says, with the search's
        posterior ``post`` as its prior (as ICP's)."""
        correlative = self.cfg.correlative
        sigma = tuple(np.sqrt(np.diag(post.cov)))
        if correlative.polish == "field":
            return refined._replace(pose=climbed(field, pts, refined.pose, post.pose, sigma,
                                                 RESIDUAL_SIGMA_M, correlative))
        fit = surface_fit(reference, pts, refined.pose, post.pose, sigma,
                          correlative.surface_radius_m)
        return refined if fit is None else refined._replace(pose=fit)

    def _fits(self, share: float, pose: Pose2D, pts: np.ndarray, relax: bool) -> bool:
        """Whether ``share`` of ``pts`` fitting the local map at ``pose`` is enough: at
        least ``min_inliers`` of all of them, or with ``inliers_over = "seen"`` and
        ``relax`` (the match found within the odometry's window, not a retry's)
        ``seen_inliers`` of those that land where the local map looked (at least
        MIN_SEEN_SHARE of all counted)."""
        cfg = self.cfg
        if share >= cfg.min_inliers or cfg.inliers_over == "all" or not relax:
            return share >= cfg.min_inliers
        return share >= self._seen_needed(pose, pts)

    def _seen_needed(self, pose: Pose2D, pts: np.ndarray) -> float:
        """The share of ``pts`` that must fit at ``pose`` under ``inliers_over = "seen"``:
        ``seen_inliers`` of those that land where the local map looked (at least
        MIN_SEEN_SHARE of all counted)."""
        return self.cfg.seen_inliers * max(self._map.looked_share(pose, pts), MIN_SEEN_SHARE)

    def _lost_below(self, guess: Pose2D, pts: np.ndarray) -> float:
        """The score under which the search's window around the odometry's ``guess``
        explains nothing and is widened: ``min_inliers``, or with ``lost_over = "seen"``
        the share :meth:`_fits` takes of a match found there (``seen_inliers`` of the end
        points ``pts`` that land, at the guess, where the local map looked)."""
        cfg = self.cfg
        if cfg.lost_over == "all":
            return cfg.min_inliers
        return min(cfg.min_inliers, self._seen_needed(guess, pts))

    def _search_sigma(self, wheel: Pose2D) -> tuple[float, float, float]:
        """The standard deviations (x, y, θ) of a wheel increment that the search's window
        and prior and its slip test take: scaled as learned (``OdometryScale``), or as
        stated where the learned scale is for the fusion alone (``learned_scale_in``)."""
        correlative = self.cfg.correlative
        st, sr = (motion_std(wheel.x, wheel.y, wheel.theta, correlative.odometry)
                  if correlative.learned_scale_in == "fusion"
                  else self._odometry.std(wheel, correlative.odometry))
        return st, st, sr

    def _jumped(self) -> bool:
        """Whether the scan before was placed against its wheel odometry."""
        return self._anchor is not None and self._anchor[0] != self._pose

    def _retry_guesses(self, odom: Pose2D, sigma: tuple[float, float, float]
                       ) -> list[tuple[Pose2D, tuple[float, float, float], bool]]:
        """Where the odometry's guess does not explain the scan, the guesses tried next, each
        with its prior's standard deviations and whether a match there agrees with the
        odometry: the last motion repeated (stale odometry: still for a few scans, then the
        whole motion at once); and, where the scan before was placed against its odometry,
        the odometry since the last scan that agreed with it (that scan before was stale:
        its content from another moment than its odometry, as a log sorted by lying stamps
        has it)."""
        guesses = [(compose(self._pose, self._last_increment), sigma, False)]
        if self._jumped():
            anchor_pose, anchor_odom = self._anchor
            since = relative(anchor_odom, odom)
            guesses.append((compose(anchor_pose, since), self._search_sigma(since), True))
        return guesses

    def _good(self, match: IcpResult, pts: np.ndarray, start: Pose2D,
              sigma: Sequence[float]) -> bool:
        """Enough pairs, close enough, and a turn from where ICP started within
        MAX_TURN_SIGMAS of the prior (a room's walls also fit turned by 90°)."""
        return (match.share >= self.cfg.min_inliers and match.rms <= self.cfg.max_rms_m
                and len(pts) >= MIN_POINTS and abs(math.remainder(match.pose.theta - start.theta,
                                                          math.tau))
                <= MAX_TURN_SIGMAS * sigma[2])

    @staticmethod
    def _widest_turn(wheel: Pose2D) -> float:
        """How far (radians) a match may turn from the odometry's guess: as far as the
        odometry turned (a doubled or a missed turn) plus the widest turn retried, not by
        the 90° that fits a corridor's walls to a hall's."""
        return abs(wheel.theta) + math.radians(max(RECOVERY_TURNS_DEG))

    def _plausible_turn(self, pose: Pose2D, guess: Pose2D, wheel: Pose2D) -> bool:
        """Whether a recovered turn differs from the odometry's by at most
        :meth:`_widest_turn`."""
        return (abs(math.remainder(pose.theta - guess.theta, math.tau))
                <= self._widest_turn(wheel))

    def _recover(self, reference: PointIndex, pts: np.ndarray,
                 guess: Pose2D, wheel: Pose2D, sigma: Sequence[float]) -> IcpResult | None:
        """Match again from the constant-velocity guess and from the odometry's guess turned
        by each of RECOVERY_TURNS_DEG, each with the same prior around itself; the best good
        match with a plausible turn wins (None: none)."""
        guesses = [compose(self._pose, self._last_increment)]
        guesses += [Pose2D(guess.x, guess.y, guess.theta + math.radians(d))
                    for d in RECOVERY_TURNS_DEG]
        best = None
        for g in guesses:
            match = icp(reference, pts, g, self.cfg.icp, sigma)
            if (self._good(match, pts, g, sigma) and self._plausible_turn(match.pose, guess, wheel)
                    and (best is None or (match.share, -match.rms) > (best.share, -best.rms))):
                best = match
        return best


def _outside(pose: Pose2D, guess: Pose2D, sigma: Sequence[float], sigmas: float) -> bool:
    """Whether ``pose`` lies more than ``sigmas`` standard deviations from ``guess`` in
    translation or rotation."""
    return (math.hypot(pose.x - guess.x, pose.y - guess.y) > sigmas * max(sigma[0], sigma[1])
            or abs(math.remainder(pose.theta - guess.theta, math.tau)) > sigmas * sigma[2])
