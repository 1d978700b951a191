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

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from dynslam_cli.localization import _loops
from dynslam_cli.types import Pose2D

FIELD_SIGMA_M = 0.08  # the spread of an end point about the wall it hit
FIELD_REACH_SIGMAS = 4.0
TOP_CELLS = 16  # the coarsest level splits the map's longer side into about this many squares
GREEDY_STARTS = 8  # each level, this many best squares are followed down to a pose
CHUNK = 1 << 22  # end-point lookups scored at a time (memory: 8 bytes each)

Allowed = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Placement:
    """The best pose of the scan in the map, its score (mean field value at the end points,
    0–1) and the best score of any pose at least the exclusion away from it."""

    pose: Pose2D | None
    score: float
    runner_up: float


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
        self.levels = [fine]
        for k in range(1, self.top + 1):
            self.levels.append(_pool(self.levels[-1], 1 << (k - 1)))


def gaussian_kernel(resolution: float) -> np.ndarray:
    """exp(−d²/2σ²) around one Occupied cell, out to FIELD_REACH_SIGMAS σ."""
    reach = math.ceil(FIELD_REACH_SIGMAS * FIELD_SIGMA_M / resolution)
    d = np.arange(-reach, reach + 1) * resolution
    return np.exp(-0.5 * (d[:, None] ** 2 + d[None, :] ** 2) / FIELD_SIGMA_M ** 2)


def _pool(grid: np.ndarray, h: int) -> np.ndarray:
    """max(grid[r, c], grid[r, c+h], grid[r+h, c], grid[r+h, c+h]), 0 beyond the grid: twice
    the window of the level below."""
    out = grid.copy()
    out[:, :-h] = np.maximum(out[:, :-h], grid[:, h:])
    rows = out.copy()
    out[:-h, :] = np.maximum(out[:-h, :], rows[h:, :])
    return out


def heading_step(points: np.ndarray, resolution: float) -> float:
    """The heading step (rad) that moves the farthest end point by about one cell (Hess et
    al., Eq. 7)."""
    far = float(np.max(np.hypot(points[:, 0], points[:, 1]))) if len(points) else 1.0
    far = max(far, resolution)
    return math.acos(max(-1.0, 1.0 - resolution ** 2 / (2.0 * far ** 2)))


