# cython: language_level=3
# distutils: extra_compile_args = -ffp-contract=off
"""Cluster sums of the surveillance signatures (edge.classify.features.SignatureExtractor): every per-cluster sum,
maximum and span of one frame's points and eq. 17's cell selection in one pass, in place of the reference's bincounts,
ufunc.at calls and full-map grids (the reference runs where the pass declines: no valid label, a negative bin).

Sums are accumulated in double in point order, as ``np.bincount`` does with its (float32 -> double) weights; the
amplitude-weighted terms are float32 products, as the reference's ``amp * cos``; so the results are bit-identical.
"""

cimport cython


@cython.cdivision(True)
def signature_pass(const int[::1] lab, const float[::1] rng, const float[::1] amp, const float[::1] cos,
                   const float[::1] sin, const int[::1] rb, const int[::1] db, float ratio, float gate_cos,
                   double[:, ::1] out, float[::1] peak, unsigned char[::1] rcs_peak, int[::1] scratch):
    """Per cluster ``k`` (labels ``0..L-1``, ``L = out.shape[1]``; points with other labels are skipped), rows of
    ``out``: 0 cells, 1 sum cos, 2 sum sin, 3 sum range (m), 4 sum amp*cos, 5 sum amp*sin, 6 lowest and 7 highest range
    (m) of the cells at or above ``ratio`` times the cluster's strongest amplitude, 8 and 9 the same of those cells
    whose angle's cos and sin give a dot product with the strongest cell's (the first of equals) of at least
    ``gate_cos`` (NaN for a cluster without cells); ``peak`` (3 L,) float32 scratch: the strongest amplitude of each
    cluster on return, then that cell's cos and sin. And the cells that
    eq. 17 sums (the reference's ``SignatureExtractor._rcs`` selection): ``rcs_peak[i] = 1`` when point ``i`` is
    above the cell one range bin below it and not below the one above, each counted only when it is a point of
    the same cluster (the last point given for a cell stands for it). ``scratch`` (int32) holds at least
    ``(rows + 1) * columns`` entries of the points' (range, Doppler) bin box. Returns the number of points with a
    valid label; -1 when a bin is negative, ``-2 - size`` when ``scratch`` is smaller than ``size`` (``rcs_peak`` not
    written in either case)."""
    cdef Py_ssize_t P = lab.shape[0], L = out.shape[1], i, k, n = 0, g
    cdef int r0 = 0, r1 = -1, d1 = -1, w, q
    cdef double r
    cdef float a
    cdef bint up, down
    for k in range(L):
        peak[k] = 0.0
        for i in range(6):
            out[i, k] = 0.0
        out[6, k] = float("inf")
        out[7, k] = float("-inf")
        out[8, k] = float("inf")
        out[9, k] = float("-inf")
    for i in range(P):
        k = lab[i]
        if k < 0 or k >= L:
            continue
        if n == 0 or rb[i] < r0:
            r0 = rb[i]
        if rb[i] > r1:
            r1 = rb[i]
        if db[i] > d1:
            d1 = db[i]
        if db[i] < 0:
            r0 = -1
        n += 1
        a = amp[i]
        out[0, k] += 1.0
        out[1, k] += <double>cos[i]
        out[2, k] += <double>sin[i]
        out[3, k] += <double>rng[i]
        out[4, k] += <double>(<float>(a * cos[i]))
        out[5, k] += <double>(<float>(a * sin[i]))
        if a > peak[k]:
            peak[k] = a
            peak[L + k] = cos[i]
            peak[2 * L + k] = sin[i]
    for i in range(P):
        k = lab[i]
        if k < 0 or k >= L:
            continue
        if amp[i] >= <float>(peak[k] * ratio):
            r = <double>rng[i]
            if r < out[6, k]:
                out[6, k] = r
            if r > out[7, k]:
                out[7, k] = r
            if peak[k] <= 0.0 or <float>(<float>(cos[i] * peak[L + k]) + <float>(sin[i] * peak[2 * L + k])) >= gate_cos:
                if r < out[8, k]:
                    out[8, k] = r
                if r > out[9, k]:
                    out[9, k] = r
    for k in range(L):
        if out[6, k] == float("inf"):
            out[6, k] = float("nan")
            out[7, k] = float("nan")
        if out[8, k] == float("inf"):
            out[8, k] = float("nan")
            out[9, k] = float("nan")
    if n == 0:
        return 0
    w = d1 + 1
    if r0 < 0:
        return -1
    if <Py_ssize_t>(r1 - r0 + 2) * w > scratch.shape[0]:
        return -2 - <Py_ssize_t>(r1 - r0 + 2) * w
    # point index of each cell of rows r0 .. r1 + 1 (the last one empty), -1 elsewhere
    for g in range(<Py_ssize_t>(r1 - r0 + 2) * w):
        scratch[g] = -1
    for i in range(P):
        k = lab[i]
        if 0 <= k < L:
            scratch[<Py_ssize_t>(rb[i] - r0) * w + db[i]] = <int>i
    for i in range(P):
        k = lab[i]
        rcs_peak[i] = 0
        if k < 0 or k >= L:
            continue
        g = <Py_ssize_t>(rb[i] - r0) * w + db[i]
        q = scratch[g - w] if rb[i] > r0 else -1
        down = q < 0 or lab[q] != k or amp[i] > amp[q]
        q = scratch[g + w]
        up = q < 0 or lab[q] != k or amp[i] >= amp[q]
        rcs_peak[i] = down and up
    return n
