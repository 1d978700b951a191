"""Where in its cell S's surface lies: the neighbourhood rule at sub-cell precision.

The neighbourhood rule (paper Sec. 5) compares an end point with S^{t-1} over a window of
``neighbourhood_m``: Occupied if any cell there is. So a wall's end point that falls a cell
off the wall (range noise, rounding, pose error) stays the wall's; and so does whatever
stands closer to a wall than that: the paper's own failure case, a box moved next to a
wall, goes into S.

With ``[dynamic] surface_m`` above 0, each cell also keeps the spread of the end points S
took as static there (their count, sums and second moments: a short segment where a wall
runs through the cell). A hit in a cell S holds firmly Free, which the window would hand
to an Occupied neighbour, stays the window's only where most of the cell's end points lie
on a surface drawn in the window's cells that S does not hold Free: across it within a
tolerance, and along it within a cell of its ends (an object in line with a surface does
not grow it cell by cell: most of a cell's points lie farther). Elsewhere it is Free:
something stands where the robot saw nothing (Table 2: into D). The tolerance is as tight
as the scan sits on S: ``surface_m``, or FIT_SPREADS times the median distance from their
surfaces of the scan's end points near S's walls, or of the FIT_BEAMS beams on either side
that fell on S's walls (a wall drawn a few centimetres apart on another pass), whichever
is widest.
"""

from __future__ import annotations

import warnings

import numpy as np

from dynslam_cli.mapping.grid import GridStack, Observation
from dynslam_cli.types import Pose2D, Scan

MOMENTS = ("surface_n", "surface_x", "surface_y", "surface_xx", "surface_xy", "surface_yy")
"""Per cell: how many end points, their sums (x, y relative to the cell's centre, metres)
and their sums of products."""
MIN_POINTS = 3  # end points that draw a cell's surface; with fewer, a point is on it
FIT_SPREADS = 3.0
FIT_BEAMS = 10  # a point's neighbours on each side whose fit to S's walls sets its tolerance