class Lattice:
    """The scan's end points turned by each heading, as cell offsets from a candidate
    pose's cell, and the scoring of candidates (heading index, column, row of the robot's
    cell in the padded field) at a level of the pyramid."""

    def __init__(self, field: MapField, points: np.ndarray) -> None:
        self.field = field
        step = heading_step(points, field.resolution)
        n = max(1, math.ceil(2.0 * math.pi / step))
        self.thetas = np.arange(n) * (2.0 * math.pi / n)
        c, s = np.cos(self.thetas)[:, None], np.sin(self.thetas)[:, None]
        res = field.resolution
        x = c * points[None, :, 0] - s * points[None, :, 1]
        y = s * points[None, :, 0] + c * points[None, :, 1]
        self.dc = np.floor(x / res + 0.5).astype(np.intp)
        self.dr = np.floor(y / res + 0.5).astype(np.intp)

    def scores(self, level: int, th: np.ndarray, col: np.ndarray, row: np.ndarray
               ) -> np.ndarray:
        """Mean value at the end points of level ``level`` of the pyramid for each candidate
        (arrays of heading indices and robot cells): the score itself at level 0, a bound
        on every pose of the candidate's 2^level square above it."""
        grid = self.field.levels[level]
        rows, cols = grid.shape
        out = np.empty(len(th))
        n = self.dc.shape[1]
        per = max(1, CHUNK // max(n, 1))
        for a in range(0, len(th), per):
            b = min(a + per, len(th))
            r = self.dr[th[a:b]] + row[a:b, None]
            c = self.dc[th[a:b]] + col[a:b, None]
            ok = (r >= 0) & (r < rows) & (c >= 0) & (c < cols)
            v = np.where(ok, grid[np.clip(r, 0, rows - 1), np.clip(c, 0, cols - 1)], 0.0)
            out[a:b] = v.mean(axis=1) if n else 0.0
        return out

    def pose(self, th: int, col: int, row: int) -> Pose2D:
        ox, oy = self.field.origin
        res = self.field.resolution
        return Pose2D(ox + col * res, oy + row * res,
                      float(math.remainder(self.thetas[th], math.tau)))


def place(field: MapField, points: np.ndarray, min_score: float = 0.0,
          exclusion_m: float = 1.0, exclusion_deg: float = 30.0, rival_share: float = 0.75
          ) -> Placement:
    """The best pose (map frame) of a scan whose end points are ``points`` (N×2, robot
    frame), over every cell of the map and every heading, and the best score of a pose at
    least ``exclusion_m`` away or turned at least ``exclusion_deg`` from it (its rival).
    Poses scoring below ``min_score`` are not looked for (the score 0 and no pose if none
    reaches it), nor rivals below ``rival_share`` of the best (runner_up 0): the lower the
    floors, the more of the map must be searched finely."""
    lattice = Lattice(field, np.asarray(points, dtype=float).reshape(-1, 2))
    best = _branch_and_bound(lattice, None, min_score)
    if best is None:
        return Placement(None, 0.0, 0.0)
    score, pose = best

    def far(th: np.ndarray, col: np.ndarray, row: np.ndarray) -> np.ndarray:
        res = field.resolution
        dx = field.origin[0] + col * res - pose.x
        dy = field.origin[1] + row * res - pose.y
        turn = np.abs(np.remainder(lattice.thetas[th] - pose.theta + math.pi, math.tau)
                      - math.pi)
        return (np.hypot(dx, dy) >= exclusion_m) | (turn >= math.radians(exclusion_deg))

    second = _branch_and_bound(lattice, far, rival_share * score)
    return Placement(pose, score, second[0] if second is not None else 0.0)


def _branch_and_bound(lattice: Lattice, allowed: Allowed | None, floor: float
                      ) -> tuple[float, Pose2D] | None:
    """The best allowed pose scoring above ``floor``, and its score: every candidate of the
    coarsest level is scored by its bound; level by level down, the squares whose bound
    does not exceed the floor or the best pose found so far are dropped and the rest split
    in four. ``allowed(th, col, row)`` (None: all) says which poses may be the answer."""
    field = lattice.field
    rows, cols = field.size
    pad, top = field.pad, field.top
    span = 1 << top
    th, row, col = np.meshgrid(np.arange(len(lattice.thetas)), np.arange(pad, pad + rows, span),
                               np.arange(pad, pad + cols, span), indexing="ij")
    th, col, row = th.ravel(), col.ravel(), row.ravel()
    bounds = lattice.scores(top, th, col, row)
    best: tuple[float, tuple[int, int, int]] | None = None
    for level in range(top, -1, -1):
        for i in np.argsort(bounds)[::-1][:GREEDY_STARTS]:
            found = _descend(lattice, level, int(th[i]), int(col[i]), int(row[i]), allowed)
            if found is not None and (best is None or found[0] > best[0]):
                best = found
        keep = bounds > max(floor, best[0] if best is not None else floor)
        th, col, row, bounds = th[keep], col[keep], row[keep], bounds[keep]
        if level == 0 or not len(th):
            break
        h = 1 << (level - 1)
        th = np.repeat(th, 4)
        col = np.repeat(col, 4) + np.tile([0, h, 0, h], len(col))
        row = np.repeat(row, 4) + np.tile([0, 0, h, h], len(row))
        inside = (col < pad + cols) & (row < pad + rows)
        th, col, row = th[inside], col[inside], row[inside]
        bounds = lattice.scores(level - 1, th, col, row)
    if len(th):  # the level-0 survivors: poses themselves, scored exactly
        ok = np.ones(len(th), bool) if allowed is None else allowed(th, col, row)
        if ok.any():
            i = int(np.flatnonzero(ok)[np.argmax(bounds[ok])])
            if best is None or bounds[i] > best[0]:
                best = (float(bounds[i]), (int(th[i]), int(col[i]), int(row[i])))
    if best is None or best[0] <= floor:
        return None
    score, (t, c, r) = best
    return score, lattice.pose(t, c, r)


def _descend(lattice: Lattice, level: int, th: int, col: int, row: int,
             allowed: Allowed | None) -> tuple[float, tuple[int, int, int]] | None:
    """Follow the best child of a square down to a pose: a pose found cheaply, whose score
    is a floor under which nothing needs looking at."""
    field = lattice.field
    rows, cols = field.size
    pad = field.pad
    while level > 0:
        h = 1 << (level - 1)
        c = np.array([col, col + h, col, col + h])
        r = np.array([row, row, row + h, row + h])
        ok = (c < pad + cols) & (r < pad + rows)
        c, r = c[ok], r[ok]
        s = lattice.scores(level - 1, np.full(len(c), th), c, r)
        k = int(np.argmax(s))
        col, row, level = int(c[k]), int(r[k]), level - 1
    if allowed is not None and not allowed(np.array([th]), np.array([col]), np.array([row]))[0]:
        return None
    score = float(lattice.scores(0, np.array([th]), np.array([col]), np.array([row]))[0])
    return score, (th, col, row)
