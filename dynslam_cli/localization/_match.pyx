# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False
"""The scan matcher's inner loops: a bucket index of 2-D points (nearest and k nearest),
point-to-line ICP over it, and the end points of a scan's beams.

Compiled by ``pip install`` (setup.py); the algorithm and its documentation live in
``dynslam_cli.localization.scanmatch``. No fast-math: results are the same on every run. The long loops release the
GIL, so threads (a Dask worker's, say) can process several logs at once.
"""

import numpy as np

from libc.math cimport INFINITY, atan2, ceil, cos, exp, fabs, floor, hypot, remainder, sin, sqrt
from libc.stdlib cimport calloc, free, malloc, realloc

from dynslam_cli.localization._linalg cimport add_prior, solve3

ctypedef unsigned char u8


MAX_BUCKETS_PER_SIDE = 1024
cdef enum:
    MAX_NEIGHBOURS = 64  # a normal's points, at most
    MIN_NORMAL_POINTS = 3  # ... and at least (fewer: no normal)


cdef class PointIndex:
    """2-D points in square buckets of side ``cell``, for nearest-point look-ups within a
    bound (fastest when the bound is about the cell size: 3×3 buckets are searched); and
    each point's normal from its ``neighbours`` nearest (at most 64) this side of a gap (a
    neighbour more than ``gap`` times as far as the one before it lies across empty space
    from the rest), computed when first asked for (ICP asks for those of the points it
    pairs with: a few hundred of a local map's thousands) and kept. A point with fewer than
    MIN_NORMAL_POINTS so near (itself included: a lone point, a short stub seen from afar)
    has no surface to be a line of: its normal is (0, 0)."""

    cdef readonly object points
    cdef const double[:, ::1] pts
    cdef double cell, x0, y0
    cdef Py_ssize_t nx, ny
    cdef Py_ssize_t[::1] start
    cdef Py_ssize_t[::1] order
    cdef const double[:, ::1] by_bucket  # the points in bucket order: read in sequence
    cdef Py_ssize_t neighbours
    cdef double gap2
    cdef double[:, ::1] nrm  # each point's normal, where ...
    cdef double[::1] thick  # ... and its neighbours' spread along it (variance, m²) ...
    cdef u8[::1] has_nrm  # ... computed
    cdef double[::1] t_lo  # how far its neighbours reach along its line, each way (m) ...
    cdef double[::1] t_hi
    cdef u8[::1] has_ext  # ... computed (ICP with ``segments`` alone asks)

    def __init__(self, points, double cell=0.25, Py_ssize_t neighbours=6,
                 double gap=INFINITY):
        self.points = np.ascontiguousarray(points, dtype=np.float64)
        self.pts = self.points
        self.cell = cell
        cdef Py_ssize_t n = self.pts.shape[0], i, b
        if not 1 <= neighbours <= MAX_NEIGHBOURS:
            raise ValueError(f"neighbours must be 1-{MAX_NEIGHBOURS}, not {neighbours}")
        self.neighbours = min(neighbours, n)
        self.gap2 = gap * gap
        self.nrm = np.zeros((n, 2))
        self.thick = np.zeros(n)
        self.t_lo = np.zeros(n)
        self.t_hi = np.zeros(n)
        self.has_nrm = np.zeros(n, dtype=np.uint8)
        self.has_ext = np.zeros(n, dtype=np.uint8)
        if n == 0:
            self.x0 = self.y0 = 0.0
            self.nx = self.ny = 1
        else:
            self.x0 = float(np.min(self.points[:, 0]))
            self.y0 = float(np.min(self.points[:, 1]))
            # At most MAX_BUCKETS_PER_SIDE buckets a side, whatever the points' spread (a
            # log's odometry jump): the answers do not depend on the bucket size, and the
            # buckets' memory and a search's rings stay bounded.
            spread = max(np.max(self.points[:, 0]) - self.x0, np.max(self.points[:, 1]) - self.y0)
            self.cell = cell = max(cell, spread / MAX_BUCKETS_PER_SIDE)
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

    def normals(self):
        """Unit normal of every point (N×2)."""
        cdef Py_ssize_t i
        for i in range(self.pts.shape[0]):
            self._normal(i)
        return np.asarray(self.nrm).copy()

    cdef void _normal(self, Py_ssize_t i) noexcept nogil:
        """Point i's unit normal into nrm[i], unless it is there: the direction of least
        spread of its ``neighbours`` nearest points this side of a gap (itself included);
        (0, 0) where they are fewer than MIN_NORMAL_POINTS."""
        if self.has_nrm[i]:
            return
        cdef Py_ssize_t iv[MAX_NEIGHBOURS]
        cdef Py_ssize_t m, kk
        cdef double mx, my, sxx, syy, sxy, dx, dy, a
        self.has_nrm[i] = 1
        kk = self._neighbours(i, iv)
        if kk < MIN_NORMAL_POINTS:
            self.nrm[i, 0] = 0.0
            self.nrm[i, 1] = 0.0
            return
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
        self.nrm[i, 0] = cos(a)
        self.nrm[i, 1] = sin(a)
        self.thick[i] = (sxx * self.nrm[i, 0] * self.nrm[i, 0]
                         + 2.0 * sxy * self.nrm[i, 0] * self.nrm[i, 1]
                         + syy * self.nrm[i, 1] * self.nrm[i, 1]) / kk

    cdef Py_ssize_t _neighbours(self, Py_ssize_t i, Py_ssize_t* iv) noexcept nogil:
        """Point i's ``neighbours`` nearest points this side of a gap, itself first, into
        iv: how many."""
        cdef double dv[MAX_NEIGHBOURS]
        cdef Py_ssize_t kk = self._search(self.pts[i, 0], self.pts[i, 1], self.neighbours,
                                          INFINITY, iv, dv)
        cdef Py_ssize_t m = 2  # (0: the point itself; 1: its nearest, always taken)
        while m < kk and (dv[m] <= self.gap2 * dv[m - 1] or dv[m - 1] == 0.0):
            m += 1
        return min(kk, m)

    cdef void _extent(self, Py_ssize_t i) noexcept nogil:
        """How far point i's normal's neighbours reach along its line (the tangent (-ny,
        nx)), each way from it, into t_lo[i] and t_hi[i], unless they are there: asked by
        ICP with ``segments`` alone (after the normal)."""
        if self.has_ext[i]:
            return
        cdef Py_ssize_t iv[MAX_NEIGHBOURS]
        cdef Py_ssize_t m, kk
        cdef double a
        self.has_ext[i] = 1
        kk = self._neighbours(i, iv)
        for m in range(kk):  # (the point itself at 0)
            a = ((self.pts[iv[m], 1] - self.pts[i, 1]) * self.nrm[i, 0]
                 - (self.pts[iv[m], 0] - self.pts[i, 0]) * self.nrm[i, 1])
            self.t_lo[i] = min(self.t_lo[i], a)
            self.t_hi[i] = max(self.t_hi[i], a)

    def query(self, points, double bound):
        """Nearest-point index of each query point (-1 where none is closer than bound)."""
        cdef const double[:, ::1] q = np.ascontiguousarray(points, dtype=np.float64)
        out = np.empty(q.shape[0], dtype=np.intp)
        cdef Py_ssize_t[::1] o = out
        cdef Py_ssize_t i
        for i in range(q.shape[0]):
            o[i] = self.nearest(q[i, 0], q[i, 1], bound)
        return out


