# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False
"""Loop closure's inner loops: the likelihood field's splat and the correlative
search's scores.

Compiled by ``pip install`` (setup.py); the algorithm and its documentation live in
``dynslam_cli.localization.loops``. No fast-math: results are the same on every run. The long loops release the
GIL, so threads (a Dask worker's, say) can process several logs at once.
"""

import numpy as np

from libc.math cimport (INFINITY, atan2, ceil, cos, exp, fabs, floor, hypot, log1p, remainder,
                        sin, sqrt)
from libc.stdlib cimport calloc, free, malloc, realloc

from dynslam_cli.localization._linalg cimport add_prior, solve3

ctypedef unsigned char u8


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


def splat_gaussians(double[:, ::1] grid, const double[:, ::1] pts, double ox, double oy,
                    double res, double sigma, Py_ssize_t reach, double scale):
    """grid[r, c] = max(itself, log(1 + scale·exp(−d²/2σ²))) for every point within
    ``reach`` cells of cell (r, c), d the distance from the point (not its cell) to the
    cell's centre: a point moved by less than a cell moves the table by as little. Cell
    (0, 0) is centred on (ox, oy); cells off the grid are skipped."""
    cdef Py_ssize_t n = pts.shape[0], nr = grid.shape[0], nc = grid.shape[1], k, r, c, r0, c0
    cdef double fx, fy, d, v, ey, inv = 0.5 / (sigma * sigma)
    # the Gaussian is separable: exp(-(dx² + dy²)/2σ²) = exp(-dx²/2σ²) exp(-dy²/2σ²), one
    # exp per row and per column of a point's square instead of one per cell
    ex_arr = np.empty(2 * max(reach, 0) + 1)
    cdef double[::1] ex = ex_arr
    with nogil:
        for k in range(n):
            fx = (pts[k, 0] - ox) / res
            fy = (pts[k, 1] - oy) / res
            c0 = <Py_ssize_t>floor(fx + 0.5)
            r0 = <Py_ssize_t>floor(fy + 0.5)
            for c in range(max(c0 - reach, 0), min(c0 + reach + 1, nc)):
                d = (c - fx) * res
                ex[c - c0 + reach] = exp(-d * d * inv)
            for r in range(max(r0 - reach, 0), min(r0 + reach + 1, nr)):
                d = (r - fy) * res
                ey = scale * exp(-d * d * inv)
                for c in range(max(c0 - reach, 0), min(c0 + reach + 1, nc)):
                    v = log1p(ey * ex[c - c0 + reach])
                    if v > grid[r, c]:
                        grid[r, c] = v


def lattice_scores(const float[:, ::1] grid, const Py_ssize_t[:, ::1] dr,
                   const Py_ssize_t[:, ::1] dc, const Py_ssize_t[::1] th,
                   const Py_ssize_t[::1] col, const Py_ssize_t[::1] row):
    """Mean grid value at the cells (row[i] + dr[th[i], k], col[i] + dc[th[i], k]) over k,
    for each candidate i (the global search's lattice); cells off the grid count 0."""
    cdef Py_ssize_t n = th.shape[0], m = dr.shape[1], i, k, r, c, t
    cdef Py_ssize_t rows = grid.shape[0], cols = grid.shape[1]
    cdef double acc
    out = np.zeros(n)
    cdef double[::1] o = out
    if m == 0:
        return out
    with nogil:
        for i in range(n):
            t = th[i]
            acc = 0.0
            for k in range(m):
                r = row[i] + dr[t, k]
                c = col[i] + dc[t, k]
                if 0 <= r < rows and 0 <= c < cols:
                    acc = acc + grid[r, c]
            o[i] = acc / m
    return out


def spline_mean(const double[:, ::1] coef, const double[:, ::1] pts, double x, double y,
                double theta, double ox, double oy, double res):
    """The mean, over the points ``pts`` (N×2) placed at pose (x, y, θ), of the cubic
    B-spline whose coefficients are ``coef`` (cell (0, 0) centred on (ox, oy); coefficients
    off the grid are 0), and its gradient in (x, y, θ): (mean, d/dx, d/dy, d/dθ)."""
    cdef Py_ssize_t n = pts.shape[0], k
    cdef double ct = cos(theta), st = sin(theta), px, py
    cdef double acc = 0.0, gx = 0.0, gy = 0.0, gt = 0.0
    cdef double at[6]
    if n == 0:
        return 0.0, 0.0, 0.0, 0.0
    with nogil:
        for k in range(n):
            px = x + ct * pts[k, 0] - st * pts[k, 1]
            py = y + st * pts[k, 0] + ct * pts[k, 1]
            _spline_at(coef, (px - ox) / res, (py - oy) / res, False, at)
            acc = acc + at[0]
            gx = gx + at[1]
            gy = gy + at[2]
            gt = gt + (-(py - y) * at[1] + (px - x) * at[2])
    return acc / n, gx / (n * res), gy / (n * res), gt / (n * res)


