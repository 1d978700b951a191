# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False
"""The pose graph's sparse solves: minimum-degree order and the LDLᵀ factorization, and
preconditioned conjugate gradients for large graphs.

Compiled by ``pip install`` (setup.py); the algorithm and its documentation live in
``dynslam_cli.localization.graph``. No fast-math: results are the same on every run. The long loops release the
GIL, so threads (a Dask worker's, say) can process several logs at once.
"""

import numpy as np

from libc.math cimport INFINITY, atan2, ceil, cos, fabs, floor, hypot, remainder, sin, sqrt
from libc.stdlib cimport calloc, free, malloc, realloc

ctypedef unsigned char u8


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
    degree on the elimination graph, George & Liu 1989). Returns the order and the
    multiplications a block LDLᵀ factorization in it takes (3×3 blocks: 27 d(d + 1)/2 for
    a node eliminated with d neighbours)."""
    cdef Py_ssize_t m = ei.shape[0], k, a, b, v, u, w, p, q, step, hsize = 0, hcap
    cdef Py_ssize_t dv, du
    cdef long long key
    cdef int stamp = 0
    cdef double flops = 0.0
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
            flops += 13.5 * dv * (dv + 1)
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
    return order_arr, flops


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


cdef void _precondition(const double[:, :, ::1] inverse, const double* r, double* z
                        ) noexcept nogil:
    """z = M⁻¹ r with M⁻¹ block diagonal (3×3 blocks)."""
    cdef Py_ssize_t b, a
    for b in range(inverse.shape[0]):
        for a in range(3):
            z[3 * b + a] = (inverse[b, a, 0] * r[3 * b] + inverse[b, a, 1] * r[3 * b + 1]
                            + inverse[b, a, 2] * r[3 * b + 2])


def conjugate_gradients(const Py_ssize_t[::1] indptr, const Py_ssize_t[::1] indices,
                        const double[::1] data, const double[:, :, ::1] inverse,
                        const double[::1] rhs, double tolerance, Py_ssize_t max_steps):
    """x with A x = rhs, A symmetric positive definite in compressed columns (duplicates
    summed), by conjugate gradients preconditioned with ``inverse`` (the inverses of A's
    3×3 diagonal blocks), until the residual is ``tolerance`` of rhs's (or ``max_steps``)."""
    cdef Py_ssize_t n = rhs.shape[0], k, p, step
    if inverse.shape[0] * 3 != n or indptr.shape[0] != n + 1:
        raise ValueError("the preconditioner or the matrix does not fit the right-hand side")
    x_arr, r_arr = np.zeros(n), np.array(rhs, dtype=np.float64)
    z_arr, d_arr, q_arr = np.empty(n), np.empty(n), np.empty(n)
    cdef double[::1] x = x_arr, r = r_arr, z = z_arr, d = d_arr, q = q_arr
    cdef double rz = 0.0, rz_new, dq, alpha, beta, rr, goal = 0.0
    with nogil:
        for k in range(n):
            goal += rhs[k] * rhs[k]
        goal *= tolerance * tolerance
        _precondition(inverse, &r[0], &z[0])
        for k in range(n):
            d[k] = z[k]
            rz += r[k] * z[k]
        for step in range(max_steps if goal > 0.0 else 0):  # (rhs 0: x = 0)
            for k in range(n):
                q[k] = 0.0
            for k in range(n):  # q = A d, column by column
                for p in range(indptr[k], indptr[k + 1]):
                    q[indices[p]] += data[p] * d[k]
            dq = 0.0
            for k in range(n):
                dq += d[k] * q[k]
            if dq <= 0.0:
                break  # (not positive definite along d: stop where we are)
            alpha = rz / dq
            rr = 0.0
            for k in range(n):
                x[k] += alpha * d[k]
                r[k] -= alpha * q[k]
                rr += r[k] * r[k]
            if rr <= goal:
                break
            _precondition(inverse, &r[0], &z[0])
            rz_new = 0.0
            for k in range(n):
                rz_new += r[k] * z[k]
            beta = rz_new / rz
            rz = rz_new
            for k in range(n):
                d[k] = z[k] + beta * d[k]
    return x_arr
