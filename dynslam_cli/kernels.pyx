# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False
"""Compiled inner loops of the per-scan work (built by ``pip install``; see setup.py).

Each function here is a loop that numpy can only express with many small array operations
per scan (ICP's correspondences and normal equations, the corner detector's split-and-fit,
the cells a beam passes through). The algorithms, and their documentation, live in the
Python modules that call them: ``scanmatch``, ``corners``, ``grid``, ``dynamic``,
``loopclosure``. No fast-math: results are the same on every run. The long loops release
the GIL, so threads (a Dask worker's, say) can process several logs at once.
"""

import numpy as np

from libc.math cimport INFINITY, atan2, ceil, cos, fabs, floor, hypot, remainder, sin, sqrt
from libc.stdlib cimport calloc, free, malloc, realloc

ctypedef unsigned char u8


cdef class PointIndex:
    """2-D points in square buckets of side ``cell``, for nearest-point look-ups within a
    bound (fastest when the bound is about the cell size: 3×3 buckets are searched)."""

    cdef readonly object points
    cdef const double[:, ::1] pts
    cdef double cell, x0, y0
    cdef Py_ssize_t nx, ny
    cdef Py_ssize_t[::1] start
    cdef Py_ssize_t[::1] order
    cdef const double[:, ::1] by_bucket  # the points in bucket order: read in sequence

    def __init__(self, points, double cell=0.25):
        self.points = np.ascontiguousarray(points, dtype=np.float64)
        self.pts = self.points
        self.cell = cell
        cdef Py_ssize_t n = self.pts.shape[0], i, b
        if n == 0:
            self.x0 = self.y0 = 0.0
            self.nx = self.ny = 1
        else:
            self.x0 = float(np.min(self.points[:, 0]))
            self.y0 = float(np.min(self.points[:, 1]))
            self.nx = <Py_ssize_t>floor((np.max(self.points[:, 0]) - self.x0) / cell) + 1
            self.ny = <Py_ssize_t>floor((np.max(self.points[:, 1]) - self.y0) / cell) + 1
        bucket = np.empty(n, dtype=np.intp)
        cdef Py_ssize_t[::1] bk = bucket
        for i in range(n):
            bk[i] = self._bucket(self.pts[i, 0], self.pts[i, 1])
        counts = np.bincount(bucket, minlength=self.nx * self.ny)
        self.start = np.concatenate(([0], np.cumsum(counts))).astype(np.intp)
        self.order = np.argsort(bucket, kind="stable").astype(np.intp)
        self.by_bucket = np.ascontiguousarray(self.points[self.order])

    cdef inline Py_ssize_t _bucket(self, double x, double y) noexcept nogil:
        cdef Py_ssize_t ix = <Py_ssize_t>floor((x - self.x0) / self.cell)
        cdef Py_ssize_t iy = <Py_ssize_t>floor((y - self.y0) / self.cell)
        return iy * self.nx + ix

    cdef Py_ssize_t nearest(self, double x, double y, double bound) noexcept nogil:
        """Index of the nearest point closer than ``bound``, or -1 (ties: the lower index)."""
        cdef Py_ssize_t j
        cdef double d2
        return j if self._search(x, y, 1, bound * bound, &j, &d2) else -1

    cdef Py_ssize_t _search(self, double x, double y, Py_ssize_t k, double bound2,
                            Py_ssize_t* idx, double* d2s) noexcept nogil:
        """The (up to) k nearest points closer than sqrt(bound2), nearest first (ties: the
        lower index), into idx and d2s; returns how many. Searches rings of buckets around
        the query's until no unsearched bucket can hold a nearer point."""
        cdef double fx = (x - self.x0) / self.cell, fy = (y - self.y0) / self.cell
        cdef Py_ssize_t cx = <Py_ssize_t>floor(fx), cy = <Py_ssize_t>floor(fy)
        cdef Py_ssize_t r = 0, found = 0, ix, iy, b, q, j, m, step
        cdef double d2, dx, dy, reach, worst
        while True:
            for iy in range(max(cy - r, 0), min(cy + r + 1, self.ny)):
                # the ring's two ends in this row, or the whole row at its top and bottom
                step = 1 if iy == cy - r or iy == cy + r else max(2 * r, 1)
                ix = cx - r - step
                while ix + step <= cx + r:
                    ix += step
                    if ix < 0 or ix >= self.nx:
                        continue
                    b = iy * self.nx + ix
                    for q in range(self.start[b], self.start[b + 1]):
                        dx = self.by_bucket[q, 0] - x
                        dy = self.by_bucket[q, 1] - y
                        d2 = dx * dx + dy * dy
                        if d2 >= bound2 or (found == k and d2 > d2s[k - 1]):
                            continue
                        j = self.order[q]
                        if found == k and d2 == d2s[k - 1] and j > idx[k - 1]:
                            continue
                        m = found if found < k else k - 1  # insert, dropping the k-th
                        while m > 0 and (d2s[m - 1] > d2
                                         or (d2s[m - 1] == d2 and idx[m - 1] > j)):
                            d2s[m] = d2s[m - 1]
                            idx[m] = idx[m - 1]
                            m -= 1
                        d2s[m] = d2
                        idx[m] = j
                        if found < k:
                            found += 1
            reach = min(min(fx - (cx - r), cx + r + 1 - fx),
                        min(fy - (cy - r), cy + r + 1 - fy)) * self.cell
            worst = d2s[k - 1] if found == k else bound2
            if reach * reach >= worst:
                return found
            if cx - r <= 0 and cy - r <= 0 and cx + r >= self.nx - 1 and cy + r >= self.ny - 1:
                return found  # the whole grid is searched
            r += 1

    def normals(self, Py_ssize_t k):
        """Unit normal of every point: the direction of least spread of its k nearest
        points (itself included)."""
        cdef Py_ssize_t n = self.pts.shape[0], i, m, kk = min(k, n)
        out = np.zeros((n, 2))
        cdef double[:, ::1] o = out
        idx = np.empty(max(kk, 1), dtype=np.intp)
        dist = np.empty(max(kk, 1))
        cdef Py_ssize_t[::1] iv = idx
        cdef double[::1] dv = dist
        cdef double mx, my, sxx, syy, sxy, dx, dy, a
        for i in range(n):
            self._search(self.pts[i, 0], self.pts[i, 1], kk, INFINITY, &iv[0], &dv[0])
            mx = my = 0.0
            for m in range(kk):
                mx += self.pts[iv[m], 0]
                my += self.pts[iv[m], 1]
            mx /= kk
            my /= kk
            sxx = syy = sxy = 0.0
            for m in range(kk):
                dx = self.pts[iv[m], 0] - mx
                dy = self.pts[iv[m], 1] - my
                sxx += dx * dx
                syy += dy * dy
                sxy += dx * dy
            a = 0.5 * atan2(2.0 * sxy, sxx - syy) + 1.5707963267948966
            o[i, 0] = cos(a)
            o[i, 1] = sin(a)
        return out

    def query(self, points, double bound):
        """Nearest-point index of each query point (-1 where none is closer than bound)."""
        cdef const double[:, ::1] q = np.ascontiguousarray(points, dtype=np.float64)
        out = np.empty(q.shape[0], dtype=np.intp)
        cdef Py_ssize_t[::1] o = out
        cdef Py_ssize_t i
        for i in range(q.shape[0]):
            o[i] = self.nearest(q[i, 0], q[i, 1], bound)
        return out


