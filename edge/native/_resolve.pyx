# cython: language_level=3
# distutils: extra_compile_args = -ffp-contract=off -O3
"""Resolver kernel (edge.lane.resolve.CellResolver.step, its numpy reference): one frame of the side-by-side
resolver in one call: the cell association, the looks' outer products, the memory's steering and update, the
two-source test and fit of the cells followed long enough, the split streaks and the cell table's ageing, dropping,
creation and cap.

Bit for bit as the reference where the arithmetic is the same: the float32 products and sums in the reference's
order with one rounding each (compiled without contraction to fused multiply-adds), the steering's cos and sin in
float64 (the C library's, as numpy's float64 ones) rounded to float32. The eigenvalues (cyclic Jacobi on the real
8 x 8 form of the 4 x 4 Hermitian matrix), the pair fits and the sources' powers are float64 as in the reference
but summed in another order than LAPACK and BLAS (differences of about 1e-16 relative): a decision differs only when
a ratio lies within that of its threshold or two pair fits tie to that precision.
"""

cimport cython
cimport numpy as cnp
from libc.stdlib cimport malloc, free, qsort
from libc.string cimport memcpy, memset
from libc.math cimport sqrt, sqrtf, fabs, cos, sin, NAN, isnan

import numpy as np

cnp.import_array()

include "_arrays.pxi"
include "_alloc.pxi"


cdef struct Cand:
    double cost
    Py_ssize_t d
    Py_ssize_t k


cdef int _cmp_cand(const void *pa, const void *pb) noexcept nogil:
    cdef const Cand *a = <const Cand *>pa
    cdef const Cand *b = <const Cand *>pb
    if a.cost < b.cost:
        return -1
    if a.cost > b.cost:
        return 1
    if a.d != b.d:
        return -1 if a.d < b.d else 1
    if a.k != b.k:
        return -1 if a.k < b.k else 1
    return 0


