# Strided array arguments through the numpy C API instead of typed memoryviews (`include "_views.pxi"`; the including
# module does `cimport numpy as cnp` and `cnp.import_array()`). A memoryview argument costs a call about 1.4-2 k
# instructions (numpy's buffer export, the memoryview object, its release); `_aview` checks the array in a few dozen.
# Element (i, j, ...) of a `_V` is at data + i * s[0] + j * s[1] + ...; the accessors return its address.

cimport numpy as cnp


cdef struct _V:
    char* data
    Py_ssize_t n[4]  # shape
    Py_ssize_t s[4]  # strides in bytes


cdef int _aview(object a, int typenum, int nd, bint writable, bint contig, _V* v, str name) except -1:
    """Fill ``v`` from ``a``: a numpy array of ``nd`` dimensions and ``typenum`` (an equivalent type passes; bool and
    uint8 pass for each other), aligned, in native byte order, of any strides (C-contiguous with ``contig``, writable
    with ``writable``). TypeError or ValueError otherwise."""
    cdef cnp.ndarray arr
    cdef int t, i
    if not cnp.PyArray_Check(a):
        raise TypeError(f"{name}: a numpy array is needed, not {type(a).__name__}")
    arr = <cnp.ndarray>a
    t = cnp.PyArray_TYPE(arr)
    if not (cnp.PyArray_NDIM(arr) == nd
            and (cnp.PyArray_EquivTypenums(t, typenum)
                 or ((typenum == cnp.NPY_BOOL or typenum == cnp.NPY_UINT8)
                     and (t == cnp.NPY_BOOL or t == cnp.NPY_UINT8)))
            and cnp.PyArray_ISALIGNED(arr) and cnp.PyArray_ISNOTSWAPPED(arr)
            and (not writable or cnp.PyArray_ISWRITEABLE(arr)) and (not contig or cnp.PyArray_IS_C_CONTIGUOUS(arr))):
        raise ValueError(f"{name}: {nd}-D {cnp.PyArray_DescrFromType(typenum)} aligned native "
                         f"{'C-contiguous ' if contig else ''}{'writable ' if writable else ''}array needed, got {a.dtype} {a.shape}")
    v.data = cnp.PyArray_BYTES(arr)
    for i in range(4):
        v.n[i] = cnp.PyArray_DIM(arr, i) if i < nd else 0
        v.s[i] = cnp.PyArray_STRIDE(arr, i) if i < nd else 0
    return 0


cdef inline double* _pd1(_V v, Py_ssize_t i) noexcept nogil:
    return <double*>(v.data + i * v.s[0])


cdef inline double* _pd2(_V v, Py_ssize_t i, Py_ssize_t j) noexcept nogil:
    return <double*>(v.data + i * v.s[0] + j * v.s[1])


cdef inline double* _pd3(_V v, Py_ssize_t i, Py_ssize_t j, Py_ssize_t k) noexcept nogil:
    return <double*>(v.data + i * v.s[0] + j * v.s[1] + k * v.s[2])


cdef inline double* _pd4(_V v, Py_ssize_t i, Py_ssize_t j, Py_ssize_t k, Py_ssize_t l) noexcept nogil:
    return <double*>(v.data + i * v.s[0] + j * v.s[1] + k * v.s[2] + l * v.s[3])


cdef inline float* _pf1(_V v, Py_ssize_t i) noexcept nogil:
    return <float*>(v.data + i * v.s[0])


cdef inline float* _pf2(_V v, Py_ssize_t i, Py_ssize_t j) noexcept nogil:
    return <float*>(v.data + i * v.s[0] + j * v.s[1])


cdef inline cnp.int64_t* _pi64_2(_V v, Py_ssize_t i, Py_ssize_t j) noexcept nogil:
    return <cnp.int64_t*>(v.data + i * v.s[0] + j * v.s[1])


cdef inline long long* _pll(_V v, Py_ssize_t i) noexcept nogil:
    return <long long*>(v.data + i * v.s[0])


cdef inline long long* _pll_2(_V v, Py_ssize_t i, Py_ssize_t j) noexcept nogil:
    return <long long*>(v.data + i * v.s[0] + j * v.s[1])


cdef inline cnp.int32_t* _pi32(_V v, Py_ssize_t i) noexcept nogil:
    return <cnp.int32_t*>(v.data + i * v.s[0])


cdef inline cnp.uint32_t* _pu32(_V v, Py_ssize_t i) noexcept nogil:
    return <cnp.uint32_t*>(v.data + i * v.s[0])


cdef inline cnp.int64_t* _pi64(_V v, Py_ssize_t i) noexcept nogil:
    return <cnp.int64_t*>(v.data + i * v.s[0])


cdef inline cnp.uint8_t* _pu8(_V v, Py_ssize_t i) noexcept nogil:
    return <cnp.uint8_t*>(v.data + i * v.s[0])


cdef inline cnp.uint8_t* _pu8_2(_V v, Py_ssize_t i, Py_ssize_t j) noexcept nogil:
    return <cnp.uint8_t*>(v.data + i * v.s[0] + j * v.s[1])


cdef inline _V _sub(_V v, int drop, int step) noexcept nogil:
    """With ``drop`` 1: element 0 of every axis after the first (``a[:, 0]``, ``a[:, 0, 0]``), a 1-D view; with
    ``drop`` 0: every ``step``-th element of the axes after the first (``a[:, ::2]``, ``a[:, ::2, ::2]``)."""
    cdef _V out = v
    cdef int i
    for i in range(1, 4):
        if drop:
            out.n[i] = 0
            out.s[i] = 0
        else:
            out.n[i] = (v.n[i] + step - 1) // step
            out.s[i] = v.s[i] * step
    return out
