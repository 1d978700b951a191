"""Correlative scan-to-submap matching with the covariance of its own response (Olson,
"Real-Time Correlative Scan Matching", ICRA 2009).

The submap (the last key scans' points at their estimated poses) is rasterized into a
lookup table of each cell's log-likelihood for a beam ending there (each point's Gaussian
centred on the point itself, not on its cell, on a lattice fixed in the submap's frame: a
reading moved by a millimetre moves the table by as little): a beam's end point lies
near a wall with a Gaussian spread (``field_sigma_m``) or is an outlier with probability
``outlier_share`` (a person, a glass pane, a wall not yet in the submap). Every pose of a
window around the wheel odometry's guess is scored by the mean log-likelihood of the scan's
end points; the posterior over the window is

    log p(x | z, u) = effective_points · mean log-likelihood(x) − ½ (x − u)ᵀ Σᵤ⁻¹ (x − u),

the scan's evidence times the number of end points that err independently (neighbouring
beams see the same wall, and the submap shares its key scans' errors: they do not count
as independent), fused with the odometry's prior of the stated noise model. The match is
the posterior's best pose, refined to its mean over the cells next to it (finer than a
cell); the covariance is the posterior's spread about it: long along a corridor, where
every offset along it scores the same, small at a corner; where the scan sees nothing
(an open hall) the prior, that is the odometry, remains.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from dynslam_cli.localization import _loops
from dynslam_cli.localization.ekf import motion_std
from dynslam_cli.sections import CorrelativeConfig, NoiseModel
from dynslam_cli.types import Pose2D


class OdometryScale:
    """How far the wheel odometry's increments fall from the matched ones, in the standard
    deviations of its stated noise model, learned from the log as it is read: the mean
    squared error (each clipped at 3σ, so that a glitch teaches little) over the matched
    scans so far, forgetting over the last LEARN_SCANS; translation and rotation apart. The
    model's standard deviations are scaled by its square root, between SCALE_RANGE's ends.
    With perfect odometry the matches' own errors (a few millimetres) are all that is left,
    so the odometry is trusted about ten times as much as the model says."""

    LEARN_SCANS = 200
    SCALE_RANGE = (0.1, 3.0)

    def __init__(self, enabled: bool = True) -> None:
        self.enabled = enabled
        self._mean_sq = [1.0, 1.0]
        self._count = 0
        self.scale = (1.0, 1.0)

    def std(self, wheel: Pose2D, model: NoiseModel) -> tuple[float, float]:
        """The scaled standard deviations (translation m, rotation rad) of a wheel
        increment."""
        st, sr = motion_std(wheel.x, wheel.y, wheel.theta, model)
        return st * self.scale[0], sr * self.scale[1]

    def learn(self, matched: Pose2D, wheel: Pose2D, model: NoiseModel) -> None:
        """One matched increment and the wheel odometry's, both in the previous robot
        frame."""
        if not self.enabled:
            return
        st, sr = motion_std(wheel.x, wheel.y, wheel.theta, model)
        z = (((matched.x - wheel.x) ** 2 + (matched.y - wheel.y) ** 2) / (2.0 * st * st),
             math.remainder(matched.theta - wheel.theta, math.tau) ** 2 / (sr * sr))
        self._count += 1
        rate = max(1.0 / self._count, 1.0 / self.LEARN_SCANS)
        lo, hi = self.SCALE_RANGE
        for k in range(2):
            self._mean_sq[k] += rate * (min(z[k], 9.0) - self._mean_sq[k])
        self.scale = tuple(min(max(math.sqrt(m), lo), hi) for m in self._mean_sq)


class OdometryCalibration:
    """The wheel odometry's systematic errors, learned from the log as it is read: a scale
    of its translation, a scale of its rotation and a heading drift per metre driven, such
    that the true increment is (s_t·dx, s_t·dy, s_r·dθ + b·|d|). Least squares between the
    matched increments (the scan's own measure, before the odometry is fused into it) and
    the wheel's, each regressed on the one that errs less: the match's translation on the
    wheel's (a wheel step is known to a few per cent, a match along it often less well),
    the wheel's turn on the match's (a wheel's turn of one step is mostly its noise: the
    match's regressed on it would shrink the scale toward zero). Forgetting over
    LEARN_SCANS matched scans, each parameter pulled
    toward no error by PRIOR_STEPS steps' worth of evidence (so a few matches move it
    little); kept within SCALE_LIMIT and DRIFT_LIMIT_DEG_PER_M. A bias removed, what is left
    of the odometry's error is random, the part its noise model can state honestly."""

    LEARN_SCANS = 2000
    PRIOR_STEPS = 50.0
    STEP_M, STEP_RAD = 0.05, 0.02  # a typical step, to weigh the prior
    SCALE_LIMIT = (0.8, 1.25)
    DRIFT_LIMIT_DEG_PER_M = 5.0
    MOUNT_LIMIT_M = 0.25

    def __init__(self, enabled: bool = False, rotation: bool = True, mount: bool = False
                 ) -> None:
        self.enabled = enabled
        self.rotation = rotation  # (False: the translation's scale alone)
        self.mount = mount  # (True: the laser mount's error too, :meth:`_learn_with_mount`)
        p = self.PRIOR_STEPS
        self._tt = np.array([p * self.STEP_M ** 2, p * self.STEP_M ** 2])  # Σ m·w, Σ w·w
        # with the mount: normal equations of m_t = s_t·w_t + (I − R(θ))·e over (s_t, e)
        self._mm = np.diag([p * self.STEP_M ** 2, p * self.STEP_RAD ** 2, p * self.STEP_RAD ** 2])
        self._mb = np.array([p * self.STEP_M ** 2, 0.0, 0.0])
        self.mount_error = (0.0, 0.0)
        """Where the log states the laser, less where it is seen from the wheels' centre of
        turning (m, robot frame): the robot frame the matcher places through the stated
        mount turns about the point this far from its origin. The poses are still reported
        in the frame the log states (the robot's, as whoever wrote the log defined it)."""
        # rotation: normal equations of wheel θ = gain·m_θ + offset·d over the regressors
        # a = [m_θ, d]: Σ aᵀa and Σ aᵀ w_θ (s_r = 1 / gain, b = −offset·s_r)
        self._rr = np.diag([p * self.STEP_RAD ** 2, p * self.STEP_M ** 2])
        self._rm = np.array([p * self.STEP_RAD ** 2, 0.0])
        self._prior = (self._tt.copy(), self._rr.copy(), self._rm.copy(), self._mm.copy(),
                       self._mb.copy())
        self.scale_t, self.scale_r, self.drift = 1.0, 1.0, 0.0  # drift: rad per m

    def correct(self, wheel: Pose2D) -> Pose2D:
        """A wheel increment (previous robot frame) with the learned errors taken out."""
        if not self.enabled:
            return wheel
        theta = (wheel.theta * self.scale_r + self.drift * math.hypot(wheel.x, wheel.y)
                 if self.rotation else wheel.theta)
        if not self.mount:
            return Pose2D(wheel.x * self.scale_t, wheel.y * self.scale_t, theta)
        ex, ey = _lever(theta) @ self.mount_error
        return Pose2D(wheel.x * self.scale_t + ex, wheel.y * self.scale_t + ey, theta)

    def learn(self, measured: Pose2D, wheel: Pose2D, seen: tuple[float, float] = (1.0, 1.0),
              seen_xy: np.ndarray | None = None) -> None:
        """One matched increment and the raw wheel increment, both in the previous robot
        frame; ``seen``: how much of the match's translation along the wheel's and of its
        rotation the scan saw (0-1, :func:`scan_share`), its weight in the sums (a match
        along a featureless corridor is the odometry's own and teaches nothing of it);
        ``seen_xy``: the same for the translation in every direction (2×2,
        :func:`seen_matrix`), which the mount's error needs."""
        if not self.enabled:
            return
        keep = 1.0 - 1.0 / self.LEARN_SCANS
        tt0, rr0, rm0, _, _ = self._prior  # (forgetting the data, never the prior)
        d = math.hypot(wheel.x, wheel.y)
        w_t, w_r = seen
        lo, hi = self.SCALE_LIMIT
        if self.mount and seen_xy is not None:
            self._learn_with_mount(measured, wheel, seen_xy, keep)
        else:
            self._tt = tt0 + keep * (self._tt - tt0) + w_t * np.array(
                [measured.x * wheel.x + measured.y * wheel.y, d * d])
            self.scale_t = min(max(self._tt[0] / self._tt[1], lo), hi)
        if not self.rotation:  # (its sums are never read)
            return
        a = np.array([math.remainder(measured.theta, math.tau), d])
        self._rr = rr0 + keep * (self._rr - rr0) + w_r * np.outer(a, a)
        self._rm = rm0 + keep * (self._rm - rm0) + w_r * a * wheel.theta
        gain, offset = np.linalg.solve(self._rr, self._rm)  # wheel θ = gain·m_θ + offset·d
        limit = math.radians(self.DRIFT_LIMIT_DEG_PER_M)
        self.scale_r = min(max(1.0 / max(float(gain), 1e-9), lo), hi)
        self.drift = min(max(-float(offset) * self.scale_r, -limit), limit)

    def _learn_with_mount(self, measured: Pose2D, wheel: Pose2D, seen: np.ndarray,
                          keep: float) -> None:
        """The translation's scale and the laser mount's error together. A log that states
        its laser ``e`` off where it is makes every match see the robot turn about another
        point: the matched translation is the wheel's, scaled, plus (I − R(θ))·e (θ the
        matched turn; :func:`_lever`), so the turns tell ``e`` apart from the scale.
        Weighted least squares, each match by what its scan saw of the translation
        (``seen``, 2×2), ``e`` pulled toward 0 as much as PRIOR_STEPS turns of STEP_RAD."""
        _, _, _, mm0, mb0 = self._prior
        jac = np.column_stack(([wheel.x, wheel.y], _lever(measured.theta)))
        self._mm = mm0 + keep * (self._mm - mm0) + jac.T @ seen @ jac
        self._mb = mb0 + keep * (self._mb - mb0) + jac.T @ seen @ [measured.x, measured.y]
        scale, ex, ey = np.linalg.solve(self._mm, self._mb)
        lo, hi = self.SCALE_LIMIT
        self.scale_t = min(max(float(scale), lo), hi)
        reach = math.hypot(ex, ey)
        shrink = min(1.0, self.MOUNT_LIMIT_M / reach) if reach > 0 else 1.0
        self.mount_error = (float(ex) * shrink, float(ey) * shrink)


def _lever(theta: float) -> np.ndarray:
    """I − R(θ): how far a point ``e`` from the robot's centre is carried, in the previous
    robot frame, beyond the centre's own motion by a turn of θ (its lever)."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[1.0 - c, s], [-s, 1.0 - c]])


def seen_matrix(cov: np.ndarray, sigma_t: float) -> np.ndarray:
    """How much of a fused increment's translation (covariance ``cov``, previous robot frame)
    the scan determined in each direction, against the odometry's prior (standard deviation
    ``sigma_t``): I − Σ/σ², its eigenvalues kept within 0–1 (along the travel it is
    :func:`scan_share`'s first)."""
    values, vectors = np.linalg.eigh(cov[:2, :2] / max(sigma_t, 1e-9) ** 2)
    return (vectors * np.clip(1.0 - values, 0.0, 1.0)) @ vectors.T


def scan_share(cov: np.ndarray, wheel: Pose2D, sigma: tuple[float, float]) -> tuple[float,
                                                                                   float]:
    """How much of a fused increment (covariance ``cov``, previous robot frame) the scan
    determined, against the odometry's prior (standard deviations ``sigma``, translation
    and rotation): 1 − posterior variance / prior variance along the wheel's direction of
    travel, and in rotation (0 where the scan saw nothing that way, 1 where it saw all)."""
    d = math.hypot(wheel.x, wheel.y)
    u = np.array([wheel.x, wheel.y]) / d if d > 0 else np.array([1.0, 0.0])
    along = float(u @ cov[:2, :2] @ u)
    return (min(max(1.0 - along / max(sigma[0], 1e-9) ** 2, 0.0), 1.0),
            min(max(1.0 - float(cov[2, 2]) / max(sigma[1], 1e-9) ** 2, 0.0), 1.0))


class View(NamedTuple):
    """One scan of a submap: the laser's position and its end points in beam order (N×2),
    in the submap's frame."""

    origin: np.ndarray
    points: np.ndarray


def seen_cells(views: list[View], origin: np.ndarray, shape: tuple[int, int], res: float,
               reach_cells: int) -> np.ndarray:
    """1.0 on the cells of a grid (cell (0, 0) centred on ``origin``, side ``res``) that a
    view looked at: inside the fan from its laser through its end points, and within
    ``reach_cells`` of those cells (as far as a wall's likelihood spreads); else 0. A beam
    with no return is left out of the fan: what it passed through counts as unseen."""
    seen = np.zeros(shape)
    mark_seen(seen, views, origin, res, reach_cells)
    return seen


def mark_seen(seen: np.ndarray, views: list[View], origin: np.ndarray, res: float,
              reach_cells: int) -> None:
    """Sets the cells of ``seen`` (:func:`seen_cells`' grid) that ``views`` looked at to
    1, drawing and widening the fans over their own bounds alone."""
    from PIL import Image, ImageDraw
    from scipy.ndimage import maximum_filter

    fans = [(np.vstack([v.origin[None, :], v.points]) - origin) / res + 0.5
            for v in views if len(v.points) >= 2]  # (a cell's centre: the pixel's)
    if not fans:
        return
    every = np.vstack(fans)
    lo = np.floor(every.min(axis=0)).astype(int) - reach_cells - 1  # (x, y) pixels
    hi = np.ceil(every.max(axis=0)).astype(int) + reach_cells + 1
    image = Image.new("L", tuple(int(v) for v in hi - lo), 0)
    draw = ImageDraw.Draw(image)
    for fan in fans:
        draw.polygon([tuple(p) for p in (fan - lo).tolist()], fill=1, outline=1)
    box = maximum_filter(np.asarray(image, dtype=np.float64), size=2 * reach_cells + 1,
                         mode="constant")
    rows, cols = seen.shape
    r0, c0 = max(lo[1], 0), max(lo[0], 0)
    r1, c1 = min(hi[1], rows), min(hi[0], cols)
    if r0 < r1 and c0 < c1:
        window = seen[r0:r1, c0:c1]
        np.maximum(window, box[r0 - lo[1]:r1 - lo[1], c0 - lo[0]:c1 - lo[0]], out=window)


MIN_SEEN_SHARE = 0.5  # a pose's score is over at least this share of the points


def seen_share(share: np.ndarray) -> np.ndarray:
    """The share of a pose's points scored, where the field knows where its submap
    looked: those on cells it saw, never less than MIN_SEEN_SHARE (a pose that puts most
    points where the submap never looked scores as if they were misses)."""
    return np.maximum(share, MIN_SEEN_SHARE)


class Posterior(NamedTuple):
    """The search's best pose, the covariance (x, y, θ) of the posterior over the window
    around it, and the best pose's share of end points that landed on the submap's walls
    (its mean likelihood ratio against an outlier, 0–1)."""

    pose: Pose2D
    cov: np.ndarray
    score: float


@dataclass
class LogField:
    """Per cell, log p(end point here) − log(outlier share): 0 far from every wall (and
    off the table, as the kernel counts cells off the grid), largest on one. Cell (0, 0)
    is centred on ``origin``."""

    grid: np.ndarray
    origin: np.ndarray
    resolution: float
    peak: float  # the value on a wall: a score's 1
    seen: np.ndarray | None = None
    """Where the submap's scans looked (:func:`seen_cells`, the grid's shape), where the
    search scores only the end points landing there; None: every end point."""


def log_field(points: np.ndarray, cfg: CorrelativeConfig) -> LogField:
    """The lookup table of the submap ``points`` (N×2, its frame)."""
    return with_points(None, points, cfg)


def with_points(field: LogField | None, points: np.ndarray, cfg: CorrelativeConfig
                ) -> LogField:
    """``field`` (None: an empty one) with ``points`` (N×2, its frame) added: the same values
    as a table made of all the points at once, on a grid grown (with GROW_SLACK_M to spare
    on every side) where the points reach beyond it."""
    res, eps = cfg.resolution_m, cfg.outlier_share
    reach = reach_cells(cfg)
    margin = (reach + 1) * res
    lo, hi = points.min(axis=0) - margin, points.max(axis=0) + margin
    if field is None:
        grid, origin = _grid_over(lo, hi, res)
        field = LogField(grid, origin, res, -math.log(eps))
    else:
        top = field.origin + res * (np.array(field.grid.shape[::-1]) - 1)  # last cell's centre
        if np.any(lo < field.origin) or np.any(hi > top):
            grid, origin = _grid_over(np.minimum(lo, field.origin) - GROW_SLACK_M,
                                      np.maximum(hi, top) + GROW_SLACK_M, res)
            c, r = np.rint((field.origin - origin) / res).astype(int)  # the old table's place
            grid[r:r + field.grid.shape[0], c:c + field.grid.shape[1]] = field.grid
            field = LogField(grid, origin, res, field.peak)
    _loops.splat_gaussians(field.grid, np.ascontiguousarray(points, dtype=np.float64),
                           float(field.origin[0]), float(field.origin[1]), res,
                           cfg.field_sigma_m, reach, (1.0 - eps) / eps)
    return field


GROW_SLACK_M = 3.0


def reach_cells(cfg: CorrelativeConfig) -> int:
    """How many cells from a wall its likelihood reaches (4 ``field_sigma_m``)."""
    return max(1, math.ceil(4.0 * cfg.field_sigma_m / cfg.resolution_m))


def _grid_over(lo: np.ndarray, hi: np.ndarray, res: float) -> tuple[np.ndarray, np.ndarray]:
    """An empty grid covering ``lo``–``hi`` (x, y), its cell (0, 0) on a lattice of the
    frame; and that cell's centre."""
    origin = np.floor(lo / res) * res
    cols, rows = np.ceil((hi - origin) / res - 1e-9).astype(int) + 1
    return np.zeros((rows, cols)), origin


def sampled_walls(points: np.ndarray, spacing: float, max_gap: float = 2.0,
                  max_bend_deg: float = 10.0) -> np.ndarray:
    """A scan's end points (N×2, in beam order) and points every ``spacing`` metres on the
    walls between them: two neighbouring end points are joined where they are at most
    ``max_gap`` apart and the segment between them runs on within ``max_bend_deg`` of its
    neighbour before or after (a wall seen at a grazing angle, whose end points lie far
    apart; not the jump from an object's edge to the wall behind it). A table of the end
    points alone would score a wall as a string of beads, and a robot driving along it
    would match best standing still."""
    if len(points) < 3:
        return points
    d = np.diff(points, axis=0)
    length = np.hypot(d[:, 0], d[:, 1])
    heading = np.arctan2(d[:, 1], d[:, 0])
    bend = np.abs(np.remainder(np.diff(heading) + math.pi, math.tau) - math.pi)
    straight = bend <= math.radians(max_bend_deg)
    runs_on = np.zeros(len(d), bool)
    runs_on[:-1] |= straight
    runs_on[1:] |= straight
    joined = np.flatnonzero(runs_on & (length <= max_gap) & (length > spacing))
    if len(joined) == 0:
        return points
    counts = np.floor(length[joined] / spacing).astype(int)  # points inside each segment
    seg = np.repeat(joined, counts)
    frac = (np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts) + 1.0) / (
        np.repeat(counts, counts) + 1.0)
    return np.concatenate([points, points[seg] + frac[:, None] * d[seg]])


