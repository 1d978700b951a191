"""Small dense linear algebra shared by the compiled kernels (inlined into each)."""

from libc.math cimport fabs


cdef inline int solve3(double a[3][3], double b[3], double x[3]) noexcept nogil:
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