cdef inline void _spline_at(const double[:, ::1] coef, double u, double v, bint curvature,
                            double* at) noexcept nogil:
    """The cubic B-spline of ``coef`` at (u, v) (cells: column, row) into at[0], its
    derivatives in u and v into at[1], at[2], and with ``curvature`` its second derivatives
    (uu, uv, vv) into at[3:6]; coefficients off the grid count 0."""
    cdef Py_ssize_t nr = coef.shape[0], nc = coef.shape[1], i, j
    cdef Py_ssize_t c = <Py_ssize_t>floor(u), r = <Py_ssize_t>floor(v)
    cdef double w
    cdef double wu[4]
    cdef double wv[4]
    cdef double du[4]
    cdef double dv[4]
    cdef double su[4]
    cdef double sv[4]
    _bspline3(u - c, wu, du)
    _bspline3(v - r, wv, dv)
    if curvature:
        _bspline3_curvature(u - c, su)
        _bspline3_curvature(v - r, sv)
    for i in range(6):
        at[i] = 0.0
    for i in range(4):
        if 0 <= r - 1 + i < nr:
            for j in range(4):
                if 0 <= c - 1 + j < nc:
                    w = coef[r - 1 + i, c - 1 + j]
                    at[0] = at[0] + w * wv[i] * wu[j]
                    at[1] = at[1] + w * wv[i] * du[j]
                    at[2] = at[2] + w * dv[i] * wu[j]
                    if curvature:
                        at[3] += w * wv[i] * su[j]
                        at[4] += w * dv[i] * du[j]
                        at[5] += w * sv[i] * wu[j]


cdef inline void _bspline3(double t, double* w, double* d) noexcept nogil:
    """The cubic B-spline's weights of the four coefficients around a point t (0-1) past
    the second of them, and their derivatives in t."""
    cdef double s = 1.0 - t
    w[0] = s * s * s / 6.0
    w[1] = (3.0 * t * t * t - 6.0 * t * t + 4.0) / 6.0
    w[2] = (-3.0 * t * t * t + 3.0 * t * t + 3.0 * t + 1.0) / 6.0
    w[3] = t * t * t / 6.0
    d[0] = -0.5 * s * s
    d[1] = 0.5 * (3.0 * t * t - 4.0 * t)
    d[2] = 0.5 * (-3.0 * t * t + 2.0 * t + 1.0)
    d[3] = 0.5 * t * t


cdef inline void _bspline3_curvature(double t, double* w) noexcept nogil:
    """The second derivatives in t of :func:`_bspline3`'s weights."""
    w[0] = 1.0 - t
    w[1] = 3.0 * t - 2.0
    w[2] = 1.0 - 3.0 * t
    w[3] = t


