"""Growable occupancy grids in log-odds and vectorized beam tracing.

Cell (row, col) covers x in [origin_x + col·res, origin_x + (col+1)·res) and likewise y with
row, so row 0 is the *lowest* y (writers flip it for images, whose first row is the top).
All layers of a :class:`GridStack` share one geometry and grow together, so the static and
dynamic maps always have the same size and origin.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dynslam_cli.errors import DynslamError
from dynslam_cli.mapping import _grid
from dynslam_cli.types import Pose2D


class MapExtentError(DynslamError):
    """The map would grow beyond its configured bound."""


def logit(p: float) -> float:
    """Log-odds of probability p."""
    return math.log(p / (1.0 - p))


def probability(logodds: np.ndarray) -> np.ndarray:
    """Probability from log-odds (elementwise)."""
    p = np.exp(-logodds.astype(np.float64))  # 1 / (1 + e^-l), in one buffer
    p += 1.0
    return np.reciprocal(p, out=p)


@dataclass(frozen=True, slots=True)
class Observation:
    """What one scan says about the grid: flat indices of cells seen free and cells hit,
    each listed once. A cell hit by one beam and passed through by another is only in
    ``hit``."""

    free: np.ndarray
    hit: np.ndarray


@dataclass(frozen=True, slots=True)
class OccupancyMap:
    """A finished map: occupancy probabilities, ``prob[row, col]`` with row 0 at the lowest y."""

    prob: np.ndarray
    resolution: float
    origin_x: float
    origin_y: float


class GridStack:
    """Named log-odds layers (float32, 0 = p 0.5 = unknown) over one growable grid."""

    def __init__(self, resolution: float, grow_margin: float, names: tuple[str, ...],
                 pad_cells: int = 1, max_extent_m: float = math.inf) -> None:
        self.resolution = resolution
        self.max_extent_m = max_extent_m
        self.pad = (pad_cells + 1) * resolution  # cells around every end point stay inside
        self.margin_cells = max(1, math.ceil(grow_margin / resolution))
        self.origin_col = 0  # world cell index of local column 0
        self.origin_row = 0
        self.layers: dict[str, np.ndarray] = {n: np.zeros((0, 0), np.float32) for n in names}
        self.seen = np.zeros((0, 0), bool)
        self._listed = np.zeros((0, 0), np.int32)  # the last scan that listed each cell
        self._scans = 0

    @property
    def shape(self) -> tuple[int, int]:
        return self.seen.shape

    def ensure(self, xmin: float, ymin: float, xmax: float, ymax: float) -> None:
        """Grow every layer so that the rectangle lies inside, with a margin."""
        r = self.resolution
        c0, c1 = math.floor(xmin / r), math.floor(xmax / r)
        r0, r1 = math.floor(ymin / r), math.floor(ymax / r)
        rows, cols = self.shape
        if rows and (self.origin_col <= c0 and c1 < self.origin_col + cols
                     and self.origin_row <= r0 and r1 < self.origin_row + rows):
            return
        m = self.margin_cells
        if rows:
            nc0 = min(self.origin_col, c0 - m) if c0 < self.origin_col else self.origin_col
            nr0 = min(self.origin_row, r0 - m) if r0 < self.origin_row else self.origin_row
            oc1, or1 = self.origin_col + cols - 1, self.origin_row + rows - 1
            nc1 = c1 + m if c1 > oc1 else oc1
            nr1 = r1 + m if r1 > or1 else or1
        else:
            nc0, nr0, nc1, nr1 = c0 - m, r0 - m, c1 + m, r1 + m
        new_shape = (nr1 - nr0 + 1, nc1 - nc0 + 1)
        width, height = new_shape[1] * r, new_shape[0] * r
        if max(width, height) > self.max_extent_m:
            raise MapExtentError(
                f"the map would span {width:.0f} m × {height:.0f} m, more than "
                f"map.max_extent_m = {self.max_extent_m:g} m: an odometry jump or a unit "
                "error in the log? (raise the bound in a --config file for a larger place)")
        dr, dc = self.origin_row - nr0, self.origin_col - nc0
        for name, old in self.layers.items():
            grown = np.zeros(new_shape, old.dtype)
            grown[dr:dr + rows, dc:dc + cols] = old
            self.layers[name] = grown
        seen = np.zeros(new_shape, bool)
        seen[dr:dr + rows, dc:dc + cols] = self.seen
        self.seen = seen
        self._listed = np.zeros(new_shape, np.int32)
        self.origin_row, self.origin_col = nr0, nc0

    def reserve_like(self, other: GridStack) -> None:
        """Size an empty stack to another's area at once (rather than growing, and copying,
        scan by scan)."""
        if self.shape[0] or not other.shape[0]:
            return
        self.origin_row, self.origin_col = other.origin_row, other.origin_col
        self.layers = {n: np.zeros(other.shape, layer.dtype) for n, layer in self.layers.items()}
        self.seen = np.zeros(other.shape, bool)
        self._listed = np.zeros(other.shape, np.int32)

    def flat_index_inside(self, x: np.ndarray, y: np.ndarray, margin_cells: int = 0
                          ) -> tuple[np.ndarray, np.ndarray]:
        """(flat indices of the points at least ``margin_cells`` inside the grid, mask of
        those points)."""
        row, col = self._row_col(x, y)
        rows, cols = self.shape
        k = margin_cells
        inside = (row >= k) & (row < rows - k) & (col >= k) & (col < cols - k)
        return row[inside] * cols + col[inside], inside

    def _row_col(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r = self.resolution
        return (np.floor(y / r).astype(np.int64) - self.origin_row,
                np.floor(x / r).astype(np.int64) - self.origin_col)

    def observe(self, sensor: Pose2D, ranges: np.ndarray, angles: np.ndarray,
                max_range: float, min_range: float, clear_cap: float) -> Observation:
        """Trace every beam of one scan from the sensor pose (sampled every cell length).

        A reading in (min_range, max_range) is a hit at its end and free space up to one cell
        before it;
        a reading >= max_range or +inf is "no return": free space up to ``clear_cap`` and no
        hit; NaN or <= min_range is invalid and ignored.
        """
        ranges = np.ascontiguousarray(ranges, dtype=np.float64)
        angles = np.ascontiguousarray(angles, dtype=np.float64)
        beams = (sensor.x, sensor.y, sensor.theta, ranges, angles, min_range, max_range,
                 clear_cap)
        x0, y0, x1, y1 = _grid.beam_extent(*beams)
        pad = self.pad
        self.ensure(x0 - pad, y0 - pad, x1 + pad, y1 + pad)
        self._scans += 1
        if self._scans == np.iinfo(np.int32).max:  # (after two billion scans)
            self._listed[:] = 0
            self._scans = 1
        # Free space stops one cell short of a hit: the cell a surface passes through is
        # often partly free, and marking it free from one angle and hit from another would
        # erode walls and flicker D.
        free, hit = _grid.trace_beams(
            self.seen.reshape(-1).view(np.uint8), self._listed.reshape(-1), self._scans,
            self.shape[1], self.resolution, self.origin_row, self.origin_col, *beams)
        return Observation(free=free, hit=hit)

    def snapshot(self, name: str) -> OccupancyMap:
        """The layer as probabilities, cropped with the other layers to the observed area."""
        r0, r1, c0, c1 = self.bounds()
        res = self.resolution
        return OccupancyMap(prob=probability(self.layers[name][r0:r1, c0:c1]),
                            resolution=res, origin_x=(self.origin_col + c0) * res,
                            origin_y=(self.origin_row + r0) * res)

    def bounds(self) -> tuple[int, int, int, int]:
        """(row0, row1, col0, col1) half-open local bounds of every observed cell (+1 cell)."""
        rows = np.flatnonzero(self.seen.any(axis=1))
        cols = np.flatnonzero(self.seen.any(axis=0))
        if not len(rows):
            return 0, min(1, self.shape[0]), 0, min(1, self.shape[1])
        r0, r1 = max(rows[0] - 1, 0), min(rows[-1] + 2, self.shape[0])
        c0, c1 = max(cols[0] - 1, 0), min(cols[-1] + 2, self.shape[1])
        return int(r0), int(r1), int(c0), int(c1)
