"""Occupancy grids in log-odds, stored by the area seen, and beam tracing.

World cell (row, col) covers x in [col·res, (col+1)·res) and likewise y with row, so row 0 is
the *lowest* y (writers flip it for images, whose first row is the top). All layers of a
:class:`GridStack` share one geometry and grow together, so the static and dynamic maps
always have the same size and origin.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from dynslam_cli.errors import DynslamError
from dynslam_cli.mapping import _grid
from dynslam_cli.types import Pose2D

TILE = _grid.TILE_SIDE  # cells on a tile's side
LOGODDS_STEP = _grid.LOGODDS_STEP  # a layer stores log-odds as int16 multiples of this
MAX_LOGODDS = 32767 * LOGODDS_STEP  # so a clamp can be at most this (p = 1 − 1.3e-14)


class MapExtentError(DynslamError):
    """The map would grow beyond its configured bound."""


def logit(p: float) -> float:
    """Log-odds of probability p."""
    return math.log(p / (1.0 - p))


def steps(logodds: float | np.ndarray) -> np.ndarray:
    """Log-odds as a layer stores them: the nearest whole number of ``LOGODDS_STEP`` (int32;
    the layers are int16, so values to store must lie within ±MAX_LOGODDS)."""
    return np.rint(np.asarray(logodds, dtype=np.float64) / LOGODDS_STEP).astype(np.int32)


def probability(stored: np.ndarray) -> np.ndarray:
    """Probability from a layer's stored log-odds (elementwise)."""
    p = np.exp(stored * -LOGODDS_STEP)  # 1 / (1 + e^-l), in one buffer (float64)
    p += 1.0
    return np.reciprocal(p, out=p)


@dataclass(frozen=True, slots=True)
class Observation:
    """What one scan says about the grid: flat indices of cells seen free and cells hit,
    each listed once. A cell hit by one beam and passed through by another is only in
    ``hit``."""

    free: np.ndarray
    hit: np.ndarray


BAND_ROWS = 256  # rows of a map read at a time by the writers


class OccupancyMap:
    """A finished map: occupancy probabilities with row 0 at the lowest y, cell (row, col)
    covering x from ``origin_x + col·resolution``. Made from a dense array (``prob``) or from
    a grid, read band by band (``rows_of(r0, r1)``: the probabilities of rows r0:r1), so a
    large map is never held in full; :attr:`prob` makes the dense array when asked."""

    def __init__(self, prob: np.ndarray | None, resolution: float, origin_x: float,
                 origin_y: float, *, shape: tuple[int, int] | None = None,
                 rows_of: Callable[[int, int], np.ndarray] | None = None) -> None:
        if prob is not None:
            shape, rows_of = prob.shape, lambda r0, r1: prob[r0:r1]
        if shape is None or rows_of is None:
            raise ValueError("an OccupancyMap needs prob, or shape and rows_of")
        self.resolution, self.origin_x, self.origin_y = resolution, origin_x, origin_y
        self.shape = (int(shape[0]), int(shape[1]))
        self._rows_of = rows_of
        self._prob = prob

    def band(self, r0: int, r1: int) -> np.ndarray:
        """Probabilities of rows r0:r1 (float64)."""
        return self._rows_of(r0, r1)

    def bands(self, rows: int = BAND_ROWS, from_top: bool = False
              ) -> Iterator[tuple[int, np.ndarray]]:
        """(first row, probabilities) of consecutive bands of ``rows`` rows, bottom up (top
        down with ``from_top``: the order of an image's rows, each band still bottom up)."""
        starts = range(0, self.shape[0], rows)
        for r0 in reversed(starts) if from_top else starts:
            yield r0, self.band(r0, min(r0 + rows, self.shape[0]))

    def dense(self) -> OccupancyMap:
        """The same map held in full (a grid's snapshot that must outlive the grid's next
        update)."""
        return OccupancyMap(self.prob, self.resolution, self.origin_x, self.origin_y)

    @property
    def prob(self) -> np.ndarray:
        """The whole map as one array (made once)."""
        if self._prob is None:
            self._prob = self.band(0, self.shape[0])
        return self._prob


