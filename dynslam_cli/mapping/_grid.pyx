# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False
"""The maps' inner loops: the cells each beam passes through and ends in, the
neighbourhood rule's classification, and the clamped log-odds update.

Compiled by ``pip install`` (setup.py); the algorithm and its documentation live in
``dynslam_cli.mapping.grid and dynslam_cli.mapping.dynamic``. No fast-math: results are the same on every run. The long loops release the
GIL, so threads (a Dask worker's, say) can process several logs at once.
"""

import numpy as np

from libc.math cimport INFINITY, atan2, ceil, cos, fabs, floor, hypot, remainder, sin, sqrt
from libc.stdlib cimport calloc, free, malloc, realloc

ctypedef unsigned char u8


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


cdef inline Py_ssize_t flat_cell(double x, double y, double res, Py_ssize_t row0,
                                 Py_ssize_t col0, Py_ssize_t cols) noexcept nogil:
    return (<Py_ssize_t>floor(y / res) - row0) * cols + (<Py_ssize_t>floor(x / res) - col0)


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


def trace_beams(u8[::1] seen, int[::1] listed, int mark, Py_ssize_t cols, double res,
                Py_ssize_t row0, Py_ssize_t col0, double sx, double sy, double sth,
                const double[::1] ranges, const double[::1] angles, double min_range,
                double max_range, double cap):
    """(free cells, hit cells) of one scan from the sensor pose (see GridStack.observe): each
    hit's end cell, and the cells sampled every ``res`` along each beam up to one cell short
    of a hit (to the cap for no return), less any cell hit; each cell listed once, which
    ``listed[cell] = mark`` records (``mark``: a value no earlier scan used). Marks them in
    ``seen``. The grid must hold every beam's extent (beam_extent)."""
    cdef Py_ssize_t n = ranges.shape[0], i, k, total = 0, nh = 0, nf = 0, c, u, v
    cdef double length, ca, sa, u0 = sx / res - col0, v0 = sy / res - row0  # sensor, in cells
    cdef bint hit_i, new
    steps = np.zeros(n, dtype=np.intp)
    dirs = np.zeros((n, 2))
    cells = np.full(n, -1, dtype=np.intp)
    cdef Py_ssize_t[::1] cnt = steps
    cdef Py_ssize_t[::1] end = cells
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
            end[i] = flat_cell(sx + length * ca, sy + length * sa, res, row0, col0, cols)
            length = max(length - res, 0.0)
        cnt[i] = <Py_ssize_t>ceil(length / res)
        total += cnt[i]
    hit = np.empty(n, dtype=np.intp)
    free = np.empty(total + 1, dtype=np.intp)
    cdef Py_ssize_t[::1] hv = hit
    cdef Py_ssize_t[::1] fv = free
    with nogil:
        for i in range(n):
            c = end[i]
            if c >= 0 and listed[c] != mark:
                listed[c] = mark
                seen[c] = 1
                hv[nh] = c
                nh += 1
        for i in range(n):
            ca = dv[i, 0]
            sa = dv[i, 1]
            for k in range(cnt[i]):  # inside the grid: truncation is floor
                v = <Py_ssize_t>(v0 + k * sa)
                u = <Py_ssize_t>(u0 + k * ca)
                c = v * cols + u
                new = listed[c] != mark  # branch-free: about half the samples are new
                listed[c] = mark
                seen[c] = 1
                fv[nf] = c
                nf += new
    return free[:nf], hit[:nh]


def classify_cells(const float[::1] logodds, const Py_ssize_t[::1] cells,
                   const Py_ssize_t[::1] offsets, double low, double high):
    """State of each cell's window (cell + offsets): 2 Occupied if any value > high, 0 Free
    if every value < low, else 1 Unknown (log-odds thresholds)."""
    cdef Py_ssize_t n = cells.shape[0], m = offsets.shape[0], i, k
    cdef double v
    cdef bint occupied, free
    out = np.empty(n, dtype=np.int8)
    cdef signed char[::1] o = out
    with nogil:
        for i in range(n):
            occupied = False
            free = True
            for k in range(m):
                v = logodds[cells[i] + offsets[k]]
                if v > high:
                    occupied = True
                    break
                if not v < low:
                    free = False
            o[i] = 2 if occupied else 0 if free else 1
    return out


def add_clamped(float[::1] logodds, const Py_ssize_t[::1] cells,
                const signed char[::1] states, const double[::1] value, double lo, double hi):
    """logodds[cell] += value[state of the cell], clamped to [lo, hi] (cells listed once)."""
    cdef Py_ssize_t i, c
    cdef double v
    with nogil:
        for i in range(cells.shape[0]):
            c = cells[i]
            v = logodds[c] + value[states[i]]
            logodds[c] = <float>(lo if v < lo else hi if v > hi else v)