cdef int solve3(double a[3][3], double b[3], double x[3]) noexcept nogil:
    """Gaussian elimination with partial pivoting; 0 if singular."""
    cdef int i, j, k, p
    cdef double m, t
    for i in range(3):
        p = i
        for k in range(i + 1, 3):
            if fabs(a[k][i]) > fabs(a[p][i]):
                p = k
        if a[p][i] == 0.0:
            return 0
        if p != i:
            for j in range(3):
                t = a[i][j]; a[i][j] = a[p][j]; a[p][j] = t
            t = b[i]; b[i] = b[p]; b[p] = t
        for k in range(i + 1, 3):
            m = a[k][i] / a[i][i]
            for j in range(i, 3):
                a[k][j] -= m * a[i][j]
            b[k] -= m * b[i]
    for i in range(2, -1, -1):
        t = b[i]
        for j in range(i + 1, 3):
            t -= a[i][j] * x[j]
        x[i] = t / a[i][i]
    return 1


def icp(PointIndex index, const double[:, ::1] normals, const double[:, ::1] pts,
        double gx, double gy, double gth, int iterations, double gate_max, double gate_min,
        double wx, double wy, double wth, double sigma):
    """Point-to-line ICP (see scanmatch.icp). Returns (x, y, θ, share, rms, ok, h): h is
    the Huber-weighted Σ J Jᵀ of the pairs of the last iteration (3×3, the prior left out)."""
    cdef double out[11]
    cdef bint ok
    with nogil:
        ok = _icp(index, normals, pts, gx, gy, gth, iterations, gate_max, gate_min, wx, wy,
                  wth, sigma, out)
    h = np.zeros((3, 3))
    if not ok:
        return gx, gy, gth, 0.0, INFINITY, False, h
    h[0, 0], h[0, 1], h[0, 2] = out[5], out[6], out[7]
    h[1, 1], h[1, 2], h[2, 2] = out[8], out[9], out[10]
    h[1, 0], h[2, 0], h[2, 1] = out[6], out[7], out[9]
    return out[0], out[1], out[2], out[3], out[4], True, h


