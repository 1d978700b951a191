"""Small dense linear algebra shared by the compiled kernels (inlined into each)."""

from libc.math cimport fabs, remainder


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


cdef inline void add_prior(double a[3][3], double b[3], double dx, double dy, double dth,
                           double wx, double wy, double wth) noexcept nogil:
    """A Gaussian prior on the pose (weights wx, wy, wθ) into Gauss-Newton's normal
    equations a d = b (the step subtracted), the pose (dx, dy, dθ) from its centre (dθ
    wrapped); 1e-9 on the diagonal keeps a free direction solvable."""
    a[0][0] += wx + 1e-9
    a[1][1] += wy + 1e-9
    a[2][2] += wth + 1e-9
    b[0] += wx * dx
    b[1] += wy * dy
    b[2] += wth * remainder(dth, 2 * 3.141592653589793)
