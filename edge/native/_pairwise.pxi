# numpy's pairwise summation in C, included by the kernels that reproduce a numpy sum bit for bit
# (`include "_pairwise.pxi"`; a .pxi is compiled into each module that includes it).

cdef double _pairwise_sum(const double *a, Py_ssize_t n) noexcept nogil:
    """``np.add.reduce`` of ``n`` contiguous float64 values, as numpy sums them: sequential below 8 terms, eight
    interleaved partial sums up to 128, halves (at a multiple of 8) beyond; so the sum is bit-identical to numpy's."""
    cdef Py_ssize_t i, j, n2
    cdef double res
    cdef double r[8]
    if n < 8:
        res = 0.0
        for i in range(n):
            res = res + a[i]
        return res
    if n <= 128:
        for j in range(8):
            r[j] = a[j]
        i = 8
        while i < n - (n % 8):
            for j in range(8):
                r[j] = r[j] + a[i + j]
            i += 8
        res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
        while i < n:
            res = res + a[i]
            i += 1
        return res
    n2 = n // 2
    n2 -= n2 % 8
    return _pairwise_sum(a, n2) + _pairwise_sum(a + n2, n - n2)
