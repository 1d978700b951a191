# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False
"""Change events' inner loops: one scan's sightings cut into blobs, and blobs linked into
tracks.

Compiled by ``pip install`` (setup.py); the algorithm and its documentation live in
``dynslam_cli.mapping.changes``. No fast-math: results are the same on every run.
"""

import numpy as np

from libc.math cimport hypot, rint
from libc.stdlib cimport free, malloc

cdef enum:
    FIELDS = 8  # a blob's record: scan, centroid x y, box x0 y0 x1 y1, point count


cdef inline Py_ssize_t root(Py_ssize_t* parent, Py_ssize_t i) noexcept nogil:
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


def scan_blobs(const double[:, ::1] xy, double gap, double scan):
    """The blobs of one scan's sighted cells (their centres, n × 2, in beam order), as
    rows of ``changes.BLOB_FIELDS``: the cells cut where successive ones lie more than
    ``gap`` apart, then pieces whose boxes come within ``gap`` of each other in x and in y
    (or are chained so) joined again; blobs in the order of their first cell."""
    cdef Py_ssize_t n = xy.shape[0], p = 0, i, j, a, b, k, g = 0
    if n == 0:
        return np.zeros((0, FIELDS))
    cdef Py_ssize_t* start = <Py_ssize_t*>malloc((n + 1) * sizeof(Py_ssize_t))
    cdef Py_ssize_t* parent = <Py_ssize_t*>malloc(n * sizeof(Py_ssize_t))
    cdef Py_ssize_t* slot = <Py_ssize_t*>malloc(n * sizeof(Py_ssize_t))
    cdef double* box = <double*>malloc(4 * n * sizeof(double))
    out = np.empty((n, FIELDS))
    cdef double[:, ::1] o = out
    cdef double x, y
    if not start or not parent or not slot or not box:
        free(start); free(parent); free(slot); free(box)
        raise MemoryError()
    with nogil:
        for i in range(n):  # pieces, each with its box
            x, y = xy[i, 0], xy[i, 1]
            if i == 0 or hypot(x - xy[i - 1, 0], y - xy[i - 1, 1]) > gap:
                start[p] = i
                box[4 * p], box[4 * p + 1], box[4 * p + 2], box[4 * p + 3] = x, y, x, y
                parent[p] = p
                p += 1
            else:
                k = 4 * (p - 1)
                box[k] = min(box[k], x)
                box[k + 1] = min(box[k + 1], y)
                box[k + 2] = max(box[k + 2], x)
                box[k + 3] = max(box[k + 3], y)
        start[p] = n
        for i in range(p):  # pieces near each other joined, the smallest piece the root
            for j in range(i + 1, p):
                if (max(box[4 * i] - box[4 * j + 2], box[4 * j] - box[4 * i + 2]) <= gap
                        and max(box[4 * i + 1] - box[4 * j + 3],
                                box[4 * j + 1] - box[4 * i + 3]) <= gap):
                    a, b = root(parent, i), root(parent, j)
                    if a != b:
                        parent[max(a, b)] = min(a, b)
        for i in range(p):  # each piece's points added to its blob's row
            a = root(parent, i)
            if a == i:
                slot[i] = g
                o[g, 0], o[g, 1], o[g, 2], o[g, 7] = scan, 0.0, 0.0, 0.0
                o[g, 3], o[g, 4], o[g, 5], o[g, 6] = box[4 * i], box[4 * i + 1], \
                    box[4 * i + 2], box[4 * i + 3]
                g += 1
            k = slot[a]
            o[k, 3] = min(o[k, 3], box[4 * i])
            o[k, 4] = min(o[k, 4], box[4 * i + 1])
            o[k, 5] = max(o[k, 5], box[4 * i + 2])
            o[k, 6] = max(o[k, 6], box[4 * i + 3])
            for j in range(start[i], start[i + 1]):
                o[k, 1] += xy[j, 0]
                o[k, 2] += xy[j, 1]
            o[k, 7] += start[i + 1] - start[i]
        for k in range(g):
            o[k, 1] /= o[k, 7]
            o[k, 2] /= o[k, 7]
    free(start); free(parent); free(slot); free(box)
    return out[:g]


def link_tracks(const double[:, ::1] blobs, const double[::1] stamps, double gate,
                double gap_s):
    """Each blob's track (0, 1, ... in order of creation; blobs as rows of
    ``changes.BLOB_FIELDS``, in scan order): a scan's blobs continue the tracks whose last
    blob was seen at most ``gap_s`` before and lies within ``gate`` of them, nearest pairs
    first (distances to 1e-9 m, then the blob's order, then the track's), one blob a scan
    per track; the others start tracks."""
    cdef Py_ssize_t n = blobs.shape[0], m = 0, live, s0 = 0, s1, i, j, k, bi, bj, made = 0
    track_ = np.empty(n, np.int64)
    cdef long long[::1] track = track_
    if n == 0:
        return track_
    cdef Py_ssize_t* ids = <Py_ssize_t*>malloc(n * sizeof(Py_ssize_t))
    cdef Py_ssize_t* ends = <Py_ssize_t*>malloc(n * sizeof(Py_ssize_t))
    cdef char* taken = <char*>malloc(n)
    cdef char* extended = <char*>malloc(n)
    cdef double* d = NULL
    cdef double now, best
    if not ids or not ends or not taken or not extended:
        free(ids); free(ends); free(taken); free(extended)
        raise MemoryError()
    try:
        while s0 < n:
            s1 = s0 + 1
            while s1 < n and blobs[s1, 0] == blobs[s0, 0]:
                s1 += 1
            k = s1 - s0
            now = stamps[<Py_ssize_t>blobs[s0, 0]]
            live = 0  # (the tracks that may continue, in order of creation)
            for j in range(m):
                if now - stamps[<Py_ssize_t>blobs[ends[j], 0]] <= gap_s:
                    ids[live], ends[live] = ids[j], ends[j]
                    live += 1
            m = live
            free(d)
            d = <double*>malloc(max(k * m, 1) * sizeof(double))
            if not d:
                raise MemoryError()
            for i in range(k):
                taken[i] = 0
                for j in range(m):
                    d[i * m + j] = rint(hypot(blobs[s0 + i, 1] - blobs[ends[j], 1],
                                              blobs[s0 + i, 2] - blobs[ends[j], 2]) * 1e9) / 1e9
            for j in range(m):
                extended[j] = 0
            while True:  # the nearest pair left, until none is within the gate
                best, bi, bj = gate, -1, -1
                for i in range(k):
                    if not taken[i]:
                        for j in range(m):
                            if not extended[j] and (d[i * m + j] < best or (
                                    bi < 0 and d[i * m + j] == best)):
                                best, bi, bj = d[i * m + j], i, j
                if bi < 0:
                    break
                track[s0 + bi] = ids[bj]
                ends[bj] = s0 + bi
                taken[bi] = extended[bj] = 1
            for i in range(k):
                if not taken[i]:
                    track[s0 + i] = made
                    ids[m], ends[m] = made, s0 + i
                    m += 1
                    made += 1
            s0 = s1
    finally:
        free(ids); free(ends); free(taken); free(extended); free(d)
    return track_