class Surfaces:
    """The surface of S within each cell, kept on the grid stack as float32 layers."""

    def __init__(self, grids: GridStack, surface_m: float, radius: int,
                 min_range_m: float, min_beams: int = 1) -> None:
        """``min_beams``: consecutive beams whose end points must lie where S was seen free
        (off the surfaces, or where the window already says Free) for a hit off the
        surfaces to count."""
        self.grids = grids
        self.surface_m = surface_m
        self.min_beams = min_beams
        self.radius = radius
        self.min_range_m = min_range_m
        # the last scan's end points: where, which hit cell holds each, and its beam
        self._last = (np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0, np.int64))
        for name in MOMENTS:
            grids.add_layer(name, np.float32)

    def end_points(self, laser: Pose2D, scan: Scan, obs: Observation
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The scan's end points that hit something (N × 2, map frame) seen from the laser's
        pose, where each one's cell is in ``obs.hit``, and each one's beam (its index in the
        scan)."""
        r = scan.ranges
        with np.errstate(invalid="ignore"):
            hit = (r > self.min_range_m) & (r < scan.max_range)
        a = laser.theta + scan.angles[hit]
        points = np.column_stack((laser.x + r[hit] * np.cos(a), laser.y + r[hit] * np.sin(a)))
        beams = np.flatnonzero(hit)
        if not len(obs.hit):
            return points[:0], np.zeros(0, np.int64), beams[:0]
        cells = self.grids.flat_cells(*self.grids.world_cells_of(points[:, 0], points[:, 1]))
        order = np.argsort(obs.hit, kind="stable")
        where = order[np.minimum(np.searchsorted(obs.hit, cells, sorter=order), len(order) - 1)]
        listed = (cells >= 0) & (obs.hit[where] == cells)
        return points[listed], where[listed], beams[listed]

    def off_surfaces(self, laser: Pose2D, scan: Scan, obs: Observation, doubt: np.ndarray,
                     walls: np.ndarray, free: float) -> np.ndarray:
        """Which hit cells (of ``obs.hit``) in ``doubt`` have most of their end points off
        every surface drawn in the window around them in cells S does not hold Free (stored
        log-odds above ``free``, in steps); ``walls``: the hit cells S holds Occupied, whose
        end points tell how well the scan fits S."""
        points, where, _ = self._last = self.end_points(laser, scan, obs)
        asked = doubt[where]
        if not asked.any():
            return np.zeros(len(obs.hit), bool)
        on_wall = walls[where]
        on_walls, _ = self.offsets(points[on_wall], obs.hit[where[on_wall]])
        rows, cols = self.grids.world_cells_of(points[asked, 0], points[asked, 1])
        off = self.nearest(points[asked], rows, cols, free)
        fit = np.full(len(points), np.nan)
        fit[on_wall] = on_walls
        near = np.lib.stride_tricks.sliding_window_view(
            np.pad(fit, FIT_BEAMS, constant_values=np.nan), 2 * FIT_BEAMS + 1)[asked]
        with warnings.catch_warnings():  # (a point with no wall beside it: NaN, all-NaN)
            warnings.simplefilter("ignore", RuntimeWarning)
            local = FIT_SPREADS * np.nanmedian(near, axis=1)
        tolerance = np.fmax(local, self.tolerance(np.concatenate((on_walls, off))))
        on = off <= tolerance
        cells = where[asked]
        kept = (2 * np.bincount(cells[on], minlength=len(obs.hit))
                >= np.bincount(cells, minlength=len(obs.hit)))
        return doubt & ~kept

    def lone(self, off: np.ndarray) -> np.ndarray:
        """Which of the hit cells ``off`` S (of the last scan's ``obs.hit``: off the
        surfaces, or where the window says Free) hold no end point among ``min_beams``
        consecutive beams whose end points are all off S."""
        _, where, beams = self._last
        if self.min_beams <= 1 or not off.any():
            return np.zeros(len(off), bool)
        # a run of off end points breaks where one is not off or a beam is skipped
        apart = off[where]
        run = np.cumsum(np.r_[True, (np.diff(beams) != 1) | ~apart[:-1]])
        long = apart & (np.bincount(run, weights=apart)[run] >= self.min_beams)
        return off & (np.bincount(where[long], minlength=len(off)) == 0)

    def learn(self, obs: Observation, static: np.ndarray) -> None:
        """Draw the last scan's end points into the surfaces of the hit cells (of
        ``obs.hit``) that S took as ``static``."""
        points, where, _ = self._last
        keep = static[where]
        cells, points = obs.hit[where[keep]], points[keep]
        if not len(cells):
            return
        offset = points - self.grids.cell_centres(cells)
        x, y = offset[:, 0], offset[:, 1]
        layers = self.grids.layers
        for name, value in zip(MOMENTS, (np.ones_like(x), x, y, x * x, x * y, y * y),
                               strict=True):
            np.add.at(layers[name], cells, value.astype(np.float32))

    def offsets(self, points: np.ndarray, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """How far each end point lies from the surface of the cell (flat index) across it,
        and along it beyond the surface's ends (its points' mean ± √3 times their spread
        along it: a segment's half length), in metres; 0 where the cell has fewer than
        MIN_POINTS (too few to tell where its surface runs); NaN where it has none. Beyond
        the ends is where an object standing in line with a surface would grow it cell by
        cell."""
        layers = self.grids.layers
        n = layers["surface_n"][cells].astype(np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            mx, my = layers["surface_x"][cells] / n, layers["surface_y"][cells] / n
            sxx = layers["surface_xx"][cells] / n - mx ** 2
            sxy = layers["surface_xy"][cells] / n - mx * my
            syy = layers["surface_yy"][cells] / n - my ** 2
        angle = 0.5 * np.arctan2(2 * sxy, sxx - syy)  # the surface's direction
        length = np.sqrt(np.maximum(3 * ((sxx + syy) / 2 + np.hypot((sxx - syy) / 2, sxy)), 0))
        d = points - self.grids.cell_centres(cells) - np.column_stack((mx, my))
        c, s = np.cos(angle), np.sin(angle)
        across = np.abs(d[:, 1] * c - d[:, 0] * s)
        beyond = np.maximum(np.abs(d[:, 0] * c + d[:, 1] * s) - length, 0.0)
        unsure = n < MIN_POINTS  # too few points to tell where the surface runs: on it
        across[unsure] = beyond[unsure] = 0.0
        return across, beyond

    def nearest(self, points: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                free: float) -> np.ndarray:
        """How far each end point (N × 2, in world cell rows, cols) lies across the nearest
        surface drawn in a cell of the window that S does not hold Free (stored log-odds
        above ``free``, in steps) and that reaches it along (the point at most a cell beyond
        the surface's ends); inf where none does."""
        grids = self.grids
        out = np.full(len(points), np.inf)
        span = np.arange(-self.radius, self.radius + 1)
        static, count = grids.layers["static"], grids.layers["surface_n"]
        reach = grids.resolution
        for dr in span:
            for dc in span:
                flat = grids.flat_cells(rows + dr, cols + dc)
                ok = flat >= 0
                ok[ok] = (static[flat[ok]] > free) & (count[flat[ok]] > 0)
                if not ok.any():
                    continue
                across, beyond = self.offsets(points[ok], flat[ok])
                i = np.flatnonzero(ok)
                out[i] = np.minimum(out[i], np.where(beyond <= reach, across, np.inf))
        return out

    def tolerance(self, across: np.ndarray) -> float:
        """How far off a surface an end point of this scan may lie and be on it, from how
        far its end points near S's walls lie off them (``across``): ``surface_m``, or
        FIT_SPREADS times their median where the scan fits S worse (its pose erred)."""
        across = across[np.isfinite(across)]
        if not len(across):
            return self.surface_m
        return max(self.surface_m, FIT_SPREADS * float(np.median(across)))
