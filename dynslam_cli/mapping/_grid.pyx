# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False
"""The maps' inner loops: the cells each beam passes through and ends in, the
neighbourhood rule's classification, and the clamped log-odds update.

Compiled by ``pip install`` (setup.py); the algorithm and its documentation live in
``dynslam_cli.mapping.grid`` and ``dynslam_cli.mapping.dynamic``. No fast-math: results
are the same on every run. The long loops release the GIL, so threads (a Dask worker's,
say) can process several logs at once.
"""

import numpy as np

from libc.math cimport INFINITY, atan2, ceil, cos, fabs, floor, hypot, remainder, sin, sqrt
from libc.stdlib cimport calloc, free, malloc, realloc
from cpython.pyport cimport PY_SSIZE_T_MIN

ctypedef unsigned char u8
ctypedef short cell_t  # a layer's stored log-odds, in steps of LOGODDS_STEP

# Log-odds are stored as int16 multiples of this step (±32 log-odds: any clamp short of
# p = 1 − 1e-13); a power of two, so stored · step is exact in float and double.
cdef double STEP = 1.0 / 1024.0
LOGODDS_STEP = STEP


# -- beam tracing and the two-map update ----------------------------------------------------

cdef inline double beam_length(double r, double min_range, double max_range, double cap,
                               bint* hit) noexcept nogil:
    """Traced length of a reading: itself if a hit, the clearing cap if no return (≥ max
    range or +inf), 0 if invalid (NaN, ≤ min range)."""
    hit[0] = r > min_range and r < max_range
    if hit[0]:
        return r
    if r >= max_range:
        return min(cap, max_range)
    return 0.0


# -- tiles: the grid's cells are stored by the area seen ----------------------------------
# A tile is TILE × TILE cells. World cell (R, C) (floor of y / res, x / res) lies in tile
# (R >> SHIFT, C >> SHIFT) at (R & MASK, C & MASK); its flat index in every layer is
# tile id · TILE² + (R & MASK) · TILE + (C & MASK). ``table`` holds the tile id of each tile
# of the grid's extent (-1: not stored yet), ``table[(TR - tr0) * tcols + (TC - tc0)]``.

cdef enum:
    SHIFT = 4
    TILE = 16  # 1 << SHIFT
    MASK = 15
TILE_SIDE = TILE

cdef struct Tiles:
    int* table
    Py_ssize_t tr0, tc0, trows, tcols
    int* tile_row  # world tile row and column of each stored tile
    int* tile_col
    Py_ssize_t count, capacity
    Py_ssize_t last_key  # one-tile cache: beams run on through the same tile
    Py_ssize_t last_id


cdef inline Py_ssize_t tile_of(Tiles* t, Py_ssize_t R, Py_ssize_t C) noexcept nogil:
    """Tile id of world cell (R, C), or -1 where no tile holds it (anywhere)."""
    cdef Py_ssize_t tr = (R >> SHIFT) - t.tr0, tc = (C >> SHIFT) - t.tc0, key
    if tr < 0 or tc < 0 or tr >= t.trows or tc >= t.tcols:
        return -1
    key = tr * t.tcols + tc
    if key != t.last_key:  # a window mostly stays in one tile
        t.last_key = key
        t.last_id = t.table[key]
    return t.last_id


cdef inline Py_ssize_t stored_tile(Tiles* t, Py_ssize_t tr, Py_ssize_t tc) noexcept nogil:
    """Tile id of world tile (tr, tc) inside the extent, a new tile if it has none yet; -1
    when there is no room left (the tracer's path: no bounds check, no cache)."""
    cdef Py_ssize_t key = (tr - t.tr0) * t.tcols + (tc - t.tc0), tid = t.table[key]
    if tid < 0:
        if t.count == t.capacity:
            return -1
        tid = t.count
        t.count += 1
        t.table[key] = <int>tid
        t.tile_row[tid] = <int>tr
        t.tile_col[tid] = <int>tc
    return tid


cdef inline Py_ssize_t cell_in(Py_ssize_t tid, Py_ssize_t R, Py_ssize_t C) noexcept nogil:
    return (tid << (2 * SHIFT)) + ((R & MASK) << SHIFT) + (C & MASK)


cdef Tiles tiles_view(int[::1] table, Py_ssize_t tr0, Py_ssize_t tc0, Py_ssize_t tcols,
                      int[::1] tile_row, int[::1] tile_col, Py_ssize_t count):
    cdef Tiles t
    t.table = &table[0]  # (no reads while trows is 0)
    t.tr0 = tr0
    t.tc0 = tc0
    t.tcols = tcols
    t.trows = table.shape[0] // tcols if tcols else 0
    t.tile_row = &tile_row[0]
    t.tile_col = &tile_col[0]
    t.count = count
    t.capacity = tile_row.shape[0]
    t.last_key = -1
    t.last_id = -1
    return t


