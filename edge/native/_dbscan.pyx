# cython: language_level=3
# distutils: extra_compile_args = -ffp-contract=off
"""DBSCAN stage kernel (edge.dsp.dbscan.CylinderDbscan.fit): the whole clustering of one thresholded range-Doppler
map in one call, with the labels of the numpy reference (CylinderDbscan.reference).

On the (range bin, Doppler bin) lattice whose Doppler axis is a circle, the eps-neighbourhood of a bin is, row by row
(range offset ``di``), a circular interval of Doppler offsets ``[-lo[di], hi[di]]`` (the reference's kernel
``d <= eps``, handed in by the caller). So:

1. neighbour counts: per point, one circular window sum per row offset that holds points, on per-row prefix sums of
   the mask (exact integers, as the reference's rounded FFT convolution);
2. core connectivity: union-find over core points, first with their 8-neighbours on the lattice (Doppler wrapping),
   then, when more than one group is left, from every boundary core point to every run of core bins inside its
   window (a run is one group already);
3. dense cluster ids in the order of each cluster's first core point in row-major order (the reference's order:
   ``ndimage.label`` numbers groups by first bin, the union keeps the smallest);
4. border points: the nearest boundary core point (squared distance in the cylinder coordinates ``[R cos, R sin, r]``,
   summed as the reference does) inside the window; ties go to the smallest cluster id.
"""

cimport cython
import numpy as np
cimport numpy as cnp
from libc.stdint cimport uint64_t
from libc.string cimport memcpy

cnp.import_array()


cdef inline int _find(int *parent, int x) noexcept nogil:
    cdef int r = x
    while parent[r] != r:
        r = parent[r]
    cdef int nxt
    while parent[x] != r:
        nxt = parent[x]
        parent[x] = r
        x = nxt
    return r


cdef inline void _union(int *parent, int a, int b) noexcept nogil:
    a = _find(parent, a)
    b = _find(parent, b)
    if a < b:
        parent[b] = a
    elif b < a:
        parent[a] = b


cdef inline int _link(int *parent, int a, int b) noexcept nogil:
    """Join the components of roots ``a != b`` (the smaller root stays); returns it."""
    if a < b:
        parent[b] = a
        return a
    parent[a] = b
    return b


cdef inline bint _row_empty(const cnp.uint8_t *r, Py_ssize_t nd) noexcept nogil:
    """No nonzero byte in ``r[0:nd]`` (eight bytes at a time)."""
    cdef Py_ssize_t j = 0
    cdef uint64_t w
    while j + 8 <= nd:
        memcpy(&w, r + j, 8)
        if w:
            return False
        j += 8
    while j < nd:
        if r[j]:
            return False
        j += 1
    return True


cdef inline int _wrap(int c, int nd) noexcept nogil:
    """Column ``c`` in ``[-nd, 2 nd)`` wrapped onto ``[0, nd)``."""
    if c < 0:
        return c + nd
    if c >= nd:
        return c - nd
    return c


cdef inline int _union_runs(int *parent, const int *idx, const int *nxt, const int *rend, int rk, int s,
                            int t) noexcept nogil:
    """Join the component of root ``rk`` with every run of core bins of a row (``idx``, ``nxt``, ``rend``) that meets
    columns ``s..t`` (one union per run); returns the joined component's root."""
    cdef int c = nxt[s]
    cdef int b
    while c <= t:
        b = _find(parent, idx[c])
        if b < rk:
            parent[rk] = b
            rk = b
        elif rk < b:
            parent[b] = rk
        c = nxt[rend[c] + 1]
    return rk