def icp(PointIndex index, const double[:, ::1] pts, double gx, double gy, double gth,
        int iterations, double gate_max, double gate_min, double wx, double wy, double wth,
        double sigma, double step_m, double step_rad, bint thickness=False,
        bint segments=False):
    """Point-to-line ICP (see scanmatch.icp): the gate shrinks over the iterations; converged
    (a step of under step_m in |x| + |y| and step_rad in θ) at a wider gate, it goes on at
    the narrowest until converged there (the answer is then the narrow gate's, outliers
    left out). Returns (x, y, θ, share, rms, ok, h): h is the Huber-weighted Σ J Jᵀ of the
    pairs of the last iteration (3×3, the prior left out). The reference points' normals
    are the index's. With ``segments`` a point pairs only where it falls beside its
    reference point's line as far as that point's neighbours reach (point to segment), not
    on the line's extension past its last point."""
    cdef double out[11]
    cdef bint ok
    with nogil:
        ok = _icp(index, pts, gx, gy, gth, iterations, gate_max, gate_min, wx, wy,
                  wth, sigma, step_m, step_rad, thickness, segments, out)
    h = np.zeros((3, 3))
    if not ok:
        return gx, gy, gth, 0.0, INFINITY, False, h
    h[0, 0], h[0, 1], h[0, 2] = out[5], out[6], out[7]
    h[1, 1], h[1, 2], h[2, 2] = out[8], out[9], out[10]
    h[1, 0], h[2, 0], h[2, 1] = out[6], out[7], out[9]
    return out[0], out[1], out[2], out[3], out[4], True, h