cdef bint _icp(PointIndex index, const double[:, ::1] normals, const double[:, ::1] pts,
               double gx, double gy, double gth, int iterations, double gate_max,
               double gate_min, double wx, double wy, double wth, double sigma,
               double out[11]) noexcept nogil:
    cdef Py_ssize_t n = pts.shape[0], i, j, used
    cdef double x = gx, y = gy, th = gth, gate, c, s, px, py, nx, ny, r, w, dpx, dpy
    cdef double share = 0.0, rms = INFINITY, sq
    cdef double a[3][3]
    cdef double b[3]
    cdef double d[3]
    cdef double jac[3]
    cdef int it, p, q
    for it in range(iterations):
        gate = gate_max + (gate_min - gate_max) * it / max(iterations - 1, 1)
        c = cos(th)
        s = sin(th)
        for p in range(3):
            b[p] = 0.0
            for q in range(3):
                a[p][q] = 0.0
        used = 0
        sq = 0.0
        for i in range(n):
            px = x + c * pts[i, 0] - s * pts[i, 1]
            py = y + s * pts[i, 0] + c * pts[i, 1]
            j = index.nearest(px, py, gate)
            if j < 0:
                continue
            used += 1
            nx = normals[j, 0]
            ny = normals[j, 1]
            r = (px - index.pts[j, 0]) * nx + (py - index.pts[j, 1]) * ny
            dpx = -s * pts[i, 0] - c * pts[i, 1]
            dpy = c * pts[i, 0] - s * pts[i, 1]
            jac[0] = nx
            jac[1] = ny
            jac[2] = nx * dpx + ny * dpy
            w = 1.0 / max(1.0, fabs(r) / sigma)
            for p in range(3):
                b[p] += jac[p] * w * r
                for q in range(3):
                    a[p][q] += jac[p] * jac[q] * w
            sq += r * r
        share = used / <double>n if n else 0.0
        if used < 10:
            return False
        out[5] = a[0][0]
        out[6] = a[0][1]
        out[7] = a[0][2]
        out[8] = a[1][1]
        out[9] = a[1][2]
        out[10] = a[2][2]
        a[0][0] += wx + 1e-9
        a[1][1] += wy + 1e-9
        a[2][2] += wth + 1e-9
        b[0] += wx * (x - gx)
        b[1] += wy * (y - gy)
        b[2] += wth * remainder(th - gth, 2 * 3.141592653589793)
        if not solve3(a, b, d):
            return False
        x -= d[0]
        y -= d[1]
        th -= d[2]
        rms = sqrt(sq / used)
        if fabs(d[0]) + fabs(d[1]) < 1e-4 and fabs(d[2]) < 1e-5:
            break
    out[0] = x
    out[1] = y
    out[2] = remainder(th, 2 * 3.141592653589793)
    out[3] = share
    out[4] = rms
    return True


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


# -- correlative matching (loop closure) ----------------------------------------------------