def angle_step(points: np.ndarray, resolution: float) -> float:
    """Rotation step (rad) that moves the scan's far points (95th percentile of range) by
    about one cell, between 0.1° and 1°."""
    if len(points) == 0:
        return math.radians(1.0)
    far = float(np.percentile(np.hypot(points[:, 0], points[:, 1]), 95))
    return min(max(resolution / max(far, 1e-9), math.radians(0.1)), math.radians(1.0))


def search(field: LogField, pts: np.ndarray, guess: Pose2D, prior_sigma: tuple[float, ...],
           cfg: CorrelativeConfig, min_score: float = 0.0, max_turn: float = math.inf
           ) -> Posterior:
    """The posterior of the pose of ``pts``' frame in the field's frame, over a window of
    ``cfg.window_sigmas`` prior standard deviations around ``guess`` (the odometry's pose,
    with ``prior_sigma`` = its x, y, θ standard deviations). Where the best pose lies on
    the window's edge (the odometry slipped or glitched), the window is searched again
    WIDEN times as wide in that direction (translation or rotation), up to the largest
    window (in rotation: and at most ``max_turn`` radians either way); and in both where
    it scores below ``min_score`` (nothing in the window explains the scan)."""
    sigma = tuple(max(float(s), 1e-9) for s in prior_sigma)
    widest_th = min(math.radians(cfg.max_window_deg), max_turn)
    half_m = min(max(cfg.window_sigmas * max(sigma[:2]), cfg.min_window_m), cfg.max_window_m)
    half_th = min(max(cfg.window_sigmas * sigma[2], math.radians(cfg.min_window_deg)),
                  widest_th)
    step = angle_step(pts, field.resolution)
    while True:
        post, edge_m, edge_th = _window_posterior(field, pts, guess, sigma, half_m, half_th,
                                                  step, cfg)
        lost = post.score < min_score
        edge_m, edge_th = edge_m or lost, edge_th or lost
        wider = (min(half_m * WIDEN, cfg.max_window_m) if edge_m else half_m,
                 min(half_th * WIDEN, widest_th) if edge_th else half_th)
        if wider == (half_m, half_th):
            return post
        half_m, half_th = wider