cdef bint _icp(PointIndex index, const double[:, ::1] pts, double gx, double gy,
               double gth, int iterations, double gate_max, double gate_min, double wx,
               double wy, double wth, double sigma, double step_m, double step_rad,
               bint thickness, bint segments, double out[11]) noexcept nogil:
    cdef Py_ssize_t n = pts.shape[0], i, j, used
    cdef double x = gx, y = gy, th = gth, gate, c, s, px, py, nx, ny, r, w, dpx, dpy, t
    cdef double share = 0.0, rms = INFINITY, sq
    cdef double a[3][3]
    cdef double b[3]
    cdef double d[3]
    cdef double jac[3]
    cdef int it, p, q
    cdef bint narrow = False  # converged at a wider gate: on at the narrowest
    for it in range(iterations):
        gate = gate_min if narrow else (
            gate_max + (gate_min - gate_max) * it / max(iterations - 1, 1))
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
            index._normal(j)
            nx = index.nrm[j, 0]
            ny = index.nrm[j, 1]
            if nx == 0.0 and ny == 0.0:  # (a point on no line: no pair)
                continue
            if segments:  # (beyond the line's last point: no pair)
                index._extent(j)
                t = (py - index.pts[j, 1]) * nx - (px - index.pts[j, 0]) * ny
                if t < index.t_lo[j] or t > index.t_hi[j]:
                    continue
            used += 1
            r = (px - index.pts[j, 0]) * nx + (py - index.pts[j, 1]) * ny
            dpx = -s * pts[i, 0] - c * pts[i, 1]
            dpy = c * pts[i, 0] - s * pts[i, 1]
            jac[0] = nx
            jac[1] = ny
            jac[2] = nx * dpx + ny * dpy
            w = 1.0 / max(1.0, fabs(r) / sigma)
            if thickness:  # (a line its neighbours do not lie on tells less: GICP's way)
                w *= sigma * sigma / (sigma * sigma + index.thick[j])
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
        add_prior(a, b, x - gx, y - gy, th - gth, wx, wy, wth)
        if not solve3(a, b, d):
            return False
        x -= d[0]
        y -= d[1]
        th -= d[2]
        rms = sqrt(sq / used)
        if fabs(d[0]) + fabs(d[1]) < step_m and fabs(d[2]) < step_rad:
            if gate <= gate_min:  # (always so once narrow)
                break
            narrow = True
    out[0] = x
    out[1] = y
    out[2] = remainder(th, 2 * 3.141592653589793)
    out[3] = share
    out[4] = rms
    return True



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