def beam_extent(double sx, double sy, double sth, const double[::1] ranges,
                const double[::1] angles, double min_range, double max_range, double cap):
    """(xmin, ymin, xmax, ymax) of the sensor and every traced beam's end."""
    cdef double x0 = sx, y0 = sy, x1 = sx, y1 = sy, length, ex, ey
    cdef bint hit
    cdef Py_ssize_t i
    for i in range(ranges.shape[0]):
        length = beam_length(ranges[i], min_range, max_range, cap, &hit)
        if length > 0:
            ex = sx + length * cos(angles[i] + sth)
            ey = sy + length * sin(angles[i] + sth)
            x0 = min(x0, ex)
            x1 = max(x1, ex)
            y0 = min(y0, ey)
            y1 = max(y1, ey)
    return x0, y0, x1, y1


def trace_beams(u8[::1] listed, int mark, int[::1] table, Py_ssize_t tr0,
                Py_ssize_t tc0, Py_ssize_t tcols, int[::1] tile_row, int[::1] tile_col,
                Py_ssize_t count, double res, Py_ssize_t row0, Py_ssize_t col0, double sx,
                double sy, double sth, const double[::1] ranges, const double[::1] angles,
                double min_range, double max_range, double cap):
    """(free cells, hit cells, tiles stored) of one scan from the sensor pose (see
    GridStack.observe): each hit's end cell, and the cells sampled every ``res`` along each
    beam up to one cell short of a hit (to the cap for no return), less any cell hit; each
    cell listed once, which ``listed[cell] = mark`` records (``mark``: a value ≥ 2 no
    earlier scan since the last reset used; a cell never seen stays 0). Stores the tiles
    they fall in (the first ``count`` of ``tile_row``/``tile_col`` are in use). Samples step in cells
    from the sensor's position relative to cell (row0, col0), the grid extent's corner,
    which must hold every beam's extent (beam_extent). Free and hit are None when the tile
    arrays ran out of room: grow them and call again."""
    cdef Py_ssize_t n = ranges.shape[0], i, k, total = 0, nh = 0, nf = 0, c, tid
    cdef Py_ssize_t R, C, base = 0, last_tr = PY_SSIZE_T_MIN, last_tc = PY_SSIZE_T_MIN
    cdef double length, ca, sa, u0 = sx / res - col0, v0 = sy / res - row0  # sensor, in cells
    cdef bint hit_i, new, full = False
    cdef Tiles t = tiles_view(table, tr0, tc0, tcols, tile_row, tile_col, count)
    steps = np.zeros(n, dtype=np.intp)
    dirs = np.zeros((n, 2))
    ends = np.zeros((n, 2), dtype=np.intp)
    is_hit = np.zeros(n, dtype=np.uint8)
    cdef Py_ssize_t[::1] cnt = steps
    cdef Py_ssize_t[:, ::1] end = ends
    cdef u8[::1] eh = is_hit
    cdef double[:, ::1] dv = dirs
    for i in range(n):
        length = beam_length(ranges[i], min_range, max_range, cap, &hit_i)
        if length <= 0:
            continue
        ca = cos(angles[i] + sth)
        sa = sin(angles[i] + sth)
        dv[i, 0] = ca
        dv[i, 1] = sa
        if hit_i:
            eh[i] = 1
            end[i, 0] = <Py_ssize_t>floor((sy + length * sa) / res)
            end[i, 1] = <Py_ssize_t>floor((sx + length * ca) / res)
            length = max(length - res, 0.0)
        cnt[i] = <Py_ssize_t>ceil(length / res)
        total += cnt[i]
    hit = np.empty(n, dtype=np.intp)
    free = np.empty(total + 1, dtype=np.intp)
    cdef Py_ssize_t[::1] hv = hit
    cdef Py_ssize_t[::1] fv = free
    with nogil:
        for i in range(n):
            if not eh[i]:
                continue
            tid = stored_tile(&t, end[i, 0] >> SHIFT, end[i, 1] >> SHIFT)
            if tid < 0:
                full = True
                break
            c = cell_in(tid, end[i, 0], end[i, 1])
            if listed[c] != mark:
                listed[c] = mark
                hv[nh] = c
                nh += 1
        for i in range(n):
            if full:
                break
            ca = dv[i, 0]
            sa = dv[i, 1]
            for k in range(cnt[i]):  # inside the extent: truncation is floor
                R = <Py_ssize_t>(v0 + k * sa) + row0
                C = <Py_ssize_t>(u0 + k * ca) + col0
                if (R >> SHIFT) != last_tr or (C >> SHIFT) != last_tc:  # a beam's next tile
                    last_tr, last_tc = R >> SHIFT, C >> SHIFT
                    tid = stored_tile(&t, last_tr, last_tc)
                    if tid < 0:
                        full = True
                        break
                    base = tid << (2 * SHIFT)
                c = base + ((R & MASK) << SHIFT) + (C & MASK)
                new = listed[c] != mark  # branch-free: about half the samples are new
                listed[c] = mark
                fv[nf] = c
                nf += new
    if full:
        return None, None, t.count
    return free[:nf], hit[:nh], t.count


