"""Bartlett (conventional beamformer) angle estimation on a uniform linear array (Lim §III-A-2).

Element ``m`` (0-based, left to right) of a ULA with spacing ``d`` sees a far-field target at azimuth
``theta`` (right +) with phase ``-2 pi m d sin(theta) / lambda`` relative to element 0, so the steering
vector is ``a_m(theta) = exp(-j 2 pi m d sin(theta) / lambda)``. The Bartlett spectrum of snapshots
``x_s`` (``s`` = chirp segments, a few looks at the same target) is

    P(theta) = sum_s |a(theta)^H x_s|^2 / (a^H a)

and the estimate is its maximum on a grid refined by a parabola. With ``d = 1.5 lambda`` the
spectrum repeats every ``asin(lambda / d)``: the grid spans the unambiguous sector
``|theta| < asin(lambda / (2 d))`` (19.5 deg), which covers the antenna's field of view.
A per-channel calibration vector ``c_m`` (complex gain of each receive path) is divided out first.
"""

from __future__ import annotations

import numpy as np


_NEIGHBOURS = np.array([-1, 0, 1])
_CONJ: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # id(steering) -> (steering, steering.conj())


def _conj_t(steering: np.ndarray) -> np.ndarray:
    """``steering.conj().T`` with the conjugate computed once per steering matrix (the pipeline passes the same
    one every frame). The same transposed view of a contiguous conjugate as before: BLAS picks its kernel by
    the layout, and a contiguous transpose sums a single look's product in another order."""
    hit = _CONJ.get(id(steering))
    if hit is None or hit[0] is not steering:
        if len(_CONJ) > 8:
            _CONJ.clear()
        hit = _CONJ[id(steering)] = (steering, steering.conj())
    return hit[1].T


def beamform(snapshots: np.ndarray, steering: np.ndarray) -> np.ndarray:
    """``a^H x`` for every grid angle: ``snapshots`` complex64 ``(n_det, n_snap, n_rx)``, ``steering`` ``(n_grid,
    n_rx)`` -> complex64 ``(n_det, n_snap, n_grid)`` (the product :func:`bartlett_consensus` starts from)."""
    return snapshots @ _conj_t(steering)


def steering_matrix(n_rx: int, spacing_m: float, wavelength_m: float, grid_rad: np.ndarray) -> np.ndarray:
    """``(n_grid, n_rx)`` complex64 steering vectors, normalised to unit norm."""
    m = np.arange(n_rx)
    a = np.exp(-2j * np.pi * np.outer(np.sin(grid_rad), m) * spacing_m / wavelength_m) / np.sqrt(n_rx)
    return a.astype(np.complex64)