def splat_max(double[:, ::1] grid, const Py_ssize_t[::1] rows, const Py_ssize_t[::1] cols,
              const double[:, ::1] kernel):
    """grid[r + i, c + j] = max(itself, kernel[i + h, j + h]) around every distinct (r, c),
    with h = kernel's half width (cells off the grid are skipped; (r, c) must be on it)."""
    cdef Py_ssize_t h = kernel.shape[0] // 2, n = rows.shape[0], k, i, j, r, c
    cdef Py_ssize_t nr = grid.shape[0], nc = grid.shape[1]
    done = np.zeros(nr * nc, dtype=np.uint8)
    cdef u8[::1] seen = done
    with nogil:
        for k in range(n):
            if seen[rows[k] * nc + cols[k]]:
                continue  # a repeat: the same splat again would change nothing
            seen[rows[k] * nc + cols[k]] = 1
            for i in range(max(-h, -rows[k]), min(h + 1, nr - rows[k])):
                r = rows[k] + i
                for j in range(max(-h, -cols[k]), min(h + 1, nc - cols[k])):
                    c = cols[k] + j
                    if kernel[i + h, j + h] > grid[r, c]:
                        grid[r, c] = kernel[i + h, j + h]


def mean_scores(const double[:, ::1] grid, double ox, double oy, double res,
                const double[:, ::1] pts, double x, double y, const double[::1] thetas,
                const Py_ssize_t[::1] tx, const Py_ssize_t[::1] ty):
    """Mean grid value of ``pts`` turned by each θ and moved to (x, y) plus (tx, ty) cells:
    shape len(thetas) × len(ty) × len(tx); points off the grid count 0. The grid's cell
    (0, 0) is centred on (ox, oy)."""
    cdef Py_ssize_t n = pts.shape[0], nx = tx.shape[0], ny = ty.shape[0], k, a, b, r, c, t
    cdef Py_ssize_t rows = grid.shape[0], cols = grid.shape[1], ix, iy
    cdef double ct, st, px, py
    out = np.zeros((thetas.shape[0], ny, nx))
    cdef double[:, :, ::1] o = out
    with nogil:
        for t in range(thetas.shape[0]):
            ct = cos(thetas[t])
            st = sin(thetas[t])
            for k in range(n):
                px = x + ct * pts[k, 0] - st * pts[k, 1]
                py = y + st * pts[k, 0] + ct * pts[k, 1]
                ix = <Py_ssize_t>floor((px - ox) / res + 0.5)
                iy = <Py_ssize_t>floor((py - oy) / res + 0.5)
                for a in range(ny):
                    r = iy + ty[a]
                    if r < 0 or r >= rows:
                        continue
                    for b in range(nx):
                        c = ix + tx[b]
                        if 0 <= c < cols:
                            o[t, a, b] += grid[r, c]
            if n:
                for a in range(ny):
                    for b in range(nx):
                        o[t, a, b] /= n
    return out