def cell_groups(const double[:, ::1] pts, double cell):
    """Each point's square among the ``cell`` squares the points fall in, numbered in order
    of each square's first point (n indices), and each square's first point (increasing):
    the square of a point being (floor(x / cell), floor(y / cell)) packed into one 64-bit
    key as ``(cx << 32) ^ (cy & 0xFFFFFFFF)``, found with a hash table in one pass instead
    of a sort."""
    cdef Py_ssize_t n = pts.shape[0], i, size = 16, slot, squares = 0
    cdef long long key, low = 0xFFFFFFFF
    cdef unsigned long long h, golden = 0x9E3779B97F4A7C15ULL  # Fibonacci hashing
    while size < 2 * n:
        size *= 2
    cdef int shift = 64
    cdef Py_ssize_t s = size
    while s > 1:
        s //= 2
        shift -= 1
    keys_arr = np.zeros(size, dtype=np.int64)
    square_arr = np.full(size, -1, dtype=np.intp)
    group_arr = np.empty(n, dtype=np.intp)
    first_arr = np.empty(n, dtype=np.intp)
    cdef long long[::1] keys = keys_arr
    cdef Py_ssize_t[::1] square = square_arr
    cdef Py_ssize_t[::1] group = group_arr
    cdef Py_ssize_t[::1] first = first_arr
    with nogil:
        for i in range(n):
            key = ((<long long>floor(pts[i, 0] / cell)) << 32) ^ (
                (<long long>floor(pts[i, 1] / cell)) & low)
            h = (<unsigned long long>key) * golden
            slot = <Py_ssize_t>(h >> shift)
            while square[slot] >= 0 and keys[slot] != key:
                slot = (slot + 1) & (size - 1)
            if square[slot] < 0:
                square[slot] = squares
                keys[slot] = key
                first[squares] = i
                squares += 1
            group[i] = square[slot]
    return group_arr, first_arr[:squares]


def first_in_cells(const double[:, ::1] pts, double cell):
    """Indices (increasing) of the first point in each ``cell`` square
    (:func:`cell_groups`): the points ``np.unique`` of the squares' keys would keep."""
    return cell_groups(pts, cell)[1]


def seen_through_counts(const double[:, ::1] pts, const double[::1] xs, const double[::1] ys,
                        const double[::1] headings, const double[:, ::1] nearest,
                        const double[::1] reach, const u8[::1] rear_blind,
                        double offset, double bin_rad, double margin):
    """For each point, how many of the range views (at ``xs``, ``ys`` facing ``headings``,
    each with its per-bin ``nearest`` ranges) saw more than ``margin`` beyond it: the bin of
    bearing b (from the view's heading) being floor((b + offset) / bin_rad) modulo the bin
    count, as scanmatch.bearing_bins has it. A point farther from a view than its
    ``reach``, or, where the view is ``rear_blind``, more than a microradian behind it, is
    skipped before its bearing is taken (scanmatch.ViewStack says why that is exact)."""
    cdef Py_ssize_t n = pts.shape[0], v_count = xs.shape[0], bins = nearest.shape[1], i, v
    cdef long long k
    cdef double dx, dy, d2, ahead, ch, sh, r2
    counts_arr = np.zeros(n, dtype=np.intp)
    cdef Py_ssize_t[::1] counts = counts_arr
    with nogil:
        for v in range(v_count):
            if reach[v] <= 0.0:
                continue
            r2 = reach[v] * reach[v]
            ch, sh = cos(headings[v]), sin(headings[v])
            for i in range(n):
                dx = pts[i, 0] - xs[v]
                dy = pts[i, 1] - ys[v]
                d2 = dx * dx + dy * dy
                ahead = dx * ch + dy * sh
                if d2 > r2 or (rear_blind[v] and ahead < 0.0 and ahead * ahead > 1e-12 * d2):
                    continue
                k = <long long>floor((atan2(dy, dx) - headings[v] + offset) / bin_rad) % bins
                if k < 0:
                    k += bins
                if hypot(dx, dy) < nearest[v, k] - margin:
                    counts[i] += 1
    return counts_arr


cdef enum:
    SURFACE_NEIGHBOURS = 32  # reference points that shape the surface at an end point, at most
cdef double EDGE_WEIGHT = 0.05  # added to an end point's weights' sum: its pull fades as they do