WIDEN = 3.0


def _window_posterior(field: LogField, pts: np.ndarray, guess: Pose2D,
                      sigma: tuple[float, ...], half_m: float, half_th: float, step: float,
                      cfg: CorrelativeConfig) -> tuple[Posterior, bool, bool]:
    """The posterior over one window (half widths ``half_m``, ``half_th``, rotation
    ``step``) and whether its best pose is on the window's edge in translation, and in
    rotation."""
    res = field.resolution
    sx, sy, sth = sigma
    n_xy = math.ceil(half_m / res)
    t = np.arange(-n_xy, n_xy + 1)
    n_th = math.ceil(half_th / step)
    dth = np.arange(-n_th, n_th + 1) * step
    pts = np.ascontiguousarray(pts, dtype=np.float64)
    scores = _loops.mean_scores(field.grid, float(field.origin[0]), float(field.origin[1]),
                                res, pts, guess.x, guess.y, guess.theta + dth, t, t,
                                cfg.bilinear)
    fit = scores  # (the share of all end points on walls: the score the search reports)
    if field.seen is not None:  # (the end points where the submap never looked: unscored)
        fit = scores / seen_share(_loops.mean_scores(
            field.seen, float(field.origin[0]), float(field.origin[1]), res, pts, guess.x,
            guess.y, guess.theta + dth, t, t, cfg.bilinear))
    dm = t * res
    log_post = cfg.effective_points * fit + odometry_log_prior(
        dm[None, None, :] / sx, dm[None, :, None] / sy, dth[:, None, None] / sth,
        cfg.odometry_glitch)
    a, r, c = np.unravel_index(int(np.argmax(log_post)), log_post.shape)
    w = np.exp(log_post - log_post[a, r, c])
    w /= w.sum()
    near = tuple(slice(max(i - PEAK_CELLS, 0), i + PEAK_CELLS + 1) for i in (a, r, c))
    near_w = w[near]
    best = np.array([(near_w.sum(axis=(0, 1)) * dm[near[2]]).sum(),
                     (near_w.sum(axis=(0, 2)) * dm[near[1]]).sum(),
                     (near_w.sum(axis=(1, 2)) * dth[near[0]]).sum()]) / near_w.sum()
    cov = _moments(w, (dth - best[2], dm - best[1], dm - best[0]))[::-1, ::-1]
    cov += np.diag([res * res, res * res, step * step]) / 12.0  # within a cell
    pose = Pose2D(guess.x + best[0], guess.y + best[1], guess.theta + best[2])
    return (Posterior(pose, cov, float(scores[a, r, c] / field.peak)),
            r in (0, 2 * n_xy) or c in (0, 2 * n_xy), a in (0, 2 * n_th))


