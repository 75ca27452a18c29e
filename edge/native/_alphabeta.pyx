# cython: language_level=3
# distutils: extra_compile_args = -ffp-contract=off
"""Alpha-beta tracker kernels of the surveillance profile (edge.track.cylinder.Cylinder, edge.track.alphabeta
BenedictBordnerFilter and GreedyAssociator): the cylinder projection, the prediction, the update and the gated
greedy association of one frame, each in one call on the few tracks and centroids, in place of a few dozen numpy
calls each.

Every value is computed with the reference's operations in its order (``np.linalg.norm`` over the last axis sums
``(x^2 + y^2) + z^2``; the angles come from libm's ``atan2``, ``cos`` and ``sin``, which numpy's float64 loops call
too unless its AVX-512 dispatch is on), so the results are bit-identical.
"""

cimport cython
from libc.math cimport atan2, cos, sin, sqrt, fabs, isnan, INFINITY


cdef inline void _project(double *s, double radius) noexcept nogil:
    """The operator N of eq. 14 on one state ``(v', u', v'', u'', r, u_r)``."""
    cdef double th = atan2(s[2], s[0])
    cdef double c = cos(th)
    cdef double sn = sin(th)
    cdef double normal = s[1] * c + s[3] * sn
    s[0] = radius * c
    s[2] = radius * sn
    s[1] = s[1] - normal * c
    s[3] = s[3] - normal * sn


def project_states(double[:, ::1] s, double radius):
    """N of eq. 14 on states ``(n, 6)``, in place."""
    cdef Py_ssize_t k
    with nogil:
        for k in range(s.shape[0]):
            _project(&s[k, 0], radius)


def project_points(double[:, ::1] p, double radius):
    """Radial projection of points ``(n, 3)`` onto the cylinder, in place."""
    cdef Py_ssize_t k
    cdef double th
    with nogil:
        for k in range(p.shape[0]):
            th = atan2(p[k, 1], p[k, 0])
            p[k, 0] = radius * cos(th)
            p[k, 1] = radius * sin(th)


def predict(double[:, ::1] s, double radius):
    """``N[A s]`` (positions plus rates, then N) on states ``(n, 6)``, in place."""
    cdef Py_ssize_t k
    with nogil:
        for k in range(s.shape[0]):
            s[k, 0] = s[k, 0] + s[k, 1]
            s[k, 2] = s[k, 2] + s[k, 3]
            s[k, 4] = s[k, 4] + s[k, 5]
            _project(&s[k, 0], radius)


def update(double[:, ::1] s, const double[:, ::1] m, double alpha, double beta, double radius):
    """``N{s + G (m - C s)}`` on states ``(n, 6)`` with measurements ``(n, 3)``, in place."""
    cdef Py_ssize_t k
    cdef int a
    cdef double r
    with nogil:
        for k in range(s.shape[0]):
            for a in range(3):
                r = m[k, a] - s[k, 2 * a]
                s[k, 2 * a] = s[k, 2 * a] + alpha * r
                s[k, 2 * a + 1] = s[k, 2 * a + 1] + beta * r
            _project(&s[k, 0], radius)


cdef inline double _dist(const double *p, Py_ssize_t step, const double *q) noexcept nogil:
    cdef double x = p[0] - q[0]
    cdef double y = p[step] - q[1]
    cdef double z = p[2 * step] - q[2]
    return sqrt((x * x + y * y) + z * z)


def associate(const double[:, ::1] pred, Py_ssize_t step, const double[:, ::1] last, const double[:, ::1] cen,
              double gate, bint gate_last, const double[::1] range_gate, double[:, ::1] cost, double[:, ::1] work,
              Py_ssize_t[::1] rows, Py_ssize_t[::1] cols):
    """Gated cost matrix and greedy assignment (GreedyAssociator.associate, greedy_assign).

    ``pred`` holds the predicted positions at columns ``0, step, 2 step`` of each row (``step`` 2 for states, 1 for
    positions); ``last`` ``(n, 3)`` the gate's reference when ``gate_last``; ``range_gate`` ``(n,)`` or empty (no
    range gate). Fills ``cost`` ``(n, m)`` (``+inf`` outside the gates) and, pairing order, ``rows``/``cols``
    (room for ``min(n, m)``); ``work`` ``(n, m)`` is scratch. Returns the number of pairs."""
    cdef Py_ssize_t n = cost.shape[0], m = cost.shape[1], t, j, bi, bj, n_pairs = 0, it
    cdef double d, g, best
    cdef bint rg = range_gate.shape[0] > 0
    with nogil:
        for t in range(n):
            for j in range(m):
                d = _dist(&pred[t, 0], step, &cen[j, 0])
                g = _dist(&last[t, 0], 1, &cen[j, 0]) if gate_last else d
                if g > gate:
                    d = INFINITY
                if rg and fabs(pred[t, 2 * step] - cen[j, 2]) > range_gate[t]:
                    d = INFINITY
                cost[t, j] = d
                work[t, j] = INFINITY if isnan(d) else d
        for it in range(n if n < m else m):
            # the first smallest entry in row-major order (np.argmin)
            best = work[0, 0]
            bi = 0
            bj = 0
            for t in range(n):
                for j in range(m):
                    if work[t, j] < best:
                        best = work[t, j]
                        bi = t
                        bj = j
            if not (best < INFINITY):
                break
            rows[n_pairs] = bi
            cols[n_pairs] = bj
            n_pairs += 1
            for j in range(m):
                work[bi, j] = INFINITY
            for t in range(n):
                work[t, bj] = INFINITY
    return n_pairs