cdef void _surface_terms(PointIndex index, const double[:, ::1] pts, double x, double y,
                         double th, double radius, double sigma, double a[3][3],
                         double b[3], Py_ssize_t* used) noexcept nogil:
    """At pose (x, y, θ): each end point's distances to its reference points' tangent lines
    within ``radius``, weighed by (1 − d²/radius²)² of its distance d to each (a weight that
    fades to nothing, its slope too, where a point leaves the circle) over their sum plus
    EDGE_WEIGHT, and by Huber's rule at ``sigma``: into a and b the normal equations Σ w J Jᵀ and Σ w J r, J the line distance's gradient
    in (x, y, θ); into used how many end points have a reference point within reach."""
    cdef Py_ssize_t n = pts.shape[0], i, m, k, j, p, q
    cdef Py_ssize_t iv[SURFACE_NEIGHBOURS]
    cdef double dv[SURFACE_NEIGHBOURS]
    cdef double wv[SURFACE_NEIGHBOURS]
    cdef double rv[SURFACE_NEIGHBOURS]
    cdef double c = cos(th), s = sin(th), px, py, dpx, dpy, r2 = radius * radius, total
    cdef double s2 = sigma * sigma
    cdef double nx, ny, r, w, jac[3]
    for p in range(3):
        b[p] = 0.0
        for q in range(3):
            a[p][q] = 0.0
    used[0] = 0
    for i in range(n):
        px = x + c * pts[i, 0] - s * pts[i, 1]
        py = y + s * pts[i, 0] + c * pts[i, 1]
        k = index._search(px, py, SURFACE_NEIGHBOURS, r2, iv, dv)
        total = EDGE_WEIGHT
        for m in range(k):
            j = iv[m]
            index._normal(j)
            if index.nrm[j, 0] == 0.0 and index.nrm[j, 1] == 0.0:
                wv[m] = 0.0  # (a point on no line)
                continue
            rv[m] = ((px - index.pts[j, 0]) * index.nrm[j, 0]
                     + (py - index.pts[j, 1]) * index.nrm[j, 1])
            wv[m] = (1.0 - dv[m] / r2) * (1.0 - dv[m] / r2) * exp(-0.5 * rv[m] * rv[m] / s2)
            total += wv[m]
        if total <= EDGE_WEIGHT:
            continue
        used[0] += 1
        dpx = -s * pts[i, 0] - c * pts[i, 1]
        dpy = c * pts[i, 0] - s * pts[i, 1]
        for m in range(k):
            if wv[m] == 0.0:
                continue
            j = iv[m]
            nx = index.nrm[j, 0]
            ny = index.nrm[j, 1]
            r = rv[m]
            w = wv[m] / total
            if fabs(r) > sigma:
                w *= sigma / fabs(r)
            jac[0] = nx
            jac[1] = ny
            jac[2] = nx * dpx + ny * dpy
            for p in range(3):
                b[p] += jac[p] * w * r
                for q in range(3):
                    a[p][q] += jac[p] * jac[q] * w


def surface_fit(PointIndex index, const double[:, ::1] pts, double sx, double sy, double sth,
                double gx, double gy, double gth, double wx, double wy, double wth,
                double radius, double sigma, int iterations, double step_m,
                double step_rad):
    """The pose, from (sx, sy, sθ), where the end points ``pts`` lie best on the reference
    points' smooth surface (each end point's Huber-weighed distances to the tangent lines
    of its reference points within ``radius``, weighed so that they fade in and out
    smoothly: :func:`_surface_terms`), with a prior ½ (wx Δx² + wy Δy² + wθ Δθ²)
    about (gx, gy, gθ): Gauss-Newton steps on the weights of the pose before (iteratively
    reweighted least squares) until a step moves it less than ``step_m`` (|x| + |y|) and
    ``step_rad``, or ``iterations`` steps. No pairing switches as the pose moves, so the
    answer moves as little as the end points do. Returns (x, y, θ, ok): ok False (and the
    start) where fewer than ten end points reach the surface."""
    cdef double x = sx, y = sy, th = sth
    cdef double a[3][3]
    cdef double b[3]
    cdef double d[3]
    cdef Py_ssize_t used = 0
    cdef int it
    cdef bint ok = True
    with nogil:
        for it in range(iterations):
            _surface_terms(index, pts, x, y, th, radius, sigma, a, b, &used)
            if used < 10:
                ok = False
                break
            add_prior(a, b, x - gx, y - gy, th - gth, wx, wy, wth)
            if not solve3(a, b, d):
                ok = False
                break
            x -= d[0]
            y -= d[1]
            th -= d[2]
            if fabs(d[0]) + fabs(d[1]) < step_m and fabs(d[2]) < step_rad:
                break
    if not ok:
        return sx, sy, sth, False
    return x, y, remainder(th, 2 * 3.141592653589793), True
