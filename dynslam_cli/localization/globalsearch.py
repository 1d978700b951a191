"""Global localization: where in a whole map a scan was taken, from no guess at all.

The branch-and-bound correlative search of Hess et al., "Real-Time Loop Closure in 2D LIDAR
SLAM" (ICRA 2016, Sec. V): a pose's score is the mean value, at the scan's end points, of
a likelihood field of the map's Occupied cells (exp(−d²/2σ²), d the distance to the
nearest one). A pyramid of max-pooled copies of the field bounds the score of every pose
in a square of 2^k × 2^k cells from above by one lookup per end point, so whole squares of
the map whose bound is below a pose already found are never looked at finely. The answer is
the best pose over every cell and heading (exact on the lattice, not a guess that happened
to converge), with the best score of a pose elsewhere (``runner_up``) to say how unique
the place is: a symmetric room or a row of identical offices scores alike in two places.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np

from dynslam_cli.geometry import transform_points
from dynslam_cli.localization import _loops
from dynslam_cli.types import Pose2D

FIELD_SIGMA_M = 0.08  # the spread of an end point about the wall it hit
FIELD_REACH_SIGMAS = 4.0
TOP_CELLS = 16  # the coarsest level splits the map's longer side into about this many squares
GREEDY_STARTS = 8  # each level, this many best squares are followed down to a pose



@dataclass(frozen=True)
class Placement:
    """The best pose of the scan in the map, its score (mean field value at the end points,
    0–1) and the best score of any pose at least the exclusion away from it, that pose."""

    pose: Pose2D | None
    score: float
    runner_up: float
    rival: Pose2D | None = None


class MapField:
    """The likelihood field of a map's Occupied cells over the map's lattice (cell (0, 0)
    centred on ``origin``), padded on the low sides so that every square of the coarsest
    level that overlaps the map is bounded right, and its max-pooled pyramid:
    ``levels[k][r, c]`` is the largest field value of the cells r..r+2^k−1, c..c+2^k−1."""

    def __init__(self, occupied: np.ndarray, resolution: float, origin: tuple[float, float],
                 ) -> None:
        """``occupied``: boolean rows × cols (row 0 at the lowest y); ``origin``: the centre
        of cell (0, 0) in the map frame."""
        rows, cols = occupied.shape
        self.resolution = resolution
        self.size = (rows, cols)
        self.top = max(0, math.ceil(math.log2(max(rows, cols, 1) / TOP_CELLS)))
        kernel = gaussian_kernel(resolution)
        pad = (1 << self.top) + kernel.shape[0] // 2  # (a square's window reaches no tail)
        self.pad = pad
        self.origin = (origin[0] - pad * resolution, origin[1] - pad * resolution)
        tail = kernel.shape[0] // 2
        fine = np.zeros((rows + pad + tail, cols + pad + tail))
        r, c = np.nonzero(occupied)
        _loops.splat_max(fine, (r + pad).astype(np.intp), (c + pad).astype(np.intp),
                         kernel)
        self.levels = [fine.astype(np.float32)]  # (single precision: half the memory)
        for k in range(1, self.top + 1):
            self.levels.append(_pool(self.levels[-1], 1 << (k - 1)))
        self._log_levels: tuple[float, list[np.ndarray]] | None = None

    def log_levels(self, outlier: float) -> list[np.ndarray]:
        """The pyramid of an end point's log-likelihood, log((1 − outlier)·v + outlier) −
        log(outlier) of each value v: near a wall with the field's spread or, with
        probability ``outlier``, anywhere (0 off the walls). The log is increasing, so the
        max-pooled levels bound it as they bound the field (made once per share)."""
        if self._log_levels is None or self._log_levels[0] != outlier:
            self._log_levels = (outlier, [log_likelihood(level, outlier)
                                          for level in self.levels])
        return self._log_levels[1]

    def values(self, points: np.ndarray, pose: Pose2D) -> np.ndarray:
        """The field's value at each end point (N×2, robot frame) of a scan at ``pose``
        (the cell it falls in, as the search scores it; 0 off the map)."""
        x, y = transform_points(pose, points).T
        fine = self.levels[0]
        col = np.floor((x - self.origin[0]) / self.resolution + 0.5).astype(np.intp)
        row = np.floor((y - self.origin[1]) / self.resolution + 0.5).astype(np.intp)
        on = (row >= 0) & (row < fine.shape[0]) & (col >= 0) & (col < fine.shape[1])
        out = np.zeros(len(points))
        out[on] = fine[row[on], col[on]]
        return out


def log_likelihood(values: np.ndarray, outlier: float) -> np.ndarray:
    """An end point's log-likelihood where the field is ``values``: near a wall with the
    field's spread or, with probability ``outlier``, anywhere; less log(``outlier``), so 0
    far from every wall (in the values' precision)."""
    return np.log1p(values * values.dtype.type((1.0 - outlier) / outlier))


def gaussian(d: np.ndarray) -> np.ndarray:
    """exp(−(dx² + dy²)/2σ²) over the offsets d (m) in x and in y: the field around one
    Occupied cell (the loop closer's too)."""
    return np.exp(-0.5 * (d[:, None] ** 2 + d[None, :] ** 2) / FIELD_SIGMA_M ** 2)


def gaussian_kernel(resolution: float) -> np.ndarray:
    """The field around one Occupied cell on a lattice of ``resolution``, out to
    FIELD_REACH_SIGMAS σ."""
    reach = math.ceil(FIELD_REACH_SIGMAS * FIELD_SIGMA_M / resolution)
    return gaussian(np.arange(-reach, reach + 1) * resolution)


def _pool(grid: np.ndarray, h: int) -> np.ndarray:
    """max(grid[r, c], grid[r, c+h], grid[r+h, c], grid[r+h, c+h]), 0 beyond the grid: twice
    the window of the level below."""
    out = grid.copy()
    out[:, :-h] = np.maximum(out[:, :-h], grid[:, h:])
    rows = out.copy()
    out[:-h, :] = np.maximum(out[:-h, :], rows[h:, :])
    return out


# The heading step turns the farthest end point by this many cells (Hess et al. take 1): a
# pose half a step off the best heading moves it by a cell, within the field's spread (1.6
# cells), and the refinement finds the heading between steps. Placing MIT CSAIL's second
# half in its first: 4.5 s instead of 8.5 s, the same pose.
HEADING_CELLS = 2.0


def heading_step(points: np.ndarray, resolution: float) -> float:
    """The heading step (rad) that turns the farthest end point by HEADING_CELLS cells (Hess
    et al., Eq. 7)."""
    turn_m = resolution * HEADING_CELLS
    far = float(np.max(np.hypot(points[:, 0], points[:, 1]))) if len(points) else 1.0
    far = max(far, turn_m)
    return math.acos(max(-1.0, 1.0 - turn_m ** 2 / (2.0 * far ** 2)))


class Lattice:
    """The scan's end points turned by each heading, as cell offsets from a candidate
    pose's cell, and the scoring of candidates (heading index, column, row of the robot's
    cell in the padded field) at a level of the pyramid."""

    def __init__(self, field: MapField, points: np.ndarray) -> None:
        self.field = field
        self.levels = field.levels  # the pyramid scored
        step = heading_step(points, field.resolution)
        n = max(1, math.ceil(2.0 * math.pi / step))
        self.thetas = np.arange(n) * (2.0 * math.pi / n)
        c, s = np.cos(self.thetas)[:, None], np.sin(self.thetas)[:, None]
        res = field.resolution
        x = c * points[None, :, 0] - s * points[None, :, 1]
        y = s * points[None, :, 0] + c * points[None, :, 1]
        self.dc = np.ascontiguousarray(np.floor(x / res + 0.5), dtype=np.intp)
        self.dr = np.ascontiguousarray(np.floor(y / res + 0.5), dtype=np.intp)

    def scoring(self, levels: list[np.ndarray]) -> Lattice:
        """The same lattice scoring another pyramid of the field's shape (its turned end
        points are not made again)."""
        other = copy.copy(self)
        other.levels = levels
        return other

    def scores(self, level: int, th: np.ndarray, col: np.ndarray, row: np.ndarray
               ) -> np.ndarray:
        """Mean value at the end points of level ``level`` of the pyramid for each candidate
        (arrays of heading indices and robot cells): the score itself at level 0, a bound
        on every pose of the candidate's 2^level square above it."""
        return _loops.lattice_scores(self.levels[level], self.dr, self.dc,
                                     th.astype(np.intp), col.astype(np.intp),
                                     row.astype(np.intp))

    def pose(self, th: int, col: int, row: int) -> Pose2D:
        ox, oy = self.field.origin
        res = self.field.resolution
        return Pose2D(ox + col * res, oy + row * res,
                      float(math.remainder(self.thetas[th], math.tau)))


class Region:
    """Where the answer may lie: poses within ``distance_m`` and ``turn_deg`` of ``pose``
    (``inside``), or those not within both (``not inside``: a rival elsewhere)."""

    def __init__(self, lattice: Lattice, pose: Pose2D, distance_m: float, turn_deg: float,
                 inside: bool) -> None:
        self.lattice, self.pose, self.inside = lattice, pose, inside
        self.distance_m, self.turn = distance_m, math.radians(turn_deg)

    def may_hold(self, th: np.ndarray, col: np.ndarray, row: np.ndarray, span: int
                 ) -> np.ndarray:
        """Whether the square of ``span`` cells from each candidate's cell, at its heading,
        may hold a pose of the region (exact for span 1)."""
        field = self.lattice.field
        res = field.resolution
        x0 = field.origin[0] + col * res - self.pose.x  # the square, relative to the pose
        y0 = field.origin[1] + row * res - self.pose.y
        x1, y1 = x0 + (span - 1) * res, y0 + (span - 1) * res
        turn = np.abs(np.remainder(self.lattice.thetas[th] - self.pose.theta + math.pi,
                                   math.tau) - math.pi)
        if self.inside:  # the square's nearest point is near enough
            near = np.hypot(np.clip(0.0, x0, x1), np.clip(0.0, y0, y1))
            return (near <= self.distance_m) & (turn <= self.turn)
        far = np.hypot(np.maximum(np.abs(x0), np.abs(x1)), np.maximum(np.abs(y0), np.abs(y1)))
        return (far >= self.distance_m) | (turn >= self.turn)


def place(field: MapField, points: np.ndarray, min_score: float = 0.0,
          rival_m: float = 1.0, rival_deg: float = 30.0, rival_share: float = 0.75,
          near: tuple[Pose2D, float, float] | None = None,
          likelier: tuple[float, float] | None = None) -> Placement:
    """The best pose (map frame) of a scan whose end points are ``points`` (N×2, robot
    frame), over every cell of the map and every heading (or, with ``near`` = (pose,
    metres, degrees), within that of the pose), and the best score of a pose at least
    ``rival_m`` away or turned at least ``rival_deg`` from it (its rival, searched over the
    same region). Poses scoring below ``min_score`` are not looked for (the score 0 and no
    pose if none reaches it), nor rivals below ``rival_share`` of the best (runner_up 0):
    the lower the floors, the more of the map must be searched finely.

    ``likelier`` = (outlier share, margin): the rival is instead the likeliest pose
    elsewhere (:meth:`MapField.log_levels`), looked for only among those whose mean
    log-likelihood comes within ``margin`` of the best's (rival_share unused); its score is
    still the field's mean."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    lattice = Lattice(field, points)
    regions = [] if near is None else [Region(lattice, *near, inside=True)]
    best = _branch_and_bound(lattice, regions, min_score)
    if best is None:
        return Placement(None, 0.0, 0.0)
    score, pose = best
    if likelier is not None:
        outlier, margin = likelier
        lattice = lattice.scoring(field.log_levels(outlier))
        floor = float(np.mean(log_likelihood(field.values(points, pose), outlier))) - margin
    else:
        floor = rival_share * score
    rival = Region(lattice, pose, rival_m, rival_deg, inside=False)
    second = _branch_and_bound(lattice, [*regions, rival], floor)
    if second is None:
        return Placement(pose, score, 0.0)
    if likelier is not None:
        return Placement(pose, score, float(np.mean(field.values(points, second[1]))),
                         second[1])
    return Placement(pose, score, *second)


def _branch_and_bound(lattice: Lattice, regions: list[Region], floor: float
                      ) -> tuple[float, Pose2D] | None:
    """The best pose of all the regions scoring above ``floor``, and its score: every
    candidate of the coarsest level is scored by its bound; level by level down, the
    squares whose bound does not exceed the floor or the best pose found so far are
    dropped and the rest split in four."""
    field = lattice.field
    rows, cols = field.size
    pad, top = field.pad, field.top
    th, row, col = np.meshgrid(np.arange(len(lattice.thetas)),
                               np.arange(pad, pad + rows, 1 << top),
                               np.arange(pad, pad + cols, 1 << top), indexing="ij")
    th, col, row = _within(regions, th.ravel(), col.ravel(), row.ravel(), 1 << top)
    bounds = lattice.scores(top, th, col, row)
    best: tuple[float, tuple[int, int, int]] | None = None
    for level in range(top, -1, -1):
        for i in np.argsort(bounds)[::-1][:GREEDY_STARTS]:
            found = _descend(lattice, regions, level, int(th[i]), int(col[i]), int(row[i]))
            if found is not None and (best is None or found[0] > best[0]):
                best = found
        keep = bounds > max(floor, best[0] if best is not None else floor)
        th, col, row, bounds = th[keep], col[keep], row[keep], bounds[keep]
        if level == 0 or not len(th):
            break
        th, col, row = _split(lattice, regions, level, th, col, row)
        bounds = lattice.scores(level - 1, th, col, row)
    if len(th):  # the level-0 survivors: poses themselves, scored exactly
        i = int(np.argmax(bounds))
        if best is None or bounds[i] > best[0]:
            best = (float(bounds[i]), (int(th[i]), int(col[i]), int(row[i])))
    if best is None or best[0] <= floor:
        return None
    score, (t, c, r) = best
    return score, lattice.pose(t, c, r)


def _within(regions: list[Region], th: np.ndarray, col: np.ndarray, row: np.ndarray,
            span: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The candidates whose squares may hold a pose of every region."""
    keep = np.ones(len(th), bool)
    for region in regions:
        keep &= region.may_hold(th, col, row, span)
    return th[keep], col[keep], row[keep]


def _split(lattice: Lattice, regions: list[Region], level: int, th: np.ndarray,
           col: np.ndarray, row: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The four squares of the level below each square (those on the map and the
    regions)."""
    rows, cols = lattice.field.size
    pad = lattice.field.pad
    h = 1 << (level - 1)
    th = np.repeat(th, 4)
    col = np.repeat(col, 4) + np.tile([0, h, 0, h], len(col))
    row = np.repeat(row, 4) + np.tile([0, 0, h, h], len(row))
    inside = (col < pad + cols) & (row < pad + rows)
    return _within(regions, th[inside], col[inside], row[inside], h)


def _descend(lattice: Lattice, regions: list[Region], level: int, th: int, col: int,
             row: int) -> tuple[float, tuple[int, int, int]] | None:
    """Follow the best child of a square down to a pose: a pose found cheaply, whose score
    is a floor under which nothing needs looking at (None if the square holds none of the
    regions)."""
    if level == 0:
        return float(lattice.scores(0, np.array([th]), np.array([col]), np.array([row]))[0]), (
            th, col, row)
    while level > 0:
        t, c, r = _split(lattice, regions, level, np.array([th]), np.array([col]),
                         np.array([row]))
        if not len(t):
            return None
        s = lattice.scores(level - 1, t, c, r)
        k = int(np.argmax(s))
        col, row, level = int(c[k]), int(r[k]), level - 1
    return float(s[k]), (th, col, row)  # (its level-0 score: the pose's own)


class BlurredMap:
    """A map's Occupied cells blurred by the end points' spread, as cubic-spline
    coefficients (made once), on which a pose is made finer than a cell: a wall drawn two
    cells thick peaks between them, where the likelihood field's max over cells (and ICP
    on the cells' centres) puts poses on a cell's centre line. ``occupied`` and ``origin``
    as for :class:`MapField`."""

    def __init__(self, occupied: np.ndarray, resolution: float,
                 origin: tuple[float, float]) -> None:
        from scipy.ndimage import gaussian_filter, spline_filter

        self.resolution, self.origin = resolution, origin
        self._spline = spline_filter(gaussian_filter(occupied.astype(float),
                                                     FIELD_SIGMA_M / resolution,
                                                     mode="constant"))

    def refine(self, points: np.ndarray, pose: Pose2D, shift_m: float, turn: float) -> Pose2D:
        """The pose within ``shift_m`` and ``turn`` (radians) of ``pose`` at which the end
        points (N×2, robot frame) lie best on the blurred map: the mean of its cubic-spline
        interpolation at them, maximized by L-BFGS-B on its exact gradient; ``pose`` where
        none does better."""
        from scipy.optimize import minimize

        pts = np.ascontiguousarray(points, dtype=float).reshape(-1, 2)
        res, (ox, oy) = self.resolution, self.origin

        def cost(v: np.ndarray) -> tuple[float, np.ndarray]:
            mean, *grad = _loops.spline_mean(self._spline, pts, pose.x + v[0], pose.y + v[1],
                                             pose.theta + v[2], ox, oy, res)
            return -mean, -np.array(grad)

        bounds = [(-shift_m, shift_m), (-shift_m, shift_m), (-turn, turn)]
        best = minimize(cost, np.zeros(3), jac=True, method="L-BFGS-B", bounds=bounds,
                        options={"ftol": 1e-12, "gtol": 1e-9})
        v = best.x if best.fun <= cost(np.zeros(3))[0] else np.zeros(3)
        return Pose2D(float(pose.x + v[0]), float(pose.y + v[1]),
                      float(math.remainder(pose.theta + v[2], math.tau)))
