# Array arguments through the numpy C API instead of typed memoryviews (`include "_arrays.pxi"`; the including
# module does `cimport numpy as cnp` and `cnp.import_array()`). A memoryview argument costs a call about 1.4 k
# instructions (numpy's buffer export and the memoryview object); these checks cost a few dozen.

cimport numpy as cnp


cdef inline void *_data(object a, int typenum, Py_ssize_t n, bint writable, str name) except NULL:
    """Data pointer of ``a``: a 1-D numpy array of ``typenum`` (an equivalent type of the same size passes), ``n``
    elements, C-contiguous, aligned, in native byte order (and writable with ``writable``). ValueError otherwise."""
    cdef cnp.ndarray arr
    if not cnp.PyArray_Check(a):
        raise TypeError(f"{name}: a numpy array is needed, not {type(a).__name__}")
    arr = <cnp.ndarray>a
    if not (cnp.PyArray_NDIM(arr) == 1 and cnp.PyArray_DIM(arr, 0) == n
            and cnp.PyArray_EquivTypenums(cnp.PyArray_TYPE(arr), typenum)
            and cnp.PyArray_ISCARRAY_RO(arr) and (not writable or cnp.PyArray_ISWRITEABLE(arr))):
        raise ValueError(f"{name}: ({n},) {cnp.PyArray_DescrFromType(typenum)} C-contiguous, aligned, native "
                         f"array needed, got {a.dtype} {a.shape}")
    # (a valid pointer even for n = 0: numpy allocates at least one element)
    return cnp.PyArray_DATA(arr)


cdef inline cnp.ndarray _new(int typenum, Py_ssize_t n):
    """A new uninitialised 1-D array of ``n`` elements of ``typenum``."""
    cdef cnp.npy_intp dims[1]
    dims[0] = n
    return cnp.PyArray_EMPTY(1, dims, typenum, 0)


cdef inline void *_data2(object a, int typenum, Py_ssize_t n0, Py_ssize_t n1, bint writable, str name) except NULL:
    """:func:`_data` of a 2-D ``(n0, n1)`` array."""
    cdef cnp.ndarray arr
    if not cnp.PyArray_Check(a):
        raise TypeError(f"{name}: a numpy array is needed, not {type(a).__name__}")
    arr = <cnp.ndarray>a
    if not (cnp.PyArray_NDIM(arr) == 2 and cnp.PyArray_DIM(arr, 0) == n0 and cnp.PyArray_DIM(arr, 1) == n1
            and cnp.PyArray_EquivTypenums(cnp.PyArray_TYPE(arr), typenum)
            and cnp.PyArray_ISCARRAY_RO(arr) and (not writable or cnp.PyArray_ISWRITEABLE(arr))):
        raise ValueError(f"{name}: ({n0}, {n1}) {cnp.PyArray_DescrFromType(typenum)} C-contiguous, aligned, native "
                         f"array needed, got {a.dtype} {a.shape}")
    return cnp.PyArray_DATA(arr)


cdef inline void *_data3(object a, int typenum, Py_ssize_t n0, Py_ssize_t n1, Py_ssize_t n2, bint writable,
                         str name) except NULL:
    """:func:`_data` of a 3-D ``(n0, n1, n2)`` array."""
    cdef cnp.ndarray arr
    if not cnp.PyArray_Check(a):
        raise TypeError(f"{name}: a numpy array is needed, not {type(a).__name__}")
    arr = <cnp.ndarray>a
    if not (cnp.PyArray_NDIM(arr) == 3 and cnp.PyArray_DIM(arr, 0) == n0 and cnp.PyArray_DIM(arr, 1) == n1
            and cnp.PyArray_DIM(arr, 2) == n2 and cnp.PyArray_EquivTypenums(cnp.PyArray_TYPE(arr), typenum)
            and cnp.PyArray_ISCARRAY_RO(arr) and (not writable or cnp.PyArray_ISWRITEABLE(arr))):
        raise ValueError(f"{name}: ({n0}, {n1}, {n2}) {cnp.PyArray_DescrFromType(typenum)} C-contiguous, aligned, "
                         f"native array needed, got {a.dtype} {a.shape}")
    return cnp.PyArray_DATA(arr)


cdef inline object _as_c(object a, int typenum):
    """``a`` itself when it is a C-contiguous aligned native numpy array of ``typenum``, else
    ``np.ascontiguousarray(a, dtype)`` (hold the result while its data is read)."""
    if (cnp.PyArray_Check(a) and cnp.PyArray_TYPE(<cnp.ndarray>a) == typenum
            and cnp.PyArray_ISCARRAY_RO(<cnp.ndarray>a)):
        return a
    import numpy
    return numpy.ascontiguousarray(a, dtype=cnp.PyArray_DescrFromType(typenum))