def _moments(w: np.ndarray, offsets: tuple[np.ndarray, ...]) -> np.ndarray:
    """Second moments Σ w · dᵢ dⱼ of a 3-D weight array ``w`` about the offsets of its three
    axes (``offsets[i]`` along axis i), from its one- and two-axis marginals: the
    covariance of the posterior without an array of every cell's offsets."""
    m = np.empty((3, 3))
    for i in range(3):
        others = tuple(k for k in range(3) if k != i)
        m[i, i] = w.sum(axis=others) @ offsets[i] ** 2
        for j in range(i + 1, 3):
            pair = w.sum(axis=3 - i - j)  # axes i, j (in order)
            m[i, j] = m[j, i] = offsets[i] @ pair @ offsets[j]
    return m


def odometry_log_prior(zx: np.ndarray, zy: np.ndarray, zth: np.ndarray,
                       glitch: float) -> np.ndarray:
    """Log prior of an offset from the odometry's guess, given in its standard deviations
    (broadcast): a Gaussian, with a floor of ``glitch`` times its peak for the odometry's
    slips and glitches (a doubled turn), so that a scan that clearly says otherwise is
    believed."""
    return np.logaddexp(-0.5 * (zx ** 2 + zy ** 2 + zth ** 2), math.log(glitch))