@cython.boundscheck(False)
@cython.wraparound(False)
@cython.cdivision(True)
cdef void _eigvals_hermitian(const float *cf, int n_rx, double *w, double *a) noexcept nogil:
    """Ascending eigenvalues ``w`` (n_rx) of the Hermitian matrix whose float32 (re, im) rows are ``cf`` (n_rx x
    2 n_rx), by cyclic complex Jacobi rotations in float64 (each pivot's phase moved onto its column, then the real
    rotation that zeroes it); ``a``: 2 n_rx^2 scratch (real parts, then imaginary parts)."""
    cdef int m = n_rx, i, j, p, q, k, sweep
    cdef double *ar = a
    cdef double *ai = a + m * m
    cdef double x, y, mag, wr, wi, theta, t, c, s, pr_, pi_, qr_, qi_
    cdef bint rotated
    for i in range(m):
        for j in range(m):
            ar[i * m + j] = cf[i * 2 * m + 2 * j]
            ai[i * m + j] = cf[i * 2 * m + 2 * j + 1]
    for i in range(m):  # (the input's own rounding: Hermitian exactly)
        ai[i * m + i] = 0.0
        for j in range(i + 1, m):
            x = 0.5 * (ar[i * m + j] + ar[j * m + i])
            y = 0.5 * (ai[i * m + j] - ai[j * m + i])
            ar[i * m + j] = x
            ar[j * m + i] = x
            ai[i * m + j] = y
            ai[j * m + i] = -y
    for sweep in range(100):
        rotated = False
        for p in range(m - 1):
            for q in range(p + 1, m):
                mag = sqrt(ar[p * m + q] * ar[p * m + q] + ai[p * m + q] * ai[p * m + q])
                if mag <= 1e-18 * (fabs(ar[p * m + p]) + fabs(ar[q * m + q])):  # below rounding: zero
                    ar[p * m + q] = 0.0
                    ai[p * m + q] = 0.0
                    ar[q * m + p] = 0.0
                    ai[q * m + p] = 0.0
                    continue
                rotated = True
                # column q times conj(a_pq) / |a_pq|, row q times its conjugate: a_pq becomes |a_pq|
                wr = ar[p * m + q] / mag
                wi = -ai[p * m + q] / mag
                for k in range(m):
                    if k == q:
                        continue
                    x = ar[k * m + q] * wr - ai[k * m + q] * wi
                    y = ar[k * m + q] * wi + ai[k * m + q] * wr
                    ar[k * m + q] = x
                    ai[k * m + q] = y
                    ar[q * m + k] = x
                    ai[q * m + k] = -y
                ar[p * m + q] = mag
                ai[p * m + q] = 0.0
                ar[q * m + p] = mag
                ai[q * m + p] = 0.0
                # the real rotation that zeroes a_pq
                theta = (ar[q * m + q] - ar[p * m + p]) / (2.0 * mag)
                if fabs(theta) > 1e150:
                    t = 0.5 / theta
                else:
                    t = 1.0 / (fabs(theta) + sqrt(theta * theta + 1.0))
                    if theta < 0.0:
                        t = -t
                c = 1.0 / sqrt(t * t + 1.0)
                s = t * c
                for k in range(m):
                    if k == p or k == q:
                        continue
                    pr_ = ar[k * m + p]
                    pi_ = ai[k * m + p]
                    qr_ = ar[k * m + q]
                    qi_ = ai[k * m + q]
                    x = c * pr_ - s * qr_
                    y = c * pi_ - s * qi_
                    ar[k * m + p] = x
                    ai[k * m + p] = y
                    ar[p * m + k] = x
                    ai[p * m + k] = -y
                    x = s * pr_ + c * qr_
                    y = s * pi_ + c * qi_
                    ar[k * m + q] = x
                    ai[k * m + q] = y
                    ar[q * m + k] = x
                    ai[q * m + k] = -y
                x = ar[p * m + p] - t * mag
                ar[q * m + q] = ar[q * m + q] + t * mag
                ar[p * m + p] = x
                ar[p * m + q] = 0.0
                ar[q * m + p] = 0.0
        if not rotated:
            break
    for i in range(m):
        x = ar[i * m + i]
        j = i
        while j > 0 and w[j - 1] > x:
            w[j] = w[j - 1]
            j -= 1
        w[j] = x


@cython.boundscheck(False)
@cython.wraparound(False)
cdef Py_ssize_t _argmax_rows(const double *fr, const float *feat, const long long *rows, Py_ssize_t start,
                             Py_ssize_t count, int F) noexcept nogil:
    """np.argmax over ``count`` rows (``rows[i]`` of ``feat``, or row i when ``rows`` is NULL) of the float64 dot
    products with ``fr``: the first maximum, or the first NaN."""
    cdef Py_ssize_t i, r, best = 0
    cdef int j
    cdef double score, best_score = 0.0
    cdef bint best_nan = False
    for i in range(count):
        r = rows[i] if rows != NULL else i
        score = 0.0
        for j in range(F):
            score = score + fr[j] * <double>feat[r * F + j]
        if score != score:
            if not best_nan:
                best_nan = True
                best = i
        elif not best_nan and (i == 0 or score > best_score):
            best_score = score
            best = i
    return best


cdef Py_ssize_t _argmax(const double *x, Py_ssize_t n) noexcept nogil:
    """np.argmax of ``x`` (n): the first maximum, or the first NaN."""
    cdef Py_ssize_t i, best = 0
    for i in range(n):
        if x[i] != x[i]:
            return i
        if x[i] > x[best]:
            best = i
    return best