cdef double _spline_terms(const double[:, ::1] coef, const double[:, ::1] pts, double x,
                          double y, double theta, double ox, double oy, double res,
                          double g[3], double h[3][3]) noexcept nogil:
    """Σ of the cubic B-spline of ``coef`` over ``pts`` placed at (x, y, θ) (as
    :func:`spline_mean`, not divided by their count); its gradient in (x, y, θ) into
    ``g``; and into ``h`` Σ Jᵀ C J, C each point's curvature across the surface (the
    negative of the spline's 2×2 Hessian in x, y with its upward bends set to zero, so h
    is positive semi-definite: on a wall's ridge, C is the wall's normal's nnᵀ times the
    ridge's curvature, as a point-to-line pair weighs), J the point's motion in (x, y, θ)."""
    cdef Py_ssize_t n = pts.shape[0], k, p, q
    cdef double ct = cos(theta), st = sin(theta), px, py, f, fu, fv, fuu, fuv, fvv
    cdef double total = 0.0, a, b, cc, tr, det, disc, l1, l2, e1x, e1y, norm, jx[3], jy[3]
    cdef double m00, m01, m11
    cdef double at[6]
    for p in range(3):
        g[p] = 0.0
        for q in range(3):
            h[p][q] = 0.0
    for k in range(n):
        px = x + ct * pts[k, 0] - st * pts[k, 1]
        py = y + st * pts[k, 0] + ct * pts[k, 1]
        _spline_at(coef, (px - ox) / res, (py - oy) / res, True, at)
        f, fu, fv, fuu, fuv, fvv = at[0], at[1], at[2], at[3], at[4], at[5]
        total += f
        fu /= res
        fv /= res
        jx[0] = 1.0
        jx[1] = 0.0
        jx[2] = -(py - y)
        jy[0] = 0.0
        jy[1] = 1.0
        jy[2] = px - x
        for p in range(3):
            g[p] += fu * jx[p] + fv * jy[p]
        # the curvature C = -Hessian (per m²), its negative eigenvalues set to zero
        a = -fuu / (res * res)
        b = -fuv / (res * res)
        cc = -fvv / (res * res)
        tr = 0.5 * (a + cc)
        det = a * cc - b * b
        disc = sqrt(max(tr * tr - det, 0.0))
        l1 = tr + disc  # the larger eigenvalue
        l2 = tr - disc
        if l1 <= 0.0:
            continue
        if l2 >= 0.0:
            m00, m01, m11 = a, b, cc
        else:  # l1 e1 e1ᵀ alone
            if fabs(b) > 1e-12 * (fabs(a) + fabs(cc)):
                e1x, e1y = b, l1 - a
            elif a >= cc:
                e1x, e1y = 1.0, 0.0
            else:
                e1x, e1y = 0.0, 1.0
            norm = e1x * e1x + e1y * e1y
            m00 = l1 * e1x * e1x / norm
            m01 = l1 * e1x * e1y / norm
            m11 = l1 * e1y * e1y / norm
        for p in range(3):
            for q in range(3):
                h[p][q] += (jx[p] * (m00 * jx[q] + m01 * jy[q])
                            + jy[p] * (m01 * jx[q] + m11 * jy[q]))
    return total


cdef double TAU = 6.283185307179586


cdef inline double _prior_cost(double dx, double dy, double dth, double wx, double wy,
                               double wth) noexcept nogil:
    """½ (wx dx² + wy dy² + wθ dθ²), dθ wrapped."""
    dth = remainder(dth, TAU)
    return 0.5 * (wx * dx * dx + wy * dy * dy + wth * dth * dth)


def spline_climb(const double[:, ::1] coef, const double[:, ::1] pts, double sx, double sy,
                 double sth, double gx, double gy, double gth, double ox, double oy,
                 double res, double kappa, double wx, double wy, double wth, int iterations,
                 double step_m, double step_rad):
    """The pose (x, y, θ), climbing from (sx, sy, sθ), where ``kappa`` × the sum of the cubic
    B-spline of ``coef`` over ``pts`` (:func:`spline_mean`'s surface), less the prior
    ½ (wx Δx² + wy Δy² + wθ Δθ²) about (gx, gy, gθ), is highest: Newton's steps on the surface's
    curvature made positive (:func:`_spline_terms`), each halved until it climbs (at most
    ten times), until a step moves the pose less than ``step_m`` (|x| + |y|) and
    ``step_rad``, or ``iterations`` steps. A smooth surface's top moves as little as its
    points do (no pairing that switches). Returns (x, y, θ)."""
    cdef double x = sx, y = sy, th = sth, nx, ny, nth, value, trial = 0.0, alpha
    cdef double g[3]
    cdef double hh[3][3]
    cdef double a[3][3]
    cdef double b[3]
    cdef double d[3]
    cdef int it, p, q, halvings
    with nogil:
        value = (kappa * _spline_terms(coef, pts, x, y, th, ox, oy, res, g, hh)
                 - _prior_cost(x - gx, y - gy, th - gth, wx, wy, wth))
        for it in range(iterations):
            for p in range(3):
                b[p] = -kappa * g[p]
                for q in range(3):
                    a[p][q] = kappa * hh[p][q]
            add_prior(a, b, x - gx, y - gy, th - gth, wx, wy, wth)
            if not solve3(a, b, d):
                break
            alpha = 1.0
            for halvings in range(11):
                nx = x - alpha * d[0]
                ny = y - alpha * d[1]
                nth = th - alpha * d[2]
                trial = (kappa * _spline_terms(coef, pts, nx, ny, nth, ox, oy, res, g, hh)
                         - _prior_cost(nx - gx, ny - gy, nth - gth, wx, wy, wth))
                if trial >= value:
                    break
                alpha *= 0.5
            if trial < value:
                break  # (no step along d climbs: at the top, as far as doubles tell)
            x, y, th, value = nx, ny, nth, trial
            if alpha * (fabs(d[0]) + fabs(d[1])) < step_m and alpha * fabs(d[2]) < step_rad:
                break
    return x, y, th