def fit(const cnp.uint8_t[:, ::1] mask, Py_ssize_t n, const int[::1] m_row, const int[::1] lo, const int[::1] hi,
        const double[::1] cosv, const double[::1] sinv, double range_bin_m):
    """Cluster the nonzero bins of ``mask`` ``(n_range, n_doppler)``, ``n`` of them.

    ``m_row`` (n_range,) core threshold per range row; ``lo``/``hi`` (2h+1,) the window of row offset ``di - h``;
    ``cosv``/``sinv`` (n_doppler,) the cylinder coordinates of each Doppler bin (km/h), ``range_bin_m`` metres per
    range bin. Returns ``(range_bin, doppler_bin, labels, core, n_clusters, counts)`` as the reference's Clusters.
    """
    cdef Py_ssize_t nr = mask.shape[0], nd = mask.shape[1]
    cdef int h = (lo.shape[0] - 1) // 2
    cdef Py_ssize_t i, j, k
    cdef int di, r2, c, a, b, e, p, q, m_i, jl, jr, rk
    cdef const cnp.uint8_t *mrow
    ri_a = np.empty(n, dtype=np.intp)
    dj_a = np.empty(n, dtype=np.intp)
    lab_a = np.full(n, -1, dtype=np.int32)
    core_a = np.zeros(n, dtype=np.bool_)
    cnt_a = np.zeros(n, dtype=np.int32)
    if n == 0:
        return ri_a, dj_a, lab_a, core_a, 0, cnt_a
    cdef Py_ssize_t[::1] ri = ri_a
    cdef Py_ssize_t[::1] dj = dj_a
    cdef int[::1] lab = lab_a
    cdef cnp.npy_bool[::1] core = core_a
    cdef int[::1] cnt = cnt_a
    # per-row prefix sums over three laps of the Doppler circle (columns -nd .. 2 nd - 1): every window sum is one
    # subtraction, without branches (written for the rows with points only)
    cdef Py_ssize_t w3 = 3 * nd + 1
    ext_a = np.empty((nr, w3), dtype=np.int32)
    win_a = np.empty((2, 2 * h + 1), dtype=np.intp)  # the prefix-sum addresses of the current row's window
    idx_a = np.empty((nr, nd), dtype=np.int32)  # point index of each core bin, -1 elsewhere (rows read only)
    row_n_a = np.zeros(nr, dtype=np.int32)
    row_c_a = np.zeros(nr, dtype=np.int32)  # core bins per row
    off_a = np.empty((2, 2 * h + 1), dtype=np.intp)
    cdef int[:, ::1] ext = ext_a
    cdef Py_ssize_t *wa = <Py_ssize_t *>cnp.PyArray_DATA(win_a)
    cdef Py_ssize_t *wb = wa + 2 * h + 1
    cdef int cur, nw = 0, t
    cdef int[:, ::1] idx = idx_a
    cdef int[::1] row_n = row_n_a
    cdef int[::1] row_c = row_c_a
    cdef Py_ssize_t[:, ::1] off = off_a
    parent_a = np.arange(n, dtype=np.int32)
    cdef int[::1] parent = parent_a
    cdef int *pp = &parent[0]
    cdef int n_core = 0, n_groups, n_clu = 0
    cdef double d2, best_d2, x0, x1, x2, t0, t1, t2
    cdef int best_lab, tot
    cdef int *er
    with nogil:
        for di in range(2 * h + 1):
            a = lo[di]
            b = hi[di]
            if a + b + 1 >= nd:  # the whole circle, once
                a = 0
                b = <int>nd - 1
            off[0, di] = b + 1 + nd
            off[1, di] = nd - a
        # points in row-major order, per-row prefix sums of the mask
        k = 0
        for i in range(nr):
            if k == n:
                break
            mrow = &mask[i, 0]
            if _row_empty(mrow, nd):  # its prefix row is never read
                continue
            er = &ext[i, 0]
            tot = 0
            for j in range(nd):
                if mrow[j] != 0:
                    ri[k] = i
                    dj[k] = j
                    k += 1
                    tot += 1
                er[nd + j + 1] = tot
            row_n[i] = tot
            if tot:
                er[nd] = 0
                for j in range(nd + 1):
                    er[j] = er[nd + j] - tot
                    er[2 * nd + j] = er[nd + j] + tot
        # idx is read on the rows with points and their two neighbours only
        for i in range(nr):
            if row_n[i] or (i > 0 and row_n[i - 1]) or (i + 1 < nr and row_n[i + 1]):
                for j in range(nd):
                    idx[i, j] = -1
        # 1. neighbour counts and core points: per map row, the window rows that hold points (the others add 0)
        # as the two prefix-sum addresses of each; points come row by row
        cur = -1
        for k in range(n):
            i = ri[k]
            j = dj[k]
            if i != cur:
                cur = <int>i
                nw = 0
                for di in range(2 * h + 1):  # window row di is map row i + di - h
                    r2 = cur + di - h
                    if 0 <= r2 < nr and row_n[r2] > 0:
                        wa[nw] = <Py_ssize_t>(&ext[r2, 0] + off[0, di])
                        wb[nw] = <Py_ssize_t>(&ext[r2, 0] + off[1, di])
                        nw += 1
            c = 0
            for t in range(nw):
                c += (<const int *>wa[t])[j] - (<const int *>wb[t])[j]
            cnt[k] = c
            if c >= m_row[i]:
                core[k] = True
                idx[i, j] = <int>k
                n_core += 1
                row_c[i] += 1
    if n_core == 0:
        return ri_a, dj_a, lab_a, core_a, 0, cnt_a
    # runs of core bins per row: next core bin at or after each column, end of the run at each core bin
    nxt_a = np.empty((nr, nd + 1), dtype=np.int32)
    cdef int[:, ::1] nxt = nxt_a
    rend_a = np.empty((nr, nd), dtype=np.int32)  # last column of the run of core bins through each core bin
    cdef int[:, ::1] rend = rend_a
    grp_a = np.empty(n, dtype=np.int32)
    cdef int[::1] grp = grp_a
    cdef int big = -1
    bnd_a = np.zeros(n, dtype=np.uint8)  # per point: a core bin with an 8-neighbour that is not core
    cdef cnp.uint8_t[::1] bnd = bnd_a
    with nogil:
        # 2. 8-connectivity (left, and the three bins of the row above; Doppler wraps). The row above is joined along
        # its own adjacent core bins already, so when the bin straight above is core its two neighbours add nothing.
        n_groups = n_core
        for k in range(n):
            if not core[k]:
                continue
            i = ri[k]
            j = dj[k]
            jl = <int>j - 1 if j > 0 else <int>nd - 1
            jr = <int>j + 1 if j < nd - 1 else 0
            rk = _find(pp, <int>k)
            q = idx[i, jl]
            if 0 <= q < k:
                b = _find(pp, q)
                if b != rk:
                    rk = _link(pp, rk, b)
                    n_groups -= 1
            q = idx[i, jr]
            if 0 <= q < k:
                b = _find(pp, q)
                if b != rk:
                    rk = _link(pp, rk, b)
                    n_groups -= 1
            if i > 0:
                q = idx[i - 1, j]
                if q >= 0:
                    b = _find(pp, q)
                    if b != rk:
                        rk = _link(pp, rk, b)
                        n_groups -= 1
                else:
                    for e in range(2):
                        q = idx[i - 1, jl if e == 0 else jr]
                        if q >= 0:
                            b = _find(pp, q)
                            if b != rk:
                                rk = _link(pp, rk, b)
                                n_groups -= 1
            # boundary: some 8-neighbour is not core (rows outside the map count as core)
            for di in range(-1, 2):
                r2 = <int>i + di
                if 0 <= r2 < nr and (idx[r2, jl] < 0 or idx[r2, j] < 0 or idx[r2, jr] < 0):
                    bnd[k] = 1
                    break
        if n_groups > 1:
            for i in range(nr):
                if row_n[i] == 0:
                    continue
                nxt[i, nd] = <int>nd
                for j in range(nd - 1, -1, -1):
                    if idx[i, j] >= 0:
                        nxt[i, j] = <int>j
                        rend[i, j] = rend[i, j + 1] if j + 1 < nd and idx[i, j + 1] >= 0 else <int>j
                    else:
                        nxt[i, j] = nxt[i, j + 1]
            # the largest lattice group's points need not search: every pair of groups within eps has one group
            # that is not the largest, and the window relation is symmetric
            for k in range(n):
                lab[k] = 0
            for k in range(n):
                if core[k]:
                    a = _find(pp, <int>k)
                    grp[k] = a
                    lab[a] += 1
                    if big < 0 or lab[a] > lab[big]:
                        big = a
            # boundary core bins: some 8-neighbour is not core (rows outside the map count as core)
            # (per map row, the window rows that hold core bins: row in wa, row offset + h in wb)
            cur = -1
            for k in range(n):
                if not bnd[k] or grp[k] == big:
                    continue
                i = ri[k]
                j = dj[k]
                if i != cur:
                    cur = <int>i
                    nw = 0
                    for di in range(-h, h + 1):
                        r2 = cur + di
                        if 0 <= r2 < nr and row_c[r2] > 0:
                            wa[nw] = r2
                            wb[nw] = di
                            nw += 1
                rk = _find(pp, <int>k)
                for t in range(nw):
                    r2 = <int>wa[t]
                    di = <int>wb[t]
                    a = lo[di + h]
                    b = hi[di + h]
                    if a + b + 1 >= nd:
                        a = 0
                        b = <int>nd - 1
                    else:
                        a = <int>j - a
                        b = <int>j + b
                    # columns a..b, circular: at most two linear segments; one union per run of core bins
                    if a < 0:
                        rk = _union_runs(pp, &idx[r2, 0], &nxt[r2, 0], &rend[r2, 0], rk, a + <int>nd, <int>nd - 1)
                        rk = _union_runs(pp, &idx[r2, 0], &nxt[r2, 0], &rend[r2, 0], rk, 0, b)
                    elif b >= nd:
                        rk = _union_runs(pp, &idx[r2, 0], &nxt[r2, 0], &rend[r2, 0], rk, a, <int>nd - 1)
                        rk = _union_runs(pp, &idx[r2, 0], &nxt[r2, 0], &rend[r2, 0], rk, 0, b - <int>nd)
                    else:
                        rk = _union_runs(pp, &idx[r2, 0], &nxt[r2, 0], &rend[r2, 0], rk, a, b)
        # 3. dense ids in order of first core point
        for k in range(n):
            lab[k] = -1
        for k in range(n):
            if core[k]:
                a = _find(pp, <int>k)
                if lab[a] < 0:  # the root is its component's smallest (first) point
                    lab[a] = n_clu
                    n_clu += 1
        for k in range(n):
            if core[k]:
                lab[k] = lab[_find(pp, <int>k)]
    # 4. border points (their nearest core bin is a boundary one, or one of the reference's seam columns)
    cdef bint any_border = False
    with nogil:
        for k in range(n):
            if not core[k]:
                any_border = True
                break
        if any_border:
            for k in range(n):
                if core[k] and (dj[k] == 0 or dj[k] == nd - 1):
                    bnd[k] = 1
            for k in range(n):
                if core[k]:
                    continue
                i = ri[k]
                j = dj[k]
                x0 = cosv[j]
                x1 = sinv[j]
                x2 = <double>i * range_bin_m
                best_d2 = 1e300
                best_lab = -1
                for di in range(-h, h + 1):
                    r2 = <int>i + di
                    if r2 < 0 or r2 >= nr or row_n[r2] == 0:
                        continue
                    a = lo[di + h]
                    b = hi[di + h]
                    if a + b + 1 >= nd:
                        a = 0
                        b = <int>nd - 1
                    else:
                        a = <int>j - a
                        b = <int>j + b
                    for c in range(a, b + 1):
                        m_i = _wrap(c, <int>nd)
                        p = idx[r2, m_i]
                        if p < 0 or not bnd[p]:
                            continue
                        t0 = x0 - cosv[m_i]
                        t1 = x1 - sinv[m_i]
                        t2 = x2 - <double>r2 * range_bin_m
                        d2 = (t0 * t0 + t1 * t1) + t2 * t2
                        q = lab[idx[r2, m_i]]
                        if d2 < best_d2 or (d2 == best_d2 and q < best_lab):
                            best_d2 = d2
                            best_lab = q
                lab[k] = best_lab
    return ri_a, dj_a, lab_a, core_a, n_clu, cnt_a