def bartlett(snapshots: np.ndarray, steering: np.ndarray, grid_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Angle of each detection.

    ``snapshots``: complex64 ``(n_det, n_snap, n_rx)`` (calibrated); ``steering``: ``(n_grid, n_rx)``
    from :func:`steering_matrix`; ``grid_rad``: ``(n_grid,)`` uniform. Returns ``(az_rad (n_det,)
    float32, spectrum (n_det, n_grid) float32)``.
    """
    if snapshots.shape[0] == 0:
        return np.zeros(0, np.float32), np.zeros((0, grid_rad.size), np.float32)
    y = snapshots @ steering.conj().T  # (n_det, n_snap, n_grid) = a^H x
    spec = (y.real * y.real + y.imag * y.imag).sum(axis=1).astype(np.float32)
    k = np.argmax(spec, axis=1)
    kk = np.clip(k, 1, grid_rad.size - 2)
    rows = np.arange(spec.shape[0])
    pm, p0, pp = spec[rows, kk - 1], spec[rows, kk], spec[rows, kk + 1]
    den = pm - 2.0 * p0 + pp
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.where((den < 0) & (k == kk), 0.5 * (pm - pp) / den, 0.0)
    step = grid_rad[1] - grid_rad[0]
    az = grid_rad[kk] + np.clip(d, -0.5, 0.5) * step
    az = np.where(k == kk, az, grid_rad[k])
    return az.astype(np.float32), spec


def bartlett_consensus(snapshots: np.ndarray, steering: np.ndarray, grid_rad: np.ndarray,
                       outlier_rad: float | np.ndarray, peak_bins: np.ndarray | None = None,
                       shared_bins: int = 1, min_agreeing: int = 3, min_clean: int = 2,
                       speeds: np.ndarray | None = None,
                       min_speed_diff: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Bartlett with per-snapshot normalisation and outlier rejection.

    In a busy scene one segment's peak bin can also hold another vehicle (the beats of two vehicles
    coincide in one segment only, because the four slopes map range and speed differently). Each
    snapshot's spectrum is normalised to unit power so every segment votes equally; snapshots whose own
    maximum lies more than ``outlier_rad`` from the median of the per-snapshot maxima are dropped, and
    the rest are summed and refined as in :func:`bartlett`. ``outlier_rad`` is a scalar or one value per
    detection ``(n_det,)``.

    A visitor weaker than the vehicle, or at an angle within ``outlier_rad`` of it, pulls the look's maximum
    only part of the way and passes that test. With ``peak_bins`` ``(n_det, n_snap)`` (each detection's FFT
    bin in each look, e.g. its pairing's peaks), a look whose bin lies within ``shared_bins`` of another
    accepted detection's bin in the same look (accepted: at least ``min_agreeing`` agreeing looks) holds both
    vehicles: it still votes in the median and counts as agreeing, but is left out of the sum when at least
    ``min_clean`` agreeing looks remain without it. With ``speeds`` ``(n_det,)``, only a detection whose speed
    differs by more than ``min_speed_diff`` counts as another vehicle (the scatterers of one vehicle pair into
    several detections of one speed, a bin or two apart, and share looks without harm).

    Returns ``(az_rad (n_det,), spectrum (n_det, n_grid), kept (n_det, n_snap) bool, used (n_det, n_snap)
    bool)``: ``kept`` the looks that agree on the angle, ``used`` those summed (``kept`` without the shared
    ones where enough remain; ``kept`` itself without ``peak_bins``).
    """
    n_det, n_snap, _ = snapshots.shape
    if n_det == 0:
        none = np.zeros((0, n_snap), bool)
        return np.zeros(0, np.float32), np.zeros((0, grid_rad.size), np.float32), none, none
    y = beamform(snapshots, steering)  # (n_det, n_snap, n_grid)
    q = y.view(y.real.dtype)  # (n_det, n_snap, 2 n_grid): re, im interleaved
    q = q * q
    p = q[..., 0::2] + q[..., 1::2]  # re * re + im * im (float32), in two calls instead of three
    # (ufunc reductions: the values of ndarray.max/.sum without their wrappers; a few us a call at this size)
    p /= np.maximum(np.maximum.reduce(p, axis=2, keepdims=True), np.float32(1e-30))
    each = grid_rad[np.argmax(p, axis=2)]  # (n_det, n_snap)
    # median over the few snapshots (np.median's value: the middle one, or the mean of the middle two)
    srt = np.sort(each, axis=1)
    h = n_snap // 2
    med = srt[:, h:h + 1] if n_snap % 2 else (srt[:, h - 1:h] + srt[:, h:h + 1]) / 2
    kept = np.abs(each - med) <= (outlier_rad[:, None] if np.ndim(outlier_rad) else outlier_rad)
    used = kept
    if peak_bins is not None and n_det > 1:
        shared = shared_looks(peak_bins, shared_bins, np.add.reduce(kept, axis=1) >= min_agreeing, speeds,
                              min_speed_diff)
        if shared.any():
            clean = kept & ~shared
            enough = np.add.reduce(clean, axis=1) >= min_clean
            used = np.where(enough[:, None], clean, kept)
    spec = np.add.reduce(p * used[..., None], axis=1)
    k = np.argmax(spec, axis=1)
    if n_det <= _SMALL:
        return _refine_small(spec, k, grid_rad), spec.astype(np.float32, copy=False), kept, used
    kk = np.minimum(np.maximum(k, 1), grid_rad.size - 2)  # np.clip, without its wrapper (5 us on a few ints)
    # the maximum and its two neighbours in one gather
    pm, p0, pp = spec.take(kk[:, None] + (np.arange(n_det) * spec.shape[1])[:, None] + _NEIGHBOURS).T
    den = pm - 2.0 * p0 + pp
    inner = k == kk
    d = np.zeros(den.shape, den.dtype)
    np.divide(0.5 * (pm - pp), den, out=d, where=(den < 0) & inner)
    step = grid_rad[1] - grid_rad[0]
    az = np.where(inner, grid_rad[kk] + np.minimum(np.maximum(d, -0.5), 0.5) * step, grid_rad[k])
    return az.astype(np.float32, copy=False), spec.astype(np.float32, copy=False), kept, used


def shared_looks(peak_bins: np.ndarray, within: int, among: np.ndarray, speeds: np.ndarray | None = None,
                 min_speed_diff: float = 0.0) -> np.ndarray:
    """``(n, looks)`` bool: the looks in which a detection's bin lies within ``within`` bins of the bin of another
    detection marked in ``among`` ``(n,)`` bool (``peak_bins`` ``(n, looks)`` int); with ``speeds`` ``(n,)``, of
    another whose speed differs by more than ``min_speed_diff``."""
    other = peak_bins[among]  # (m, looks)
    near = np.abs(peak_bins[:, None, :] - other[None, :, :]) <= within  # (n, m, looks)
    if np.count_nonzero(near) == near.shape[1] * near.shape[2]:  # only each of ``among`` with itself (most frames)
        return np.zeros(peak_bins.shape, bool)
    rows = np.flatnonzero(among)
    near[rows, np.arange(rows.size)] = False  # not with itself
    if speeds is not None:
        near &= (np.abs(speeds[:, None] - speeds[None, among]) > min_speed_diff)[:, :, None]
    return np.logical_or.reduce(near, axis=1)


#: up to this many detections :func:`bartlett_consensus` refines the maxima one by one with NumPy scalars (more:
#: the array form is cheaper)
_SMALL = 10


def _refine_small(spec: np.ndarray, k: np.ndarray, grid_rad: np.ndarray) -> np.ndarray:
    """The parabolic refinement of :func:`bartlett_consensus` (its last eight lines) one detection at a time:
    the same operations on NumPy scalars of the arrays' own types (float32 arithmetic for float32 spectra, the
    Python constants weakly typed as in the array form), so the same values; a few detections cost a couple of
    microseconds each instead of twenty array calls."""
    top = grid_rad.size - 2
    step = grid_rad[1] - grid_rad[0]
    zero = spec.dtype.type(0)
    az = []
    for row, ki in zip(spec, k.tolist()):
        if 1 <= ki <= top:
            pm, p0, pp = row[ki - 1], row[ki], row[ki + 1]
            den = pm - 2.0 * p0 + pp
            d = 0.5 * (pm - pp) / den if den < 0 else zero
            az.append(grid_rad[ki] + min(max(d, -0.5), 0.5) * step)  # (a NaN passes like np.minimum/maximum's)
        else:
            az.append(grid_rad[ki])
    return np.array(az).astype(np.float32, copy=False)


def peak_coherence(snapshots: np.ndarray, steering: np.ndarray, k: np.ndarray, kept: np.ndarray) -> np.ndarray:
    """Fraction of the kept looks' energy that the steering vector at grid index ``k`` holds, per detection:
    ``sum_s |a_k^H x_s|^2 / sum_s |x_s|^2`` over the kept looks ``s`` (``steering`` rows of unit norm). 1 for one
    point source, lower when the cell holds scatterers at several angles (the two sides of a truck's body in one
    range bin) or noise. ``snapshots`` (n, looks, rx), ``k`` (n,) int, ``kept`` (n, looks) bool -> (n,) float32."""
    if snapshots.shape[0] == 0:
        return np.zeros(0, np.float32)
    a = steering.take(k, axis=0).conj()  # (n, rx)
    y = np.einsum("nsr,nr->ns", snapshots, a)
    p = (y.real * y.real + y.imag * y.imag) * kept
    e = np.add.reduce((snapshots.real * snapshots.real + snapshots.imag * snapshots.imag), axis=2) * kept
    return (np.add.reduce(p, axis=1) / np.maximum(np.add.reduce(e, axis=1), np.float32(1e-30))).astype(np.float32)
