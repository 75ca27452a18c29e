"""Range-Doppler maps of the surveillance profile (Tavanti eq. 4) and the cylinder wrapping (eqs. 5-8).

:class:`RangeDopplerProcessor` is built once per front end: canceller matrix, Kaiser windows with
shape factor ``K_sf`` (the ``beta`` of ``scipy.signal.windows.kaiser``) on fast time and slow time,
axes. Per frame::

    iq (n_rx, N_c, N_s) complex64
      -> IIR canceller along chirps, first chirp dropped          (N_c - 1, N_s)
      -> Kaiser w_r, range FFT zero-padded to N_R, keep [0, N_R/2) (N_c - 1, N_R/2)
      -> Kaiser w_D, Doppler FFT zero-padded to N_D, centred       (N_R/2, N_D) after transpose

Map layout: ``amplitude[i, j]``, ``i`` range bin (``range_m[i] = i * fs / N_R * c / (2 S)``, 0 to the
unambiguous range ``N_s c / (4 B)``), ``j`` Doppler bin after ``fftshift``: radial speed
``v[j] = (j - N_D/2) * lambda / (2 N_D T_PRI)`` in ``[-v_max, v_max)``, positive receding (a receding
scatterer advances the slow-time phase: the slow-time frequency is ``-f_D = 2 v / lambda``). Speeds
beyond ``±v_max`` (5.4 km/h on the Distance2Go) alias, exactly as on the board.

Amplitude scale: ``|FFT| / (sum(w_r) sum(w_D))``, i.e. a complex tone of ``A`` ADC counts that the
canceller passes with gain ``g`` reads ``g A`` at its peak. ``th_RD`` is in these units (counts).

Cylinder (eq. 6), speeds in km/h and ranges in metres (DESIGN §5): ``theta = pi (v + v_max) / v_max``
(``theta[j] = 2 pi j / N_D``), ``[v', v''] = (v_max / pi) [cos theta, sin theta]``, height ``r``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.fft
import scipy.signal

from edge.dsp.mti import iir_canceller, iir_canceller_matrix
from edge.types import FrontendInfo
from hal.waveform import SPEED_OF_LIGHT_MPS


@dataclass(frozen=True, eq=False)
class RangeDopplerMap:
    """One frame's map and what it was made from (for plots and features)."""

    amplitude: np.ndarray  # (n_range, n_doppler) float32, counts
    filtered: np.ndarray  # (N_c - 1, N_s) complex64: canceller output of the first channel


