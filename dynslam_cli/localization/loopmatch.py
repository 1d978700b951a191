"""The loop closures' matcher: where a submap of scans lies in another, found by a
correlative search over a window of translations and rotations on a likelihood field of
the other (a coarse pass on a max-pooled field bounds every fine cell below it, then the
best coarse cells are searched finely), with the spread of the poses that score almost as
well as its covariance (Olson 2009's way), so a match along a featureless corridor
constrains only the directions it can see.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dynslam_cli.localization import _loops
from dynslam_cli.localization._match import PointIndex
from dynslam_cli.localization.correlative import View, seen_cells, seen_share
from dynslam_cli.localization.globalsearch import gaussian
from dynslam_cli.types import Pose2D

FIELD_RES_M = 0.05
FIELD_REACH_CELLS = 7  # the field is 0 beyond 0.35 m (4.4 σ) of every point
COARSE_CELLS = 6  # the coarse pass steps this many fine cells (0.3 m)
TOP_COARSE = 6
ANGLE_STEP_DEG = 1.0
NORMAL_NEIGHBOURS = 6


def _field_kernels() -> tuple[np.ndarray, np.ndarray]:
    """The fine field around one occupied cell, exp(−d²/2σ²) out to FIELD_REACH_CELLS, and
    its max over the coarse pass's window (COARSE_CELLS + 1 cells square): the value at the
    window's cell nearest the centre, as the field falls with distance."""
    h, w = FIELD_REACH_CELLS, COARSE_CELLS // 2
    wide = np.arange(-h - w, h + w + 1)
    return (gaussian(np.arange(-h, h + 1) * FIELD_RES_M),
            gaussian(np.sign(wide) * np.maximum(np.abs(wide) - w, 0) * FIELD_RES_M))