cdef inline double _cell(const double[:, ::1] grid, Py_ssize_t r, Py_ssize_t c) noexcept nogil:
    """A cell's value; 0 off the grid."""
    if r < 0 or c < 0 or r >= grid.shape[0] or c >= grid.shape[1]:
        return 0.0
    return grid[r, c]


def mean_scores(const double[:, ::1] grid, double ox, double oy, double res,
                const double[:, ::1] pts, double x, double y, const double[::1] thetas,
                const Py_ssize_t[::1] tx, const Py_ssize_t[::1] ty, bint bilinear=False):
    """Mean grid value of ``pts`` turned by each θ and moved to (x, y) plus (tx, ty) cells:
    shape len(thetas) × len(ty) × len(tx); points off the grid count 0. The grid's cell
    (0, 0) is centred on (ox, oy). A point reads its nearest cell, or with ``bilinear`` the
    four cells around it weighed by its place among their centres (the score then moves
    with the pose, not in steps of a cell)."""
    cdef Py_ssize_t n = pts.shape[0], nx = tx.shape[0], ny = ty.shape[0], k, a, b, r, c, t
    cdef Py_ssize_t rows = grid.shape[0], cols = grid.shape[1], ix, iy, b0, b1
    cdef double ct, st, px, py, u, v, w00, w01, w10, w11
    cdef const double* row
    cdef const double* row1
    cdef double* acc
    cdef bint consecutive = True  # tx = tx[0], tx[0] + 1, ...: a row's cells are contiguous
    for b in range(1, nx):
        consecutive = consecutive and tx[b] == tx[0] + b
    out = np.zeros((thetas.shape[0], ny, nx))
    cdef double[:, :, ::1] o = out
    with nogil:
        for t in range(thetas.shape[0]):
            ct = cos(thetas[t])
            st = sin(thetas[t])
            for k in range(n):
                px = x + ct * pts[k, 0] - st * pts[k, 1]
                py = y + st * pts[k, 0] + ct * pts[k, 1]
                if bilinear:
                    u = (px - ox) / res
                    v = (py - oy) / res
                    ix = <Py_ssize_t>floor(u)
                    iy = <Py_ssize_t>floor(v)
                    u -= ix
                    v -= iy
                    w00, w01 = (1.0 - u) * (1.0 - v), u * (1.0 - v)
                    w10, w11 = (1.0 - u) * v, u * v
                    for a in range(ny):
                        r = iy + ty[a]
                        if r < -1 or r >= rows:
                            continue
                        c = ix + tx[0] if nx else 0
                        if consecutive and nx and 0 <= r < rows - 1 and c >= 0 \
                                and c + nx < cols:  # all four cells inside: vectorized
                            row = &grid[r, c]
                            row1 = &grid[r + 1, c]
                            acc = &o[t, a, 0]
                            for b in range(nx):
                                acc[b] += (w00 * row[b] + w01 * row[b + 1]
                                           + w10 * row1[b] + w11 * row1[b + 1])
                            continue
                        for b in range(nx):
                            c = ix + tx[b]
                            o[t, a, b] += (_cell(grid, r, c) * w00 + _cell(grid, r, c + 1) * w01
                                           + _cell(grid, r + 1, c) * w10
                                           + _cell(grid, r + 1, c + 1) * w11)
                    continue
                ix = <Py_ssize_t>floor((px - ox) / res + 0.5)
                iy = <Py_ssize_t>floor((py - oy) / res + 0.5)
                for a in range(ny):
                    r = iy + ty[a]
                    if r < 0 or r >= rows:
                        continue
                    if consecutive and nx:  # no test per cell: the compiler vectorizes it
                        c = ix + tx[0]
                        b0 = max(0, -c)
                        b1 = min(nx, cols - c)
                        row = &grid[r, 0]
                        acc = &o[t, a, 0]
                        for b in range(b0, b1):
                            acc[b] += row[c + b]
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