cdef inline int window_state(const cell_t* logodds, Tiles* t, Py_ssize_t R, Py_ssize_t C,
                             Py_ssize_t radius, double low, double high) noexcept nogil:
    """2 Occupied if any cell of the window around world cell (R, C) is > high, 0 Free if
    every one is < low, else 1 Unknown; cells not stored count 0 (p = 0.5)."""
    cdef Py_ssize_t dr, dc, tid
    cdef double v
    cdef bint free = True
    for dr in range(-radius, radius + 1):
        for dc in range(-radius, radius + 1):
            tid = tile_of(t, R + dr, C + dc)
            v = logodds[cell_in(tid, R + dr, C + dc)] * STEP if tid >= 0 else 0.0
            if v > high:
                return 2
            if not v < low:
                free = False
    return 0 if free else 1


def classify_cells(const cell_t[::1] logodds, const Py_ssize_t[::1] cells, Py_ssize_t radius,
                   int[::1] table, Py_ssize_t tr0, Py_ssize_t tc0, Py_ssize_t tcols,
                   int[::1] tile_row, int[::1] tile_col, Py_ssize_t count, double low,
                   double high):
    """State of each stored cell's window of ``radius`` cells (window_state)."""
    cdef Py_ssize_t n = cells.shape[0], i, c, tid
    cdef Tiles t = tiles_view(table, tr0, tc0, tcols, tile_row, tile_col, count)
    out = np.empty(n, dtype=np.int8)
    cdef signed char[::1] o = out
    with nogil:
        for i in range(n):
            c = cells[i]
            tid = c >> (2 * SHIFT)
            o[i] = window_state(&logodds[0], &t,
                                (<Py_ssize_t>t.tile_row[tid] << SHIFT) + ((c >> SHIFT) & MASK),
                                (<Py_ssize_t>t.tile_col[tid] << SHIFT) + (c & MASK),
                                radius, low, high)
    return out


def classify_world_cells(const cell_t[::1] logodds, const Py_ssize_t[::1] rows,
                         const Py_ssize_t[::1] cols, Py_ssize_t radius, int[::1] table,
                         Py_ssize_t tr0, Py_ssize_t tc0, Py_ssize_t tcols, int[::1] tile_row,
                         int[::1] tile_col, Py_ssize_t count, double low, double high):
    """State of the window around each world cell (rows[i], cols[i]), stored or not."""
    cdef Py_ssize_t n = rows.shape[0], i
    cdef Tiles t = tiles_view(table, tr0, tc0, tcols, tile_row, tile_col, count)
    out = np.empty(n, dtype=np.int8)
    cdef signed char[::1] o = out
    with nogil:
        for i in range(n):
            o[i] = window_state(&logodds[0], &t, rows[i], cols[i], radius, low, high)
    return out


def add_clamped(cell_t[::1] logodds, const Py_ssize_t[::1] cells,
                const signed char[::1] states, const int[::1] value, int lo, int hi):
    """logodds[cell] += value[state of the cell], clamped to [lo, hi] (all in steps; cells
    listed once)."""
    cdef Py_ssize_t i, c
    cdef int v
    with nogil:
        for i in range(cells.shape[0]):
            c = cells[i]
            v = logodds[c] + value[states[i]]
            logodds[c] = <cell_t>(lo if v < lo else hi if v > hi else v)


def cells_above(const cell_t[::1] logodds, const Py_ssize_t[::1] cells, int threshold,
                bint above=True):
    """The cells (flat indices, in their order) whose stored log-odds exceed ``threshold``
    (steps), or with ``above`` False do not: of the cells a scan saw free, those S held
    Occupied; of those it hit, those S did not yet (change events)."""
    cdef Py_ssize_t n = cells.shape[0], i, k = 0
    out = np.empty(n, dtype=np.intp)
    cdef Py_ssize_t[::1] o = out
    with nogil:
        for i in range(n):
            o[k] = cells[i]
            k += (logodds[cells[i]] > threshold) == above
    return out[:k]