FINE_KERNEL, COARSE_KERNEL = _field_kernels()
FIELD_MARGIN_M = (COARSE_KERNEL.shape[0] // 2 + 1) * FIELD_RES_M


@dataclass
class LikelihoodField:
    """exp(−d²/2σ²) of the distance d from each cell to the nearest occupied cell of the
    submap, on a fine grid, and its max-pooled copy for the coarse pass; the submap's points
    indexed, with their normals for ICP; and, where the submap's views are known, which
    cells its scans looked at (1, else 0) and its min-pooled copy for the coarse pass."""

    fine: np.ndarray
    coarse: np.ndarray
    origin: np.ndarray  # map coordinates of cell (0, 0)
    index: PointIndex
    seen: np.ndarray | None = None
    seen_coarse: np.ndarray | None = None


def likelihood_field(points: np.ndarray, views: list[View] | None = None
                     ) -> LikelihoodField:
    """The field of the submap ``points``; with ``views``, also where they looked
    (:func:`seen_cells`)."""
    lo = points.min(axis=0) - FIELD_MARGIN_M
    hi = points.max(axis=0) + FIELD_MARGIN_M
    shape = np.ceil((hi - lo) / FIELD_RES_M).astype(int) + 1
    cols, rows = np.floor((points - lo) / FIELD_RES_M + 0.5).astype(np.intp).T.copy()
    fine = np.zeros((shape[1], shape[0]))
    coarse = np.zeros((shape[1], shape[0]))
    _loops.splat_max(fine, rows, cols, FINE_KERNEL)
    _loops.splat_max(coarse, rows, cols, COARSE_KERNEL)
    index = PointIndex(points, neighbours=NORMAL_NEIGHBOURS)
    if views is None:
        return LikelihoodField(fine, coarse, lo, index)
    from scipy.ndimage import minimum_filter

    seen = seen_cells(views, lo, fine.shape, FIELD_RES_M, FIELD_REACH_CELLS)
    return LikelihoodField(fine, coarse, lo, index, seen,
                           minimum_filter(seen, size=COARSE_CELLS + 1, mode="constant"))


def _scores(grid: np.ndarray, origin: np.ndarray, pts: np.ndarray, thetas: np.ndarray,
            base: np.ndarray, tx: np.ndarray, ty: np.ndarray) -> np.ndarray:
    """Mean field value of ``pts`` rotated by each θ and moved to base + (tx, ty) cells, for
    every (θ, ty, tx): an array of shape (len(thetas), len(ty), len(tx))."""
    return _loops.mean_scores(grid, float(origin[0]), float(origin[1]), FIELD_RES_M, pts,
                               float(base[0]), float(base[1]), thetas,
                               tx.astype(np.intp), ty.astype(np.intp))


def constraint_ratio(points: np.ndarray) -> float:
    """How well a set of points pins down a position, weakest direction over strongest
    (eigenvalues of the sum of n nᵀ over the points' normals): about 0 for the two walls of a
    corridor, which say nothing about the position along it."""
    ev = np.linalg.eigvalsh(_normal_scatter(points))
    return float(ev[0] / max(ev[1], 1e-12))


def weakest_axis(points: np.ndarray) -> np.ndarray:
    """The direction (a unit 2-vector, the points' frame) the points pin down least, as
    :func:`constraint_ratio` weighs them: along a corridor's walls."""
    return np.linalg.eigh(_normal_scatter(points))[1][:, 0]


def _normal_scatter(points: np.ndarray) -> np.ndarray:
    """The sum of n nᵀ over the points' normals (2×2)."""
    n = PointIndex(points, neighbours=NORMAL_NEIGHBOURS).normals()
    return n.T @ n


@dataclass(frozen=True)
class Match:
    """A correlative match: the pose, its score (mean likelihood of the points, 0–1), the
    covariance of the poses that score almost as well (its ambiguity) and whether those
    poses reach the window's edge in translation (the ambiguity is then wider than the
    covariance says: a corridor longer than the window)."""

    pose: Pose2D
    score: float
    cov: np.ndarray
    censored: bool = False


def correlative_match(field: LikelihoodField, pts: np.ndarray, guess: Pose2D,
                      window_m: float, window_deg: float) -> Match:
    """Best pose of ``pts``' frame in the field's frame within the window around ``guess``.
    Where the field knows where its submap looked, a pose is scored on the points that
    land there (an end point where the old scans never looked is neither a hit nor a
    miss), so the search does not slide the scan to overlap the submap.

    Scores are weighed by a mild preference for the guess's position, so along a
    featureless corridor (where every offset scores the same) the estimate stays put
    instead of sliding."""
    half = math.ceil(window_m / (COARSE_CELLS * FIELD_RES_M))
    coarse_t = np.arange(-half, half + 1) * COARSE_CELLS
    n_ang = math.ceil(window_deg / ANGLE_STEP_DEG)
    dthetas = np.radians(np.arange(-n_ang, n_ang + 1) * ANGLE_STEP_DEG)
    base = np.array([guess.x, guess.y])
    t_m = coarse_t * FIELD_RES_M
    preference = _preference(t_m[None, :], t_m[:, None], window_m)
    blocks = None
    if field.seen_coarse is None and len(coarse_t) >= BLOCK_MIN_CELLS:
        blocks = _Blocks(field, pts, guess.theta + dthetas, base, coarse_t, preference)
        bounds = blocks.top(TOP_COARSE)
    else:
        bounds = _scores(field.coarse, field.origin, pts, guess.theta + dthetas, base,
                         coarse_t, coarse_t)
    if field.seen_coarse is not None:  # (the fewest seen below a coarse cell: a bound)
        bounds /= seen_share(_scores(field.seen_coarse, field.origin, pts,
                                      guess.theta + dthetas, base, coarse_t, coarse_t))
    ranked = bounds * preference[None]
    if blocks is None:
        order = best_first(ranked, TOP_COARSE)
    else:  # (the cells scored hold the best; equal values still in index order)
        cells = blocks.cells()
        order = cells[best_first(ranked.ravel()[cells], TOP_COARSE)]
    fine_t = np.arange(-(COARSE_CELLS // 2), COARSE_CELLS // 2 + 1)
    sub_angles = np.radians(np.array([-0.5, 0.0, 0.5]) * ANGLE_STEP_DEG)
    best = (-1.0, 0.0, guess)  # (weighed score, score, pose)
    for flat in order:
        a, r, c = np.unravel_index(int(flat), ranked.shape)
        if ranked[a, r, c] <= best[0]:
            break  # the coarse score bounds every fine score below it
        tx, ty = coarse_t[c] + fine_t, coarse_t[r] + fine_t
        ths = dthetas[a] + sub_angles
        fine = _scores(field.fine, field.origin, pts, guess.theta + ths, base, tx, ty)
        if field.seen is not None:
            fine /= seen_share(_scores(field.seen, field.origin, pts, guess.theta + ths,
                                        base, tx, ty))
        for th, sc in zip(ths, fine, strict=True):
            w = sc * _preference(tx[None, :] * FIELD_RES_M, ty[:, None] * FIELD_RES_M,
                                 window_m)
            i, j = np.unravel_index(int(np.argmax(w)), w.shape)
            if w[i, j] > best[0]:
                best = (float(w[i, j]), float(sc[i, j]), Pose2D(
                    guess.x + tx[j] * FIELD_RES_M, guess.y + ty[i] * FIELD_RES_M,
                    guess.theta + th))
    _, score, pose = best
    if blocks is not None:
        bounds = blocks.above(AMBIGUITY_SHARE * score)
    return Match(pose, score, *_ambiguity(bounds, t_m, dthetas, score))


BLOCK_CELLS = 4  # a wide window's first pass bounds 4 × 4 coarse cells of a heading at once
BLOCK_MIN_CELLS = 48  # ... where the window is this many coarse cells across (7 m) or more
BLOCK_REACH = (BLOCK_CELLS - 1) * COARSE_CELLS // 2  # a block's cells from its centre


class _Blocks:
    """A wide window's coarse bounds, found block by block where they matter (branch and
    bound, Hess et al. 2016, one level above the coarse pass): the coarse field max-pooled
    over a block's reach bounds the score of every coarse cell of the block at that heading,
    so a block whose bound is below the cells already found is never scored cell by cell.
    The cells scored are exactly the full pass's (the same sums), so the match is the
    same; the others read −1."""

    def __init__(self, field: LikelihoodField, pts: np.ndarray, thetas: np.ndarray,
                 base: np.ndarray, coarse_t: np.ndarray, preference: np.ndarray) -> None:
        n = len(coarse_t)
        nb = math.ceil(n / BLOCK_CELLS)
        starts = coarse_t[np.arange(nb) * BLOCK_CELLS]
        pooled, origin = _pooled_coarse(field)
        self.block_bounds = _scores(pooled, origin, pts, thetas, base,
                                    starts + BLOCK_REACH, starts + BLOCK_REACH)
        padded = np.zeros((nb * BLOCK_CELLS, nb * BLOCK_CELLS))
        padded[:n, :n] = preference
        best_preference = padded.reshape(nb, BLOCK_CELLS, nb, BLOCK_CELLS).max(axis=(1, 3))
        self._ranked = self.block_bounds * best_preference[None]
        self._order = best_first(self._ranked, self._ranked.size)
        self._next = 0  # blocks before this in _order are scored
        self.bounds = np.full((len(thetas), n, n), -1.0)  # (−1: not scored)
        self._field, self._pts, self._thetas, self._base = field, pts, thetas, base
        self._coarse_t, self._preference = coarse_t, preference

    def _cells(self, flat: int) -> tuple[int, slice, slice]:
        """Block ``flat``'s heading and its coarse cells' rows and columns."""
        a, br, bc = np.unravel_index(flat, self._ranked.shape)
        return (int(a), slice(br * BLOCK_CELLS, (br + 1) * BLOCK_CELLS),
                slice(bc * BLOCK_CELLS, (bc + 1) * BLOCK_CELLS))

    def _score(self, flat: int) -> tuple[int, slice, slice]:
        """Block ``flat``'s cells scored (once); its heading, rows and columns."""
        a, rows, cols = block = self._cells(flat)
        if self.bounds[a, rows, cols][0, 0] < 0:  # (a score is never below 0)
            t = self._coarse_t
            self.bounds[a, rows, cols] = _scores(self._field.coarse, self._field.origin,
                                                 self._pts, self._thetas[a:a + 1],
                                                 self._base, t[cols], t[rows])[0]
        return block

    def top(self, k: int) -> np.ndarray:
        """The bounds with at least every cell among the ``k`` best weighed by the
        preference scored: blocks best first, until a block's weighed bound is below the
        k-th best cell scored."""
        found: list[float] = []  # the weighed bounds of the cells scored, best k
        ranked = self._ranked.ravel()
        while self._next < len(self._order):
            flat = int(self._order[self._next])
            if len(found) >= k and ranked[flat] < found[k - 1]:
                break
            a, rows, cols = self._score(flat)
            self._next += 1
            weighed = self.bounds[a, rows, cols] * self._preference[rows, cols]
            found = sorted([*found, *weighed.ravel().tolist()], reverse=True)[:k]
        return self.bounds

    def cells(self) -> np.ndarray:
        """The flat indices of the cells scored, in order."""
        return np.flatnonzero(self.bounds.ravel() >= 0)

    def above(self, floor: float) -> np.ndarray:
        """The bounds with every cell whose bound reaches ``floor`` scored."""
        for flat in np.flatnonzero(self.block_bounds.ravel() >= floor):
            self._score(int(flat))
        return self.bounds


def _pooled_coarse(field: LikelihoodField) -> tuple[np.ndarray, np.ndarray]:
    """The coarse field's max over a block's reach (BLOCK_REACH cells each way), padded by
    that reach so that a block whose centre lies off the field still bounds its cells on
    it; and the padded grid's origin. Made for each wide search, not kept with the field:
    kept, it took freiburg-campus moderate from 270 to 325 MB at the same speed."""
    from scipy.ndimage import maximum_filter

    pooled = maximum_filter(np.pad(field.coarse, BLOCK_REACH), size=2 * BLOCK_REACH + 1,
                            mode="constant")
    return pooled, field.origin - BLOCK_REACH * FIELD_RES_M


def best_first(values: np.ndarray, k: int) -> np.ndarray:
    """The flat indices of the ``k`` largest of ``values``, largest first, equal values in
    index order: a partition and a sort of those alone (a sort of a wide window's every
    coarse pose took most of a long log's time)."""
    flat = values.ravel()
    if flat.size > k:
        top = np.flatnonzero(flat >= np.partition(flat, flat.size - k)[flat.size - k])
    else:
        top = np.arange(flat.size)
    return top[np.lexsort((top, -flat[top]))][:k]


DISTANCE_PREFERENCE = 0.5  # weight falls by a quarter from the guess to the window edge
AMBIGUITY_SHARE = 0.95  # poses whose coarse bound reaches this share of the best score


def _preference(dx_m: np.ndarray, dy_m: np.ndarray, window_m: float) -> np.ndarray:
    """Weight of an offset from the guess's position (broadcast over the arguments): 1 at
    the guess, falling to 1 − DISTANCE_PREFERENCE at the window's corner. Its heading gets
    none: walls pin a heading, and the heading is what a loop closure most often corrects
    (preferring the guess's, closures kept 2.5–8° of a wrong graph's heading on fhw)."""
    d2 = (dx_m ** 2 + dy_m ** 2) / max(window_m, 1e-9) ** 2
    return 1.0 - DISTANCE_PREFERENCE * 0.5 * d2


# Spread of one coarse cell (uniform over its width): the least uncertainty a match has.
CELL_COV = np.diag([COARSE_CELLS * FIELD_RES_M, COARSE_CELLS * FIELD_RES_M,
                    math.radians(ANGLE_STEP_DEG)]) ** 2 / 12.0


def _ambiguity(bounds: np.ndarray, t_m: np.ndarray, dthetas: np.ndarray,
               score: float) -> tuple[np.ndarray, bool]:
    """Covariance (x, y, θ) of the coarse cells that could hold a pose about as good as the
    best: wide along a corridor, small where the scene pins the match down; and whether
    any of them lies on the window's edge in translation."""
    a, r, c = np.nonzero(bounds >= AMBIGUITY_SHARE * score)
    edge = len(t_m) - 1
    censored = bool(np.any((r == 0) | (r == edge) | (c == 0) | (c == edge)))
    if len(a) < 2:
        return CELL_COV.copy(), censored
    return (np.cov(np.column_stack((t_m[c], t_m[r], dthetas[a])), rowvar=False) + CELL_COV,
            censored)
