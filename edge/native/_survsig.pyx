# cython: language_level=3
# distutils: extra_compile_args = -ffp-contract=off
"""Cluster sums of the surveillance signatures (edge.classify.features.SignatureExtractor): every per-cluster sum,
maximum and span of one frame's points in one pass, in place of the reference's bincounts and ufunc.at calls.

Sums are accumulated in double in point order, as ``np.bincount`` does with its (float32 -> double) weights; the
amplitude-weighted terms are float32 products, as the reference's ``amp * cos``; so the results are bit-identical.
"""

cimport cython


@cython.cdivision(True)
def cluster_sums(const long[::1] lab, const float[::1] rng, const float[::1] amp, const float[::1] cos,
                 const float[::1] sin, float ratio, double[:, ::1] out, float[::1] peak):
    """Per cluster ``k`` (labels ``0..L-1``, ``L = out.shape[1]``, all points valid), rows of ``out``:
    0 cells, 1 sum cos, 2 sum sin, 3 sum range (m), 4 sum amp*cos, 5 sum amp*sin, 6 lowest and 7 highest range (m)
    of the cells at or above ``ratio`` times the cluster's strongest amplitude (NaN for a cluster without cells).
    ``peak`` (L,) float32 scratch: the strongest amplitude of each cluster on return."""
    cdef Py_ssize_t P = lab.shape[0], L = out.shape[1], i, k
    cdef double r
    cdef float a
    for k in range(L):
        peak[k] = 0.0
        for i in range(6):
            out[i, k] = 0.0
        out[6, k] = float("inf")
        out[7, k] = float("-inf")
    for i in range(P):
        k = lab[i]
        a = amp[i]
        out[0, k] += 1.0
        out[1, k] += <double>cos[i]
        out[2, k] += <double>sin[i]
        out[3, k] += <double>rng[i]
        out[4, k] += <double>(<float>(a * cos[i]))
        out[5, k] += <double>(<float>(a * sin[i]))
        if a > peak[k]:
            peak[k] = a
    for i in range(P):
        k = lab[i]
        if amp[i] >= <float>(peak[k] * ratio):
            r = <double>rng[i]
            if r < out[6, k]:
                out[6, k] = r
            if r > out[7, k]:
                out[7, k] = r
    for k in range(L):
        if out[6, k] == float("inf"):
            out[6, k] = float("nan")
            out[7, k] = float("nan")
