# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False
"""The corner detector's inner loops: split-and-merge line fitting over a scan's runs.

Compiled by ``pip install`` (setup.py); the algorithm and its documentation live in
``dynslam_cli.localization.corners``. No fast-math: results are the same on every run. The long loops release the
GIL, so threads (a Dask worker's, say) can process several logs at once.
"""

import numpy as np

from libc.math cimport INFINITY, atan2, ceil, cos, fabs, floor, hypot, remainder, sin, sqrt
from libc.stdlib cimport calloc, free, malloc, realloc

ctypedef unsigned char u8


# -- corners --------------------------------------------------------------------------------

cdef void line_fit(const double[:, ::1] p, Py_ssize_t a, Py_ssize_t b, double out[5]
                   ) noexcept nogil:
    """Total least squares over p[a..b]: centre (x, y), unit direction (x, y), RMS residual."""
    cdef Py_ssize_t i, n = b - a + 1
    cdef double mx = 0.0, my = 0.0, sxx = 0.0, syy = 0.0, sxy = 0.0, dx, dy, half, rad, lo
    for i in range(a, b + 1):
        mx += p[i, 0]
        my += p[i, 1]
    mx /= n
    my /= n
    for i in range(a, b + 1):
        dx = p[i, 0] - mx
        dy = p[i, 1] - my
        sxx += dx * dx
        syy += dy * dy
        sxy += dx * dy
    half = 0.5 * (sxx + syy)
    rad = hypot(0.5 * (sxx - syy), sxy)
    lo = half - rad
    if lo < 0.0:
        lo = 0.0
    dx = 0.5 * atan2(2.0 * sxy, sxx - syy)  # direction of most spread
    out[0] = mx
    out[1] = my
    out[2] = cos(dx)
    out[3] = sin(dx)
    out[4] = sqrt(lo / n)


def split_runs(const double[:, ::1] p, Py_ssize_t lo, Py_ssize_t hi, double tol):
    """Straight runs of p[lo..hi] (inclusive index pairs, in order) by recursive splitting
    at the point farthest from the chord."""
    stack = [(lo, hi)]
    out = []
    cdef Py_ssize_t a, b, i, k
    cdef double dx, dy, n, dist, best
    while stack:
        a, b = stack.pop()
        if b - a < 2:
            out.append((a, b))
            continue
        dx = p[b, 0] - p[a, 0]
        dy = p[b, 1] - p[a, 1]
        n = hypot(dx, dy)
        best = -1.0
        k = a + 1
        for i in range(a + 1, b):
            if n < 1e-9:
                dist = hypot(p[i, 0] - p[a, 0], p[i, 1] - p[a, 1])
            else:
                dist = fabs(dx * (p[i, 1] - p[a, 1]) - dy * (p[i, 0] - p[a, 0])) / n
            if dist > best:
                best = dist
                k = i
        if best > tol:
            stack.append((k, b))
            stack.append((a, k))
        else:
            out.append((a, b))
    out.sort()
    return out


def detect_corners(const double[::1] ranges, const double[::1] angles, double limit,
                   double jump_m, double jump_ratio, double tol, Py_ssize_t min_points,
                   double min_length, double max_rms, double cos_max, double max_gap,
                   Py_ssize_t max_beams_between):
    """Corners (x, y, convex) of one scan in the laser frame (see corners.py): clusters of
    consecutive valid beams (range in (0.05, limit)) without range jumps, straight runs in
    each, and corners where two adjacent good runs meet."""
    cdef Py_ssize_t n = ranges.shape[0], i, start = 0
    pts = np.zeros((n, 2))
    cdef double[:, ::1] p = pts
    valid = np.zeros(n, dtype=np.uint8)
    cdef u8[::1] ok = valid
    for i in range(n):
        if ranges[i] > 0.05 and ranges[i] < limit:  # NaN fails both
            ok[i] = 1
            p[i, 0] = ranges[i] * cos(angles[i])
            p[i, 1] = ranges[i] * sin(angles[i])
    out = []
    for i in range(1, n + 1):
        if (i < n and ok[i] and ok[i - 1] and fabs(ranges[i] - ranges[i - 1])
                <= jump_m + jump_ratio * min(ranges[i], ranges[i - 1])):
            continue  # the cluster goes on
        if ok[i - 1] and i - start >= 2 * min_points:
            _corners_of_cluster(p, start, i - 1, tol, min_points, min_length, max_rms,
                                cos_max, max_gap, limit, max_beams_between, out)
        start = i
    return out


cdef _corners_of_cluster(const double[:, ::1] p, Py_ssize_t lo, Py_ssize_t hi, double tol,
                         Py_ssize_t min_points, double min_length, double max_rms,
                         double cos_max, double max_gap, double limit,
                         Py_ssize_t max_beams_between, list out):
    """Corners where two adjacent good straight runs of p[lo..hi] meet, appended to out."""
    runs = split_runs(p, lo, hi, tol)
    cdef Py_ssize_t m = len(runs), k, prev = -1, a, b, a2, b2
    cdef double f[5]
    cdef double g[5]
    cdef double den, t, cx, cy, side_c, side_o, ax, ay, bx, by
    cdef int t_i
    fits = np.zeros((m, 5))
    cdef double[:, ::1] fv = fits
    good = np.zeros(m, dtype=np.uint8)
    cdef u8[::1] gv = good
    for k in range(m):
        a, b = runs[k]
        if (b - a + 1 >= min_points
                and hypot(p[b, 0] - p[a, 0], p[b, 1] - p[a, 1]) >= min_length):
            line_fit(p, a, b, f)
            if f[4] <= max_rms:
                for t_i in range(5):
                    fv[k, t_i] = f[t_i]
                gv[k] = 1
    for k in range(m):
        if not gv[k]:
            continue
        if prev < 0:
            prev = k
            continue
        a, b = runs[prev]
        a2, b2 = runs[k]
        for t_i in range(5):
            f[t_i] = fv[prev, t_i]
            g[t_i] = fv[k, t_i]
        prev = k
        if a2 - b > max_beams_between:
            continue  # something else lies between the two sides
        if fabs(f[2] * g[2] + f[3] * g[3]) > cos_max:
            continue  # nearly collinear: not a real angle
        den = f[2] * g[3] - f[3] * g[2]
        if fabs(den) < 1e-9:
            continue
        t = ((g[0] - f[0]) * g[3] - (g[1] - f[1]) * g[2]) / den
        cx = f[0] + t * f[2]
        cy = f[1] + t * f[3]
        if (hypot(cx - p[b, 0], cy - p[b, 1]) > max_gap
                or hypot(cx - p[a2, 0], cy - p[a2, 1]) > max_gap or hypot(cx, cy) > limit):
            continue
        # convex iff the corner and the sensor (origin) lie on one side of the far ends' line
        ax, ay, bx, by = p[a, 0], p[a, 1], p[b2, 0], p[b2, 1]
        side_c = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        side_o = (bx - ax) * (0.0 - ay) - (by - ay) * (0.0 - ax)
        out.append((cx, cy, side_c * side_o > 0))