class GridStack:
    """Named log-odds layers (int16 in steps of ``LOGODDS_STEP``, 0 = p 0.5 = unknown) over
    one grid, stored by the area seen: in tiles of ``TILE × TILE`` cells, each allocated when
    a beam first reaches it. With the byte of marks that lists each cell once per scan (0:
    never seen), a cell costs 2 bytes a layer + 1.

    The grid's *extent* (``origin_row``, ``origin_col``, ``shape``: a rectangle of world
    cells that grows with a margin to hold every scan) bounds the map and fixes where beams
    are sampled; memory follows the tiles. A cell's *flat index* addresses it in every
    layer (``layers[name]``): tile id · TILE² + its place in the tile.
    """

    def __init__(self, resolution: float, grow_margin: float, names: tuple[str, ...],
                 pad_cells: int = 1, max_extent_m: float = math.inf) -> None:
        self.resolution = resolution
        self.max_extent_m = max_extent_m
        self.pad = (pad_cells + 1) * resolution  # cells around every end point stay inside
        self.margin_cells = max(1, math.ceil(grow_margin / resolution))
        self.origin_col = 0  # world cell index of the extent's column 0
        self.origin_row = 0
        self._shape = (0, 0)
        self.layers: dict[str, np.ndarray] = {n: np.zeros(0, np.int16) for n in names}
        # the mark of the last scan that listed a cell: 0 never, 1 before the marks wrapped
        self._listed = np.zeros(0, np.uint8)
        self._mark = 1
        # tiles: world tile (row, col) of each stored tile; the extent's table of tile ids
        self.tile_rows = np.zeros(0, np.int32)
        self.tile_cols = np.zeros(0, np.int32)
        self.tiles = 0
        self.seeded = False
        """Whether cells were set from an earlier session's map (:meth:`seed`)."""
        self._table = np.full((0, 0), -1, np.int32)
        self._table_origin = (0, 0)  # world tile of the table's [0, 0]

    @property
    def shape(self) -> tuple[int, int]:
        """Rows and columns of the extent."""
        return self._shape

    def ensure(self, xmin: float, ymin: float, xmax: float, ymax: float) -> None:
        """Grow the extent so that the rectangle lies inside, with a margin."""
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
        self._set_extent(nr0, nc0, nr1 - nr0 + 1, nc1 - nc0 + 1)

    def _set_extent(self, row0: int, col0: int, rows: int, cols: int) -> None:
        width, height = cols * self.resolution, rows * self.resolution
        if max(width, height) > self.max_extent_m:
            raise MapExtentError(
                f"the map would span {width:.0f} m × {height:.0f} m, more than "
                f"map.max_extent_m = {self.max_extent_m:g} m: an odometry jump or a unit "
                "error in the log? (raise the bound in a --config file for a larger place)")
        self.origin_row, self.origin_col, self._shape = row0, col0, (rows, cols)
        tr0, tc0 = row0 // TILE, col0 // TILE  # the tiles the extent touches
        tr1, tc1 = (row0 + rows - 1) // TILE, (col0 + cols - 1) // TILE
        table = np.full((tr1 - tr0 + 1, tc1 - tc0 + 1), -1, np.int32)
        table[self.tile_rows[:self.tiles] - tr0, self.tile_cols[:self.tiles] - tc0] = \
            np.arange(self.tiles, dtype=np.int32)
        self._table, self._table_origin = table, (tr0, tc0)

    def add_layer(self, name: str, dtype: type) -> None:
        """Another layer, of any number type, over the cells stored so far and to come (0)."""
        self.layers[name] = np.zeros(len(self._listed), dtype)

    def reserve_like(self, other: GridStack) -> None:
        """Take another stack's extent and room for its tiles at once (rather than growing,
        and copying, scan by scan)."""
        if self.shape[0] or not other.shape[0]:
            return
        self._set_extent(other.origin_row, other.origin_col, *other.shape)
        self._grow_tiles(other.tiles + other.tiles // 4)  # (room for poses the graph moved)

    def _grow_tiles(self, capacity: int) -> None:
        """Room for ``capacity`` tiles in every array, new cells 0. Arrays are grown in place
        (realloc: no second copy at any moment); empty ones are made afresh, and the pages
        of the room not yet used cost no memory until a tile is stored there."""
        size = capacity * TILE * TILE

        def grown(a: np.ndarray) -> np.ndarray:
            if not len(a):
                return np.zeros(size, a.dtype)
            a.resize(size, refcheck=False)
            return a

        self.layers = {name: grown(a) for name, a in self.layers.items()}
        self._listed = grown(self._listed)
        self.tile_rows.resize(capacity, refcheck=False)
        self.tile_cols.resize(capacity, refcheck=False)

    def world_cells(self, flat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World (row, col) of cells given by flat index."""
        flat = np.asarray(flat, dtype=np.int64)
        tile, place = np.divmod(flat, TILE * TILE)
        r, c = np.divmod(place, TILE)
        return (self.tile_rows[tile].astype(np.int64) * TILE + r,
                self.tile_cols[tile].astype(np.int64) * TILE + c)

    def cell_centres(self, flat: np.ndarray) -> np.ndarray:
        """Map-frame (x, y) of the centres of cells given by flat index (N × 2)."""
        rows, cols = self.world_cells(flat)
        return (np.column_stack((cols, rows)) + 0.5) * self.resolution

    def flat_cells(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Flat indices of world cells (rows, cols); -1 where no tile holds the cell."""
        rows, cols = np.asarray(rows, dtype=np.int64), np.asarray(cols, dtype=np.int64)
        tr, tc = rows // TILE - self._table_origin[0], cols // TILE - self._table_origin[1]
        inside = (tr >= 0) & (tr < self._table.shape[0]) & (tc >= 0) & (tc < self._table.shape[1])
        tile = np.full(rows.shape, -1, np.int64)
        tile[inside] = self._table[tr[inside], tc[inside]]
        flat = tile * TILE * TILE + (rows % TILE) * TILE + cols % TILE
        return np.where(tile >= 0, flat, -1)

    def seed(self, name: str, rows: np.ndarray, cols: np.ndarray, values: np.ndarray) -> None:
        """Set the layer's stored values (int16 steps) at world cells (rows, cols), listed
        once each, as seen: an earlier session's map that this one starts from."""
        if not len(rows):
            return
        r = self.resolution
        self.ensure(cols.min() * r, rows.min() * r, (cols.max() + 0.5) * r,
                    (rows.max() + 0.5) * r)
        tr0, tc0 = self._table_origin
        wanted = np.zeros(self._table.shape, bool)  # (marked on the table, not np.unique's
        wanted[rows // TILE - tr0, cols // TILE - tc0] = True  # sort: 10x faster)
        new = np.argwhere(wanted & (self._table < 0)) + np.array([tr0, tc0])  # (row by row)
        if self.tiles + len(new) > len(self.tile_rows):
            self._grow_tiles(self.tiles + len(new) + 64)
        ids = np.arange(self.tiles, self.tiles + len(new), dtype=np.int32)
        self.tile_rows[ids], self.tile_cols[ids] = new[:, 0], new[:, 1]
        self._table[new[:, 0] - tr0, new[:, 1] - tc0] = ids
        self.tiles += len(new)
        flat = self.flat_cells(rows, cols)
        self.layers[name][flat] = values
        self._listed[flat] = np.maximum(self._listed[flat], 1)
        self.seeded = True

    def world_cells_of(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World (row, col) of the cells holding the points (x, y)."""
        r = self.resolution
        return np.floor(y / r).astype(np.intp), np.floor(x / r).astype(np.intp)

    def _tiles_args(self) -> tuple:
        tr0, tc0 = self._table_origin
        return (self._table.reshape(-1), tr0, tc0, self._table.shape[1], self.tile_rows,
                self.tile_cols, self.tiles)

    def classify_cells(self, name: str, flat: np.ndarray, radius: int, low: float,
                       high: float) -> np.ndarray:
        """State (0 Free, 1 Unknown, 2 Occupied; log-odds thresholds) of the layer over the
        window of ``radius`` cells around each stored cell (flat indices)."""
        return _grid.classify_cells(self.layers[name], flat, radius, *self._tiles_args(),
                                    low, high)

    def classify_world_cells(self, name: str, rows: np.ndarray, cols: np.ndarray,
                             radius: int, low: float, high: float) -> np.ndarray:
        """The same around world cells (rows, cols), stored or not (not stored: p 0.5)."""
        return _grid.classify_world_cells(self.layers[name], rows, cols, radius,
                                          *self._tiles_args(), low, high)

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
        while True:
            self._mark += 1
            if self._mark == 256:  # (marks are bytes: start again, keeping "seen" as 1)
                np.minimum(self._listed, 1, out=self._listed)
                self._mark = 2
            # Free space stops one cell short of a hit: the cell a surface passes through is
            # often partly free, and marking it free from one angle and hit from another
            # would erode walls and flicker D.
            free, hit, self.tiles = _grid.trace_beams(
                self._listed, self._mark, *self._tiles_args(), self.resolution,
                self.origin_row, self.origin_col, *beams)
            if free is not None:
                return Observation(free=free, hit=hit)
            self._grow_tiles(len(self.tile_rows) + max(64, len(self.tile_rows) // 8))  # again

    @property
    def seen(self) -> np.ndarray:
        """Whether each stored cell has been seen (bool, by flat index)."""
        return self._listed[:self.tiles * TILE * TILE] != 0

    def window(self, name: str, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        """The layer's stored values (int16 steps) over extent rows r0:r1, columns c0:c1, 0
        where no tile is stored (everywhere for a layer not kept)."""
        out = np.zeros((r1 - r0, c1 - c0), np.int16)
        source = self.layers.get(name)
        if source is None:
            return out
        wr0, wc0 = self.origin_row + r0, self.origin_col + c0  # the window in world cells
        wr1, wc1 = self.origin_row + r1, self.origin_col + c1
        n = self.tiles
        tr = self.tile_rows[:n].astype(np.int64) * TILE
        tc = self.tile_cols[:n].astype(np.int64) * TILE
        wanted = np.flatnonzero((tr < wr1) & (tr + TILE > wr0) & (tc < wc1) & (tc + TILE > wc0))
        tiles = source[:n * TILE * TILE].reshape(n, TILE, TILE)
        for t in wanted:
            a, b = max(tr[t], wr0), min(tr[t] + TILE, wr1)
            c, d = max(tc[t], wc0), min(tc[t] + TILE, wc1)
            out[a - wr0:b - wr0, c - wc0:d - wc0] = tiles[t, a - tr[t]:b - tr[t],
                                                          c - tc[t]:d - tc[t]]
        return out

    def snapshot(self, name: str) -> OccupancyMap:
        """The layer as probabilities, cropped with the other layers to the observed area;
        read from the grid band by band as the writers need it (so the grid must not change
        while the map is in use)."""
        r0, r1, c0, c1 = self.bounds()
        res = self.resolution
        return OccupancyMap(None, res, (self.origin_col + c0) * res,
                            (self.origin_row + r0) * res, shape=(r1 - r0, c1 - c0),
                            rows_of=lambda a, b: probability(self.window(name, r0 + a, r0 + b,
                                                                         c0, c1)))

    def mapped(self, name: str, convert: Callable[[np.ndarray], np.ndarray]
               ) -> tuple[np.ndarray, float, float]:
        """(values, origin x, origin y): the layer over the observed area (the crop of
        :meth:`snapshot`, row 0 at the lowest y), its stored values (int16 steps) turned into
        values by ``convert`` (elementwise, whole arrays; a cell no tile holds is
        ``convert`` of 0); made at once, in a few whole-array steps (a recording sends the
        maps while the run goes on)."""
        r0, r1, c0, c1 = self.bounds()
        res = self.resolution
        wr0, wc0 = self.origin_row + r0, self.origin_col + c0  # the crop in world cells
        wr1, wc1 = self.origin_row + r1, self.origin_col + c1
        n = self.tiles
        tr0, tc0 = wr0 // TILE, wc0 // TILE  # the tiles the crop touches
        rows, cols = (wr1 - 1) // TILE - tr0 + 1, (wc1 - 1) // TILE - tc0 + 1
        fill = convert(np.zeros(1, np.int16))
        block = np.full((rows * TILE, cols * TILE), fill[0], fill.dtype)
        layer = self.layers.get(name)
        if n and layer is not None:
            tiles = block.reshape(rows, TILE, cols, TILE).transpose(0, 2, 1, 3)  # (a view)
            tiles[self.tile_rows[:n] - tr0, self.tile_cols[:n] - tc0] = \
                convert(layer[:n * TILE * TILE]).reshape(n, TILE, TILE)
        top, left = wr0 - tr0 * TILE, wc0 - tc0 * TILE
        return block[top:top + r1 - r0, left:left + c1 - c0], wc0 * res, wr0 * res

    def bounds(self) -> tuple[int, int, int, int]:
        """(row0, row1, col0, col1) half-open extent bounds of every observed cell (+1 cell).
        Every stored tile holds a seen cell, so only the outermost tiles are looked into."""
        n = self.tiles
        if not n:
            return 0, min(1, self.shape[0]), 0, min(1, self.shape[1])
        marks = self._listed[:n * TILE * TILE].reshape(n, TILE, TILE)  # (0: not seen)
        tr, tc = self.tile_rows[:n].astype(np.int64), self.tile_cols[:n].astype(np.int64)

        def extreme(tiles: np.ndarray, axis: int, last: bool) -> int:
            """The lowest (or highest) seen row (axis 1) or column (axis 2) within tiles."""
            hits = np.flatnonzero(marks[tiles].any(axis=3 - axis).any(axis=0))
            return int(hits[-1] if last else hits[0])

        r_lo = tr.min() * TILE + extreme(np.flatnonzero(tr == tr.min()), 1, False)
        r_hi = tr.max() * TILE + extreme(np.flatnonzero(tr == tr.max()), 1, True)
        c_lo = tc.min() * TILE + extreme(np.flatnonzero(tc == tc.min()), 2, False)
        c_hi = tc.max() * TILE + extreme(np.flatnonzero(tc == tc.max()), 2, True)
        return (max(int(r_lo) - self.origin_row - 1, 0),
                min(int(r_hi) - self.origin_row + 2, self.shape[0]),
                max(int(c_lo) - self.origin_col - 1, 0),
                min(int(c_hi) - self.origin_col + 2, self.shape[1]))

    def memory(self) -> dict[str, float]:
        """What the grid holds, for the summary: tiles, cells stored and seen, bytes per cell
        seen."""
        cells = self.tiles * TILE * TILE
        per_cell = sum(a.itemsize for a in (*self.layers.values(), self._listed))
        seen = int(np.count_nonzero(self._listed[:cells]))
        return {"tiles": self.tiles, "cells_stored": cells, "cells_seen": seen,
                "bytes_per_seen_cell": round(per_cell * cells / seen, 2) if seen else 0.0}
