# New arrays through the numpy C API (`include "_alloc.pxi"`; the including module does `cimport numpy as cnp` and
# `cnp.import_array()`). np.empty and np.zeros called from a kernel cost a module attribute lookup, a Python-level
# call and numpy's argument parsing; PyArray_EMPTY and PyArray_ZEROS make the same arrays (C order, the dtype of
# ``t``, zero-filled for the latter) without them.

cimport numpy as cnp


cdef inline cnp.ndarray _empty1(int t, Py_ssize_t n0):
    """``np.empty(n0, dtype)`` for the numpy type number ``t``."""
    cdef cnp.npy_intp d[1]
    d[0] = n0
    return cnp.PyArray_EMPTY(1, d, t, 0)


cdef inline cnp.ndarray _empty2(int t, Py_ssize_t n0, Py_ssize_t n1):
    """``np.empty((n0, n1), dtype)``."""
    cdef cnp.npy_intp d[2]
    d[0], d[1] = n0, n1
    return cnp.PyArray_EMPTY(2, d, t, 0)


cdef inline cnp.ndarray _empty3(int t, Py_ssize_t n0, Py_ssize_t n1, Py_ssize_t n2):
    """``np.empty((n0, n1, n2), dtype)``."""
    cdef cnp.npy_intp d[3]
    d[0], d[1], d[2] = n0, n1, n2
    return cnp.PyArray_EMPTY(3, d, t, 0)


cdef inline cnp.ndarray _empty4(int t, Py_ssize_t n0, Py_ssize_t n1, Py_ssize_t n2, Py_ssize_t n3):
    """``np.empty((n0, n1, n2, n3), dtype)``."""
    cdef cnp.npy_intp d[4]
    d[0], d[1], d[2], d[3] = n0, n1, n2, n3
    return cnp.PyArray_EMPTY(4, d, t, 0)


cdef inline cnp.ndarray _zeros1(int t, Py_ssize_t n0):
    """``np.zeros(n0, dtype)``."""
    cdef cnp.npy_intp d[1]
    d[0] = n0
    return cnp.PyArray_ZEROS(1, d, t, 0)


cdef inline cnp.ndarray _zeros2(int t, Py_ssize_t n0, Py_ssize_t n1):
    """``np.zeros((n0, n1), dtype)``."""
    cdef cnp.npy_intp d[2]
    d[0], d[1] = n0, n1
    return cnp.PyArray_ZEROS(2, d, t, 0)


cdef inline cnp.ndarray _zeros3(int t, Py_ssize_t n0, Py_ssize_t n1, Py_ssize_t n2):
    """``np.zeros((n0, n1, n2), dtype)``."""
    cdef cnp.npy_intp d[3]
    d[0], d[1], d[2] = n0, n1, n2
    return cnp.PyArray_ZEROS(3, d, t, 0)