CLIMB_STEPS = 30  # Newton's steps at most (3-5 from ICP's pose on a smooth surface)
CLIMB_CONVERGED = (1e-6, 1e-7)  # a step under this (|x| + |y| m, |θ| rad): at the top


def climbed(field: LogField, pts: np.ndarray, start: Pose2D, center: Pose2D,
            prior_sigma: tuple[float, ...], residual_sigma: float, cfg: CorrelativeConfig
            ) -> Pose2D:
    """The pose of ``pts``' frame (N×2) nearest ``start`` where the field's smooth surface
    (its cells as cubic B-spline coefficients: continuous to its second derivatives, so
    Newton's steps meet at one top whatever the start within its basin) summed over the
    end points is highest, less a Gaussian prior about ``center`` with ``prior_sigma``
    (x, y, θ). Each end point weighs as a pair of ICP's with ``residual_sigma`` (m): the
    table's curvature across a wall, (1 − outlier share) / σ², scaled to 1 / residual²."""
    kappa = cfg.field_sigma_m ** 2 / ((1.0 - cfg.outlier_share) * residual_sigma ** 2)
    wx, wy, wth = (1.0 / max(float(s), 1e-6) ** 2 for s in prior_sigma)
    x, y, th = _loops.spline_climb(
        field.grid, np.ascontiguousarray(pts, dtype=np.float64), start.x, start.y,
        start.theta, center.x, center.y, center.theta, float(field.origin[0]),
        float(field.origin[1]), field.resolution, kappa, wx, wy, wth, CLIMB_STEPS,
        *CLIMB_CONVERGED)
    return Pose2D(x, y, math.remainder(th, math.tau))


PEAK_CELLS = 2  # the pose is the posterior's mean over this many steps around its best