class RangeDopplerProcessor:
    """IIR canceller + windowed, zero-padded 2-D FFT, positive range half kept (Tavanti eq. 4)."""

    def __init__(
        self,
        frontend: FrontendInfo,
        *,
        k_c: float = 0.5,
        k_sf: float = 3.0,
        n_range_fft: int = 512,
        n_doppler_fft: int = 256,
    ) -> None:
        wf = frontend.waveform
        if len(wf.segments) != 1 or wf.segments[0].n_chirps < 3:
            raise ValueError("range-Doppler processing needs one segment of identical chirps (a Distance2Go frame)")
        seg = wf.segments[0]
        n_c, n_s = seg.n_chirps, seg.n_samples
        if n_range_fft < n_s or n_doppler_fft < n_c - 1 or n_range_fft % 2:
            raise ValueError("zero-padded FFT lengths must be even and at least the frame's samples/chirps")
        self.frontend = frontend
        self.k_c = float(k_c)
        self.k_sf = float(k_sf)
        self.n_range_fft = int(n_range_fft)
        self.n_doppler_fft = int(n_doppler_fft)
        self.n_range = self.n_range_fft // 2
        self._h = iir_canceller_matrix(n_c, k_c)
        self.w_r = scipy.signal.windows.kaiser(n_s, k_sf, sym=True).astype(np.float32)
        self.w_d = scipy.signal.windows.kaiser(n_c - 1, k_sf, sym=True).astype(np.float32)
        self._win = (self.w_d[:, None] * self.w_r[None, :]).astype(np.float32)
        self._scale = np.float32(1.0 / (float(self.w_r.sum()) * float(self.w_d.sum())))
        # axes
        fs = seg.sample_rate_hz
        slope = seg.slope_hz_per_s
        lam = wf.wavelength_m
        self.pri_s = seg.pri_s
        self.beat_hz = (np.arange(self.n_range) * fs / self.n_range_fft).astype(np.float32)
        self.range_m = (self.beat_hz * SPEED_OF_LIGHT_MPS / (2.0 * abs(slope))).astype(np.float32)
        self.range_bin_m = float(fs / self.n_range_fft * SPEED_OF_LIGHT_MPS / (2.0 * abs(slope)))
        self.v_max_kmh = float(lam / (4.0 * seg.pri_s) * 3.6)
        k = np.arange(self.n_doppler_fft) - self.n_doppler_fft // 2
        self.radial_speed_kmh = (k * lam / (2.0 * self.n_doppler_fft * seg.pri_s) * 3.6).astype(np.float32)
        self.doppler_bin_kmh = float(2.0 * self.v_max_kmh / self.n_doppler_fft)
        self.theta_rad = (2.0 * np.pi * np.arange(self.n_doppler_fft) / self.n_doppler_fft).astype(np.float32)
        self.cylinder_radius_kmh = self.v_max_kmh / math.pi
        # the FFTs' zero-padded inputs, kept between frames (only their leading parts are written)
        self._pad_r = np.zeros((n_c - 1, self.n_range_fft), dtype=np.complex64)
        self._pad_d = np.zeros((self.n_range, self.n_doppler_fft), dtype=np.complex64)  # range rows: no transposes

    @property
    def shape(self) -> tuple[int, int]:
        return (self.n_range, self.n_doppler_fft)

    def process(self, iq: np.ndarray) -> RangeDopplerMap:
        """``iq`` complex64 ``(n_rx, N_c, N_s)`` (first channel used) -> :class:`RangeDopplerMap`."""
        u = iir_canceller(iq[0], self._h)  # (N_c - 1, N_s)
        pad_r, pad_d = self._pad_r, self._pad_d
        np.multiply(u, self._win, out=pad_r[:, : u.shape[1]])  # windowed chirps, zero-padded to N_R
        pad_d[:, : u.shape[0]] = scipy.fft.fft(pad_r, axis=1, workers=1)[:, : self.n_range].T  # (n_range, N_c-1)
        rd = scipy.fft.fft(pad_d, axis=1, workers=1)  # (n_range, N_D)
        # magnitude with the fftshift along Doppler: out[:, k] = |rd[:, (k - N_D // 2) % N_D]|
        nd, s = self.n_doppler_fft, self.n_doppler_fft // 2
        out = np.empty((self.n_range, nd), dtype=np.float32)
        np.abs(rd[:, : nd - s], out=out[:, s:])
        np.abs(rd[:, nd - s :], out=out[:, :s])
        out *= self._scale
        return RangeDopplerMap(out, u)

    # --- cylinder ---------------------------------------------------------------------------------

    def wrap(self, range_bin: np.ndarray, doppler_bin: np.ndarray) -> np.ndarray:
        """Map bins to the cylinder (eq. 6): ``(N, 3)`` float32 ``[v', v'', r]`` (km/h, km/h, m)."""
        th = self.theta_rad[doppler_bin]
        rad = np.float32(self.cylinder_radius_kmh)
        out = np.empty((np.size(range_bin), 3), dtype=np.float32)
        out[:, 0] = rad * np.cos(th)
        out[:, 1] = rad * np.sin(th)
        out[:, 2] = self.range_m[range_bin]
        return out

    def unwrap(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Inverse (eq. 7): ``(N, 3)`` cylinder points -> (range m, aliased radial speed km/h)."""
        p = np.atleast_2d(points)
        th = np.mod(np.arctan2(p[:, 1], p[:, 0]), 2.0 * np.pi)
        return p[:, 2].astype(np.float32), (th * self.v_max_kmh / np.pi - self.v_max_kmh).astype(np.float32)


def threshold_map(amplitude: np.ndarray, th_rd: float) -> tuple[np.ndarray, np.ndarray]:
    """Bins at or above ``th_rd``: (range bins, Doppler bins), int arrays in row-major order."""
    ri, di = np.nonzero(amplitude >= np.float32(th_rd))
    return ri, di


def detection_mask(amplitude: np.ndarray, th_rd: float, sidelobe_guard_db: float = 0.0) -> np.ndarray:
    """Cells of a map ``(n_range, n_doppler)`` that are points: at or above ``th_rd`` and, when
    ``sidelobe_guard_db > 0``, no more than that many dB below the strongest cell of their range row
    and of their Doppler column.

    The guard removes the Doppler and range sidelobes of strong echoes: the Kaiser window with
    ``K_sf = 3`` has a peak sidelobe of about -25 dB, so a car a few metres away (35-45 dB above
    ``th_RD``) paints its whole range row and Doppler column above the threshold; DBSCAN then joins
    every target near that range into the car's cluster. A weaker target survives unless it shares
    the strong echo's range row or Doppler column *and* is more than the guard below it.
    Two reductions and two comparisons per cell (``(n_range, n_doppler)`` bool).
    """
    a = np.asarray(amplitude)
    mask = a >= np.float32(th_rd)
    if sidelobe_guard_db > 0:
        k = np.float32(10.0 ** (-sidelobe_guard_db / 20.0))
        mask &= a >= a.max(axis=1, keepdims=True) * k
        mask &= a >= a.max(axis=0, keepdims=True) * k
    return mask