def end_points(const double[::1] ranges, const double[::1] angles, Py_ssize_t step,
               double x, double y, double theta, double lo, double hi):
    """End points (N×2) of every step-th beam whose range is in (lo, hi), seen from the pose
    (x, y, θ) of the sensor."""
    cdef Py_ssize_t n = ranges.shape[0], i, m = 0
    out = np.empty(((n + step - 1) // step, 2))
    cdef double[:, ::1] o = out
    cdef double r
    for i in range(0, n, step):
        r = ranges[i]
        if r > lo and r < hi:  # NaN fails both
            o[m, 0] = x + r * cos(angles[i] + theta)
            o[m, 1] = y + r * sin(angles[i] + theta)
            m += 1
    return out[:m].copy()


# -- pose graph: the sparse normal equations ------------------------------------------------
cdef void _heap_push(long long* heap, Py_ssize_t* size, long long key) noexcept nogil:
    cdef Py_ssize_t k = size[0], parent
    size[0] += 1
    while k > 0:
        parent = (k - 1) // 2
        if heap[parent] <= key:
            break
        heap[k] = heap[parent]
        k = parent
    heap[k] = key


cdef long long _heap_pop(long long* heap, Py_ssize_t* size) noexcept nogil:
    cdef long long top = heap[0], last
    cdef Py_ssize_t k = 0, child, n
    size[0] -= 1
    n = size[0]
    last = heap[n]
    while True:
        child = 2 * k + 1
        if child >= n:
            break
        if child + 1 < n and heap[child + 1] < heap[child]:
            child += 1
        if heap[child] >= last:
            break
        heap[k] = heap[child]
        k = child
    heap[k] = last
    return top


cdef Py_ssize_t _keep_unmarked(Py_ssize_t* row, Py_ssize_t length, int* mark,
                               int stamp) noexcept nogil:
    """Keep, in order and in place, the entries of row[:length] not marked ``stamp`` yet
    (marking them, so repeats go too); returns how many are kept."""
    cdef Py_ssize_t p, kept = 0, w
    for p in range(length):
        w = row[p]
        if mark[w] != stamp:
            mark[w] = stamp
            row[kept] = w
            kept += 1
    return kept


def minimum_degree(Py_ssize_t n, const Py_ssize_t[::1] ei, const Py_ssize_t[::1] ej):
    """An ordering of the n nodes of the graph with edges (ei[k], ej[k]) for a Cholesky
    factorization that fills in little: repeatedly the node of least degree (ties: the lower
    index) is eliminated, its neighbours becoming neighbours of each other (exact minimum
    degree on the elimination graph, George & Liu 1989)."""
    cdef Py_ssize_t m = ei.shape[0], k, a, b, v, u, w, p, q, step, hsize = 0, hcap
    cdef Py_ssize_t dv, du
    cdef long long key
    cdef int stamp = 0
    deg_arr = np.zeros(n, dtype=np.intp)
    cap_arr = np.zeros(n, dtype=np.intp)
    mark_arr = np.zeros(n, dtype=np.intc)
    done_arr = np.zeros(n, dtype=np.uint8)
    order_arr = np.empty(n, dtype=np.intp)
    cdef Py_ssize_t[::1] deg = deg_arr, cap = cap_arr, order = order_arr
    cdef int[::1] mark = mark_arr
    cdef u8[::1] done = done_arr
    cdef Py_ssize_t** adj = <Py_ssize_t**>calloc(n, sizeof(Py_ssize_t*))
    cdef Py_ssize_t* grown
    hcap = 2 * m + 2 * n + 1
    cdef long long* heap = <long long*>malloc(hcap * sizeof(long long))
    cdef long long* bigger
    if adj == NULL or heap == NULL:
        free(adj)
        free(heap)
        raise MemoryError()
    try:
        for k in range(m):  # room for every listed neighbour (duplicates dropped below)
            if ei[k] != ej[k]:
                cap[ei[k]] += 1
                cap[ej[k]] += 1
        for a in range(n):
            cap[a] = max(cap[a], 4)
            adj[a] = <Py_ssize_t*>malloc(cap[a] * sizeof(Py_ssize_t))
            if adj[a] == NULL:
                raise MemoryError()
        for k in range(m):
            a, b = ei[k], ej[k]
            if a != b:
                adj[a][deg[a]] = b
                deg[a] += 1
                adj[b][deg[b]] = a
                deg[b] += 1
        for a in range(n):  # drop repeated edges
            stamp += 1
            mark[a] = stamp
            deg[a] = _keep_unmarked(adj[a], deg[a], &mark[0], stamp)
            _heap_push(heap, &hsize, deg[a] * n + a)
        for step in range(n):
            while True:  # the least degree still current (stale entries are skipped)
                key = _heap_pop(heap, &hsize)
                v = key % n
                if not done[v] and key == deg[v] * n + v:
                    break
            done[v] = 1
            order[step] = v
            dv = deg[v]
            for p in range(dv):  # each neighbour u: adj(u) ∪ adj(v) less u and v
                u = adj[v][p]
                stamp += 1
                mark[u] = stamp
                mark[v] = stamp
                du = _keep_unmarked(adj[u], deg[u], &mark[0], stamp)
                for q in range(dv):
                    w = adj[v][q]
                    if mark[w] != stamp:
                        mark[w] = stamp
                        if du == cap[u]:
                            cap[u] *= 2
                            grown = <Py_ssize_t*>realloc(adj[u], cap[u] * sizeof(Py_ssize_t))
                            if grown == NULL:
                                raise MemoryError()
                            adj[u] = grown
                        adj[u][du] = w
                        du += 1
                deg[u] = du
                if hsize == hcap:
                    hcap *= 2
                    bigger = <long long*>realloc(heap, hcap * sizeof(long long))
                    if bigger == NULL:
                        raise MemoryError()
                    heap = bigger
                _heap_push(heap, &hsize, du * n + u)
            free(adj[v])
            adj[v] = NULL
    finally:
        for a in range(n):
            free(adj[a])
        free(adj)
        free(heap)
    return order_arr


def solve_spd(const Py_ssize_t[::1] indptr, const Py_ssize_t[::1] indices,
              const double[::1] data, const Py_ssize_t[::1] perm, const double[::1] rhs):
    """x with A x = rhs, A symmetric positive definite, given in compressed columns (both
    triangles; duplicate entries are summed), by the LDLᵀ factorization of A with rows and
    columns in the order ``perm`` (Davis's up-looking algorithm, "Algorithm 849", 2005).
    Raises ValueError if a pivot is not positive."""
    cdef Py_ssize_t n = rhs.shape[0], k, kk, p, i, top, ln, p2
    cdef double yi, l_ki
    pinv_arr = np.empty(n, dtype=np.intp)
    parent_arr = np.empty(n, dtype=np.intp)
    flag_arr = np.empty(n, dtype=np.intp)
    lnz_arr = np.zeros(n, dtype=np.intp)
    lp_arr = np.zeros(n + 1, dtype=np.intp)
    cdef Py_ssize_t[::1] pinv = pinv_arr, parent = parent_arr, flag = flag_arr
    cdef Py_ssize_t[::1] lnz = lnz_arr, lp = lp_arr
    for k in range(n):
        pinv[perm[k]] = k
    for k in range(n):  # symbolic: the elimination tree and each column's count
        parent[k] = -1
        flag[k] = k
        kk = perm[k]
        for p in range(indptr[kk], indptr[kk + 1]):
            i = pinv[indices[p]]
            while i < k and flag[i] != k:
                if parent[i] == -1:
                    parent[i] = k
                lnz[i] += 1
                flag[i] = k
                i = parent[i]
    for k in range(n):
        lp[k + 1] = lp[k] + lnz[k]
    li_arr = np.empty(lp[n], dtype=np.intp)
    lx_arr = np.empty(lp[n], dtype=np.float64)
    d_arr = np.empty(n, dtype=np.float64)
    y_arr = np.zeros(n, dtype=np.float64)
    pattern_arr = np.empty(n, dtype=np.intp)
    cdef Py_ssize_t[::1] li = li_arr, pattern = pattern_arr
    cdef double[::1] lx = lx_arr, d = d_arr, y = y_arr
    for k in range(n):  # numeric: row k of L from the rows above it
        top = n
        flag[k] = k
        lnz[k] = 0
        kk = perm[k]
        for p in range(indptr[kk], indptr[kk + 1]):
            i = pinv[indices[p]]
            if i > k:
                continue
            y[i] += data[p]
            ln = 0
            while flag[i] != k:
                pattern[ln] = i
                ln += 1
                flag[i] = k
                i = parent[i]
            while ln > 0:
                top -= 1
                ln -= 1
                pattern[top] = pattern[ln]
        d[k] = y[k]
        y[k] = 0.0
        while top < n:
            i = pattern[top]
            top += 1
            yi = y[i]
            y[i] = 0.0
            p2 = lp[i] + lnz[i]
            for p in range(lp[i], p2):
                y[li[p]] -= lx[p] * yi
            l_ki = yi / d[i]
            d[k] -= l_ki * yi
            li[p2] = k
            lx[p2] = l_ki
            lnz[i] += 1
        if not d[k] > 0.0:
            raise ValueError("the matrix is not positive definite")
    x_arr = np.empty(n, dtype=np.float64)
    cdef double[::1] x = x_arr
    for k in range(n):
        y[k] = rhs[perm[k]]
    for k in range(n):  # L z = P b
        for p in range(lp[k], lp[k + 1]):
            y[li[p]] -= lx[p] * y[k]
    for k in range(n):
        y[k] /= d[k]
    for k in range(n - 1, -1, -1):  # Lᵀ w = D⁻¹ z
        for p in range(lp[k], lp[k + 1]):
            y[k] -= lx[p] * y[li[p]]
    for k in range(n):
        x[perm[k]] = y[k]
    return x_arr