# -- graph distance (the search window's size) ----------------------------------------------

def shortest_paths(const Py_ssize_t[::1] head, const Py_ssize_t[::1] nxt,
                   const Py_ssize_t[::1] to, const double[::1] length, Py_ssize_t n,
                   const Py_ssize_t[::1] sources, double limit, Py_ssize_t max_nodes,
                   const Py_ssize_t[::1] targets):
    """Dijkstra from the ``sources`` over an undirected graph of ``n`` nodes kept as
    adjacency lists (node v's first half-edge is head[v], each half-edge e leads to to[e]
    with length[e] and is followed by nxt[e]; -1 ends a list): the distance of every node to
    the nearest source, ∞ beyond ``limit``, beyond the ``max_nodes`` nearest nodes, and
    beyond the last of the ``targets`` if any are given (the search stops at whichever comes
    first, so its cost is that of the graph within it; a target's distance is exact)."""
    cdef Py_ssize_t s
    if head.shape[0] < n or sources.shape[0] == 0:
        raise ValueError("no source, or adjacency lists that do not cover the graph's nodes")
    for s in range(sources.shape[0]):
        if not 0 <= sources[s] < n:
            raise ValueError("a source is not a node of the graph")
    dist = np.full(n, INFINITY)
    settled_arr = np.zeros(n, dtype=np.uint8)
    cdef double[::1] d = dist
    cdef u8[::1] settled = settled_arr
    cdef Py_ssize_t cap = 64, size = 0, i, c, e, v, w, count = 0
    cdef Py_ssize_t left = targets.shape[0]  # targets not settled yet
    wanted_arr = np.zeros(n, dtype=np.uint8)
    cdef u8[::1] wanted = wanted_arr
    for s in range(targets.shape[0]):
        if not 0 <= targets[s] < n:
            raise ValueError("a target is not a node of the graph")
        if wanted[targets[s]]:
            left -= 1  # (listed twice)
        wanted[targets[s]] = 1
    if targets.shape[0] == 0:
        left = -1  # no targets: never stop for them
    cdef double dv, dw
    cdef double *key = <double *>malloc((cap + sources.shape[0]) * sizeof(double))
    cdef Py_ssize_t *node = <Py_ssize_t *>malloc((cap + sources.shape[0]) * sizeof(Py_ssize_t))
    cdef void *grown
    if key == NULL or node == NULL:
        free(key)
        free(node)
        raise MemoryError()
    cap += sources.shape[0]
    try:
        for s in range(sources.shape[0]):  # (all at 0: already a heap)
            d[sources[s]] = 0.0
            key[size], node[size] = 0.0, sources[s]
            size += 1
        while size and count < max_nodes and left != 0:
            dv, v = key[0], node[0]  # pop the heap's least ...
            size -= 1
            i = 0
            while True:  # ... and sift its last entry down from the top
                c = 2 * i + 1
                if c >= size:
                    break
                if c + 1 < size and key[c + 1] < key[c]:
                    c += 1
                if key[size] <= key[c]:
                    break
                key[i], node[i] = key[c], node[c]
                i = c
            key[i], node[i] = key[size], node[size]
            if dv > d[v] or settled[v]:
                continue  # a stale entry
            settled[v] = 1
            count += 1
            if wanted[v]:
                left -= 1
            e = head[v]
            while e >= 0:
                w = to[e]
                dw = dv + length[e]
                if dw < d[w] and dw <= limit:
                    d[w] = dw
                    if size == cap:
                        cap *= 2
                        grown = realloc(key, cap * sizeof(double))
                        if grown == NULL:
                            raise MemoryError()
                        key = <double *>grown
                        grown = realloc(node, cap * sizeof(Py_ssize_t))
                        if grown == NULL:
                            raise MemoryError()
                        node = <Py_ssize_t *>grown
                    i = size  # push, sifting up
                    size += 1
                    while i and key[(i - 1) // 2] > dw:
                        key[i], node[i] = key[(i - 1) // 2], node[(i - 1) // 2]
                        i = (i - 1) // 2
                    key[i], node[i] = dw, w
                e = nxt[e]
    finally:
        free(key)
        free(node)
    if size:  # stopped early: those reached but not settled are beyond where it stopped
        dist[settled_arr == 0] = INFINITY
    return dist