def eigvals(const float[:, :, ::1] cov):
    """Ascending eigenvalues (k, rx) float64 of the Hermitian ``cov`` given as its float32 view (k, rx, 2 rx) (for
    the tests)."""
    cdef Py_ssize_t k = cov.shape[0], i
    cdef int n_rx = cov.shape[1]
    out = _empty2(cnp.NPY_FLOAT64, k, n_rx)
    cdef double[:, ::1] o = out
    cdef double *a = <double *>malloc(4 * n_rx * n_rx * sizeof(double) + 8)
    if a == NULL:
        raise MemoryError()
    try:
        for i in range(k):
            _eigvals_hermitian(&cov[i, 0, 0], n_rx, &o[i, 0], a)
    finally:
        free(a)
    return out


@cython.boundscheck(False)
@cython.wraparound(False)
@cython.cdivision(True)
def step(c_range_in, c_v_in, c_cov_in, c_n_in, c_misses_in, c_streak_in, rng_a, vel_a, looks_a, az_a,
         bint follow, double period_s, double range_gate, double speed_gate, double memory_frames,
         long long min_frames, long long min_split_frames, long long max_misses, double min_eig_ratio,
         double min_noise_ratio, double pair_hint_eig_ratio, float min_lateral, double min_power_ratio,
         double min_speed32, Py_ssize_t max_cells, float phase_per_lag, coarse_t_a, fine_rows_a, pair_feat_a,
         pair_th_a, pair_dsin_a, pinv_a):
    """One frame of :meth:`edge.lane.resolve.CellResolver.step`.

    Cells (m): ``c_range``, ``c_v`` float64, ``c_cov`` the complex64 covariances (m, rx, rx), frame counts ``c_n``,
    ``c_misses``, ``c_streak`` int64. Detections (n): ``rng``, ``vel``, ``az`` float32 (``az`` used with
    ``follow``), ``looks`` the complex64 snapshots (n, looks, rx). ``phase_per_lag``: the steering phase per unit
    shift and element lag, float32 (-2 pi d / lambda). Tables of the resolver: the coarse pairs' features transposed,
    float64 (rx^2, nc), their 3 x 3 fine neighbours' rows (nc, 9), every pair's features (P, rx^2), angles (P, 2),
    direction-cosine spread (P,) and source estimator ``pinv`` (P, 2, 2 rx) float32 view.

    Returns ``(split (n,) uint8, angles (n, 2) float32, two_sources (n,) uint8, range, v, cov (m', rx, rx)
    complex64, n, misses, streak)``: the new cell table. The arrays are read through the numpy C API; the cells and
    detections are converted to C-contiguous arrays of those types when they are not (np.ascontiguousarray), the
    tables must be; ``fine_rows``' entries must be rows of ``pair_feat``, which the resolver's tables are (not
    checked)."""
    if not (cnp.PyArray_Check(looks_a) and cnp.PyArray_NDIM(<cnp.ndarray>looks_a) == 3
            and cnp.PyArray_Check(coarse_t_a) and cnp.PyArray_NDIM(<cnp.ndarray>coarse_t_a) == 2
            and cnp.PyArray_Check(fine_rows_a) and cnp.PyArray_NDIM(<cnp.ndarray>fine_rows_a) == 2
            and cnp.PyArray_Check(pair_feat_a) and cnp.PyArray_NDIM(<cnp.ndarray>pair_feat_a) == 2):
        raise ValueError("looks (n, looks, rx), coarse_t (rx^2, nc), fine_rows (nc, 9), pair_feat (P, rx^2) needed")
    c_range_in = _as_c(c_range_in, cnp.NPY_FLOAT64)
    c_v_in = _as_c(c_v_in, cnp.NPY_FLOAT64)
    c_cov_in = _as_c(c_cov_in, cnp.NPY_COMPLEX64)
    looks_a = _as_c(looks_a, cnp.NPY_COMPLEX64)
    rng_a = _as_c(rng_a, cnp.NPY_FLOAT32)
    vel_a = _as_c(vel_a, cnp.NPY_FLOAT32)
    az_a = _as_c(az_a, cnp.NPY_FLOAT32)
    c_n_in = _as_c(c_n_in, cnp.NPY_INT64)
    c_misses_in = _as_c(c_misses_in, cnp.NPY_INT64)
    c_streak_in = _as_c(c_streak_in, cnp.NPY_INT64)
    cdef Py_ssize_t m = len(c_range_in), n = len(rng_a)
    cdef Py_ssize_t n_looks_all = cnp.PyArray_DIM(<cnp.ndarray>looks_a, 1)
    cdef int n_rx = cnp.PyArray_DIM(<cnp.ndarray>looks_a, 2) if n else cnp.PyArray_DIM(<cnp.ndarray>c_cov_in, 1)
    cdef int F = n_rx * n_rx
    cdef Py_ssize_t W = 2 * n_rx
    cdef Py_ssize_t nc = cnp.PyArray_DIM(<cnp.ndarray>coarse_t_a, 1), n_fine = cnp.PyArray_DIM(<cnp.ndarray>fine_rows_a, 1)
    cdef Py_ssize_t n_pairs = cnp.PyArray_DIM(<cnp.ndarray>pair_feat_a, 0)
    cdef const float *rng = <const float *>_data(rng_a, cnp.NPY_FLOAT32, n, False, "rng")
    cdef const float *vel = <const float *>_data(vel_a, cnp.NPY_FLOAT32, n, False, "vel")
    cdef const float *looks = <const float *>_data3(looks_a, cnp.NPY_COMPLEX64, n, n_looks_all, n_rx, False, "looks")
    cdef const float *az = <const float *>_data(az_a, cnp.NPY_FLOAT32, len(az_a), False, "az")
    if follow and len(az_a) < n:
        raise ValueError("az: one angle per detection needed")
    cdef const double *coarse_t = <const double *>_data2(coarse_t_a, cnp.NPY_FLOAT64, F, nc, False, "coarse_t")
    cdef const long long *fine_rows = <const long long *>_data2(fine_rows_a, cnp.NPY_INT64, nc, n_fine, False,
                                                                "fine_rows")
    cdef const float *pair_feat = <const float *>_data2(pair_feat_a, cnp.NPY_FLOAT32, n_pairs, F, False, "pair_feat")
    cdef const float *pair_th = <const float *>_data2(pair_th_a, cnp.NPY_FLOAT32, n_pairs, 2, False, "pair_th")
    cdef const float *pair_dsin = <const float *>_data(pair_dsin_a, cnp.NPY_FLOAT32, n_pairs, False, "pair_dsin")
    cdef const float *pinv = <const float *>_data3(pinv_a, cnp.NPY_FLOAT32, n_pairs, 2, W, False, "pinv")
    cdef const double *c_range = <const double *>_data(c_range_in, cnp.NPY_FLOAT64, m, False, "c_range")
    cdef const double *c_v = <const double *>_data(c_v_in, cnp.NPY_FLOAT64, m, False, "c_v")
    cdef const float *c_cov = <const float *>_data3(c_cov_in, cnp.NPY_COMPLEX64, m, n_rx, n_rx, False, "c_cov")
    cdef const long long *c_n = <const long long *>_data(c_n_in, cnp.NPY_INT64, m, False, "c_n")
    cdef const long long *c_miss = <const long long *>_data(c_misses_in, cnp.NPY_INT64, m, False, "c_misses")
    cdef const long long *c_streak = <const long long *>_data(c_streak_in, cnp.NPY_INT64, m, False, "c_streak")
    cdef Py_ssize_t i, j, d, k, s, a, b, l, cnt, n_cand, n_keep, n_new, n_out, best, bc, p
    cdef int r_, s_, lag
    cdef float sr, si, acc, nrm, inv, xr_a, xi_a, xr_b, xi_b, scale, wgt, cr, ci, fr_, fi_, shift32, ph
    cdef double pr, dr, dv, shift, old, w_lo, noise, pa0, pa1, ratio
    cdef double br, bi, qr, qi, tr, ti, accr, lo, hi
    cdef float lateral
    cdef bint any_now, above, hint, two

    split_arr = _zeros1(cnp.NPY_UINT8, n)
    cdef unsigned char *split = <unsigned char *>cnp.PyArray_DATA(<cnp.ndarray>split_arr)
    two_arr = _zeros1(cnp.NPY_UINT8, n)
    cdef unsigned char *two_src = <unsigned char *>cnp.PyArray_DATA(<cnp.ndarray>two_arr)
    ang_arr = _empty2(cnp.NPY_FLOAT32, n, 2)  # np.full((n, 2), np.nan, np.float32)
    cdef float *ang = <float *>cnp.PyArray_DATA(<cnp.ndarray>ang_arr)
    cdef Py_ssize_t q
    for q in range(2 * n):
        ang[q] = <float>NAN
    # the followed cells' state, updated here (copies: the inputs stay as they were), and the new looks' products
    cdef double *crange = <double *>malloc((2 * m + 1) * sizeof(double))
    cdef double *cv = crange + m
    cdef long long *cn = <long long *>malloc((3 * m + 1) * sizeof(long long))
    cdef long long *cmiss = cn + m
    cdef long long *cstreak = cn + 2 * m
    cdef float *cov = <float *>malloc((m * n_rx * W + n * n_rx * W + 1) * sizeof(float))
    if crange == NULL or cn == NULL or cov == NULL:
        free(crange); free(cn); free(cov)
        raise MemoryError()
    cdef float *rnew = cov + m * n_rx * W
    memcpy(crange, c_range, m * sizeof(double))
    memcpy(cv, c_v, m * sizeof(double))
    memcpy(cn, c_n, m * sizeof(long long))
    memcpy(cmiss, c_miss, m * sizeof(long long))
    memcpy(cstreak, c_streak, m * sizeof(long long))
    memcpy(cov, c_cov, m * n_rx * W * sizeof(float))
    memset(rnew, 0, n * n_rx * W * sizeof(float))

    cdef Py_ssize_t *match = <Py_ssize_t *>malloc((n + 1) * sizeof(Py_ssize_t))
    cdef unsigned char *taken = <unsigned char *>malloc(m + 1)
    cdef unsigned char *now = <unsigned char *>malloc(n + 1)
    cdef Cand *cand = <Cand *>malloc((n * m + 1) * sizeof(Cand))
    cdef float *p_el = <float *>malloc((n_rx + 1) * sizeof(float))
    cdef float *lagf = <float *>malloc((4 * n_rx + 2) * sizeof(float))
    cdef double *w = <double *>malloc((n_rx + 1) * sizeof(double))
    cdef double *scratch = <double *>malloc((4 * F + 2) * sizeof(double))
    cdef double *fr = <double *>malloc((F + 1) * sizeof(double))
    cdef float *xr = <float *>malloc((n_looks_all * n_rx + 1) * sizeof(float))
    cdef float *xi = <float *>malloc((n_looks_all * n_rx + 1) * sizeof(float))
    cdef Py_ssize_t *order = NULL
    cdef double *scores = <double *>malloc((nc + 1) * sizeof(double))
    if (match == NULL or taken == NULL or now == NULL or cand == NULL or p_el == NULL or lagf == NULL or w == NULL
            or scratch == NULL or fr == NULL or xr == NULL or xi == NULL or scores == NULL):
        free(match); free(taken); free(now); free(cand); free(p_el); free(lagf); free(w); free(scratch)
        free(fr); free(xr); free(xi); free(scores)
        raise MemoryError()
    try:
        # --- association: pairs inside the gates, cheapest first (ties: detection, then cell), one to one
        for d in range(n):
            match[d] = -1
            now[d] = 0
        for k in range(m):
            taken[k] = 0
        n_cand = 0
        if m and n:
            for d in range(n):
                for k in range(m):
                    pr = crange[k] + cv[k] * period_s
                    dr = fabs(<double>rng[d] - pr)
                    dv = fabs(<double>vel[d] - cv[k])
                    if dr <= range_gate and dv <= speed_gate:
                        cand[n_cand].cost = dr / range_gate + dv / speed_gate
                        cand[n_cand].d = d
                        cand[n_cand].k = k
                        n_cand += 1
            if n_cand:
                qsort(cand, n_cand, sizeof(Cand), _cmp_cand)
                for i in range(n_cand):
                    d = cand[i].d
                    k = cand[i].k
                    if match[d] < 0 and not taken[k]:
                        taken[k] = 1
                        match[d] = k
        # --- outer products of the normalised looks, averaged over the looks
        for d in range(n):
            cnt = 0
            for s in range(n_looks_all):
                for a in range(n_rx):
                    sr = looks[(d * n_looks_all + s) * W + 2 * a]
                    si = looks[(d * n_looks_all + s) * W + 2 * a + 1]
                    p_el[a] = sr * sr + si * si
                acc = p_el[0]
                for a in range(1, n_rx):
                    acc = acc + p_el[a]
                nrm = sqrtf(acc)
                if nrm > 0:
                    cnt += 1
                inv = <float>1.0 / (nrm if (nrm > <float>1e-30 or nrm != nrm) else <float>1e-30)
                for a in range(n_rx):
                    xr[s * n_rx + a] = looks[(d * n_looks_all + s) * W + 2 * a] * inv
                    xi[s * n_rx + a] = looks[(d * n_looks_all + s) * W + 2 * a + 1] * inv
            scale = <float>1.0 / <float>(cnt if cnt > 1 else 1)
            for a in range(n_rx):
                for b in range(n_rx):
                    sr = 0
                    si = 0
                    for s in range(n_looks_all):
                        xr_a = xr[s * n_rx + a]
                        xi_a = xi[s * n_rx + a]
                        xr_b = xr[s * n_rx + b]
                        xi_b = xi[s * n_rx + b]
                        if s == 0:
                            sr = xr_a * xr_b + xi_a * xi_b
                            si = xi_a * xr_b - xr_a * xi_b
                        else:
                            sr = sr + (xr_a * xr_b + xi_a * xi_b)
                            si = si + (xi_a * xr_b - xr_a * xi_b)
                    rnew[(d * n_rx + a) * W + 2 * b] = sr * scale
                    rnew[(d * n_rx + a) * W + 2 * b + 1] = si * scale
        # --- the followed cells: steering, memory update, the two-source test of those followed long enough
        for d in range(n):
            k = match[d]
            if k < 0:
                continue
            if follow:
                old = crange[k]
                if not (old >= 1e-3 or isnan(old)):
                    old = 1e-3
                shift = sin(<double>az[d]) * (1.0 - <double>rng[d] / old)
                shift32 = <float>shift
                for l in range(2 * n_rx - 1):
                    ph = (phase_per_lag * shift32) * <float>(l - (n_rx - 1))
                    lagf[2 * l] = <float>cos(<double>ph)
                    lagf[2 * l + 1] = <float>sin(<double>ph)
                for a in range(n_rx):
                    for b in range(n_rx):
                        lag = a - b + n_rx - 1
                        fr_ = lagf[2 * lag]
                        fi_ = lagf[2 * lag + 1]
                        cr = cov[(k * n_rx + a) * W + 2 * b]
                        ci = cov[(k * n_rx + a) * W + 2 * b + 1]
                        cov[(k * n_rx + a) * W + 2 * b] = cr * fr_ - ci * fi_
                        cov[(k * n_rx + a) * W + 2 * b + 1] = cr * fi_ + ci * fr_
            cn[k] += 1
            wgt = <float>(1.0 / <double>cn[k] if 1.0 / <double>cn[k] >= 1.0 / memory_frames else 1.0 / memory_frames)
            for a in range(n_rx):
                for b in range(2 * n_rx):
                    cov[(k * n_rx + a) * W + b] = cov[(k * n_rx + a) * W + b] + wgt * (rnew[(d * n_rx + a) * W + b] - cov[(k * n_rx + a) * W + b])
            crange[k] = <double>rng[d]
            cv[k] = <double>vel[d]
            cmiss[k] = 0
            if cn[k] >= min_frames and fabs(<double>vel[d]) >= min_speed32:
                _eigvals_hermitian(&cov[(k * n_rx + 0) * W + 0], n_rx, w, scratch)
                w_lo = 0.0
                for a in range(n_rx - 2):
                    w_lo = w_lo + w[a] if a else w[a]
                noise = w_lo / (n_rx - 2)
                if not (noise >= 1e-12 or isnan(noise)):
                    noise = 1e-12
                above = w[n_rx - 2] >= min_noise_ratio * noise
                hint = above and w[n_rx - 2] >= pair_hint_eig_ratio * w[n_rx - 1]
                two = w[n_rx - 2] >= min_eig_ratio * w[n_rx - 1] and above
                two_src[d] = hint
                if two:
                    # features: Re of the diagonal, 2 Re and 2 Im of the upper triangle (row by row)
                    for a in range(n_rx):
                        fr[a] = cov[(k * n_rx + a) * W + 2 * a]
                    p = n_rx
                    for a in range(n_rx):
                        for b in range(a + 1, n_rx):
                            fr[p] = <double>(<float>2.0 * cov[(k * n_rx + a) * W + 2 * b])
                            p += 1
                    for a in range(n_rx):
                        for b in range(a + 1, n_rx):
                            fr[p] = <double>(<float>2.0 * cov[(k * n_rx + a) * W + 2 * b + 1])
                            p += 1
                    # the coarse pairs' fits, feature by feature over all pairs (a loop the compiler vectorises)
                    for i in range(nc):
                        scores[i] = fr[0] * coarse_t[0 * nc + i]
                    for j in range(1, F):
                        for i in range(nc):
                            scores[i] = scores[i] + fr[j] * coarse_t[j * nc + i]
                    bc = _argmax(scores, nc)
                    best = fine_rows[bc * n_fine + _argmax_rows(fr, pair_feat, &fine_rows[bc * n_fine], 0, n_fine, F)]
                    lateral = rng[d] * pair_dsin[best]
                    # powers of the two fitted sources, diag(B+ R B+^H)
                    for a in range(2):
                        accr = 0.0
                        for r_ in range(n_rx):
                            br = pinv[(best * 2 + a) * W + 2 * r_]
                            bi = pinv[(best * 2 + a) * W + 2 * r_ + 1]
                            for s_ in range(n_rx):
                                qr = cov[(k * n_rx + r_) * W + 2 * s_]
                                qi = cov[(k * n_rx + r_) * W + 2 * s_ + 1]
                                tr = br * qr - bi * qi
                                ti = br * qi + bi * qr
                                accr = accr + (tr * <double>pinv[(best * 2 + a) * W + 2 * s_] + ti * <double>pinv[(best * 2 + a) * W + 2 * s_ + 1])
                        if a == 0:
                            pa0 = accr
                        else:
                            pa1 = accr
                    if isnan(pa0) or isnan(pa1):
                        ratio = NAN
                    else:
                        lo = pa0 if pa0 <= pa1 else pa1
                        hi = pa0 if pa0 >= pa1 else pa1
                        ratio = lo / (hi if hi >= 1e-30 else 1e-30)
                    if lateral >= min_lateral and ratio >= min_power_ratio:
                        now[d] = 1
                        ang[2 * d + 0] = pair_th[2 * best + 0]
                        ang[2 * d + 1] = pair_th[2 * best + 1]
        # a cell split in a few frames in a row only
        for d in range(n):
            k = match[d]
            if k < 0:
                continue
            cstreak[k] = cstreak[k] + 1 if now[d] else 0
            split[d] = now[d] and cstreak[k] >= min_split_frames
        for d in range(n):
            if not split[d]:
                ang[2 * d + 0] = NAN
                ang[2 * d + 1] = NAN
        # --- age, drop, create, cap
        for d in range(n):
            if match[d] >= 0:
                taken[match[d]] = 2  # (seen this frame)
        n_keep = 0
        for k in range(m):
            if taken[k] != 2:
                cmiss[k] += 1
            if cmiss[k] <= max_misses:
                n_keep += 1
        n_new = 0
        for d in range(n):
            if match[d] < 0:
                n_new += 1
        n_out = n_keep + n_new
        order = <Py_ssize_t *>malloc((n_out + 1) * sizeof(Py_ssize_t))  # >= 0: a cell, < 0: -1 - detection
        if order == NULL:
            raise MemoryError()
        i = 0
        for k in range(m):
            if cmiss[k] <= max_misses:
                order[i] = k
                i += 1
        for d in range(n):
            if match[d] < 0:
                order[i] = -1 - d
                i += 1
        if n_out > max_cells:  # the most recently seen (stable by misses; new cells have none)
            for i in range(1, n_out):
                j = i
                p = order[i]
                old = <double>(cmiss[p] if p >= 0 else 0)
                while j > 0 and <double>(cmiss[order[j - 1]] if order[j - 1] >= 0 else 0) > old:
                    order[j] = order[j - 1]
                    j -= 1
                order[j] = p
            n_out = max_cells
        o_range = _new(cnp.NPY_FLOAT64, n_out)
        o_v = _new(cnp.NPY_FLOAT64, n_out)
        o_cov = _empty3(cnp.NPY_COMPLEX64, n_out, n_rx, n_rx)
        o_n = _new(cnp.NPY_INT64, n_out)
        o_miss = _new(cnp.NPY_INT64, n_out)
        o_streak = _new(cnp.NPY_INT64, n_out)
        _fill(<double *>cnp.PyArray_DATA(<cnp.ndarray>o_range), <double *>cnp.PyArray_DATA(<cnp.ndarray>o_v),
              <float *>cnp.PyArray_DATA(<cnp.ndarray>o_cov), <long long *>cnp.PyArray_DATA(<cnp.ndarray>o_n),
              <long long *>cnp.PyArray_DATA(<cnp.ndarray>o_miss), <long long *>cnp.PyArray_DATA(<cnp.ndarray>o_streak),
              order, n_out, n_rx * W, crange, cv, cov, cn, cmiss, cstreak, rng, vel, rnew)
        return split_arr, ang_arr, two_arr, o_range, o_v, o_cov, o_n, o_miss, o_streak
    finally:
        free(match); free(taken); free(now); free(cand); free(p_el); free(lagf); free(w); free(scratch)
        free(fr); free(xr); free(xi); free(order); free(scores); free(crange); free(cn); free(cov)


cdef void _fill(double *o_range, double *o_v, float *o_cov, long long *o_n, long long *o_miss, long long *o_streak,
                Py_ssize_t *order, Py_ssize_t n_out, Py_ssize_t csize, const double *crange, const double *cv,
                const float *cov, const long long *cn, const long long *cmiss, const long long *cstreak,
                const float *rng, const float *vel, const float *rnew) noexcept nogil:
    """The new cell table's rows in ``order`` (>= 0: a cell, < 0: -1 - a new detection); ``csize`` floats a
    covariance."""
    cdef Py_ssize_t i, p, d
    for i in range(n_out):
        p = order[i]
        if p >= 0:
            o_range[i] = crange[p]
            o_v[i] = cv[p]
            o_n[i] = cn[p]
            o_miss[i] = cmiss[p]
            o_streak[i] = cstreak[p]
            memcpy(o_cov + i * csize, cov + p * csize, csize * sizeof(float))
        else:
            d = -1 - p
            o_range[i] = <double>rng[d]
            o_v[i] = <double>vel[d]
            o_n[i] = 1
            o_miss[i] = 0
            o_streak[i] = 0
            memcpy(o_cov + i * csize, rnew + d * csize, csize * sizeof(float))
