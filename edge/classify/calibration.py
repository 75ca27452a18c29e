"""The surveillance board's RCS calibration constant C (issue 31): what it is, how a corner reflector measures it.

Radar equation of a point target on boresight at range ``R`` (Tavanti eq. 17's tone amplitude ``A`` in ADC counts,
the IF high-pass compensated)::

    A^2 = sigma * K / R^4,     K = P_t G_t G_r lambda^2 g^2 / ((4 pi)^3 L)      (g: sqrt(W) -> counts)
    C   = 10 log10(K)   [dB counts^2 m^4 per m^2]
    sigma_dBsm = 10 log10(A^2 R^4) - C

``C`` holds everything a board varies in from unit to unit (TX power, antenna gains, receive gain, radome, mounting).
:func:`measure_reflector` measures it from frames of a static corner reflector of known RCS on boresight at a
known range; without a measurement the datasheet value :data:`DATASHEET_C_DB` stands, with
:data:`DATASHEET_C_SD_DB` of uncertainty. The antenna pattern off boresight is not compensated: a 1-RX board
does not measure azimuth, so a target is assumed on boresight (a target at the edge of the 42 deg x 20 deg
beam reads up to 6 dB low, both ways at -3 dB).
"""

from __future__ import annotations

import math
from typing import Iterable

import numpy as np
import scipy.fft
import scipy.signal

from hal.frame import SATURATED_FRACTION
from hal.waveform import SPEED_OF_LIGHT_MPS

#: C of a Distance2Go built to its datasheet (Tavanti Table I and the BGT24MTR11 data: P_t 11 dBm, 12 dBi TX and RX
#: patch arrays of 42 x 20 deg, 6 dB of system loss, 12 dB noise figure plus 24 dB of IF excess noise at 3 counts
#: rms in the 42.7 kHz sampled band: hw_sim.radio.D2G_RADIO, the nominal board the shipped reference set was built
#: on), as :func:`measure_reflector` reads it there (reflector-d2g, 2.69 m^2 at 5 m): 61.40 dB. The radar equation
#: of those figures gives 62.17 dB; the procedure reads 0.8 dB lower (the simulated echo peaks at 4.87 m for
#: 5.00 m), and the constant is the procedure's own so that a measured C refers a board to this one exactly.
#: dB (counts^2 m^4 per m^2 of RCS)
DATASHEET_C_DB = 61.40
#: uncertainty (1 sd, dB) of :data:`DATASHEET_C_DB` on an actual unit: BGT24MTR11 TX power and receive gain
#: spread from unit to unit, with temperature and behind a radome by several dB (issue 31)
DATASHEET_C_SD_DB = 3.0


def trihedral_rcs_m2(edge_m: float, wavelength_m: float) -> float:
    """Peak RCS (m^2) of a triangular trihedral corner reflector of inner edge ``edge_m``: 4 pi a^4 / (3 lambda^2)
    (Knott, Shaeffer & Tuley, Radar Cross Section, 2nd ed. 2004, table 6.1)."""
    if edge_m <= 0.0 or wavelength_m <= 0.0:
        raise ValueError("edge and wavelength must be positive")
    return 4.0 * math.pi * edge_m**4 / (3.0 * wavelength_m**2)


def if_highpass_compensation(beat_hz: float | np.ndarray, corner_hz: float) -> float | np.ndarray:
    """Amplitude factor undoing the IF amplifier's first-order high-pass of corner ``corner_hz`` (eq. 17's
    sqrt(f_c^2 + f_b^2) / f_b)."""
    fb = np.asarray(beat_hz, dtype=np.float64)
    return np.sqrt(corner_hz * corner_hz + fb * fb) / fb


def reflector_amplitude(iq: np.ndarray, frontend, *, range_m: float, window_m: float = 0.75, k_sf: float = 3.0,
                        oversample: int = 16) -> tuple[float, float]:
    """Tone amplitude (ADC counts) and range (m) of the strongest static echo within ``window_m`` of ``range_m`` in
    one frame: the chirps averaged (a static target has the same phase on every chirp), the DC removed, a Kaiser
    window (shape ``k_sf``) and an FFT zero-padded ``oversample`` times, scaled so that a tone of A counts reads A."""
    seg = frontend.waveform.segments[0]
    x = np.asarray(iq)[0].astype(np.complex128).mean(axis=0)
    x = x - x.mean()
    n = x.size
    w = scipy.signal.windows.kaiser(n, k_sf, sym=True)
    nfft = int(oversample) * n
    spec = np.abs(scipy.fft.fft(x * w, n=nfft)) / float(w.sum())
    f = np.arange(nfft) * seg.sample_rate_hz / nfft
    r = f * SPEED_OF_LIGHT_MPS / (2.0 * abs(seg.slope_hz_per_s))
    sel = np.flatnonzero(np.abs(r - range_m) <= window_m)
    sel = sel[sel < nfft // 2]
    if sel.size == 0:
        raise ValueError(f"range {range_m} m is outside the board's range axis")
    k = int(sel[np.argmax(spec[sel])])
    return float(spec[k]), float(r[k])


def measure_reflector(frames: Iterable, frontend, *, rcs_m2: float, range_m: float, range_sd_m: float = 0.05,
                      if_corner_hz: float = 1000.0, window_m: float = 0.75, k_sf: float = 3.0,
                      max_clipped_fraction: float = SATURATED_FRACTION) -> dict:
    """C (dB) from frames of a static corner reflector of RCS ``rcs_m2`` on boresight at ``range_m`` (tape-measured,
    1 sd ``range_sd_m``), with its uncertainty: the frames' spread over sqrt(N) and the range's 40 log10 term,
    in quadrature. Refused (ValueError) when more than ``max_clipped_fraction`` of the samples sit at the ADC's
    full scale. Returns a dict with ``c_db``, ``c_sd_db``, the per-frame spread, the measured peak range and
    ``frames``."""
    if rcs_m2 <= 0.0 or range_m <= 0.0:
        raise ValueError("reflector RCS and range must be positive")
    seg = frontend.waveform.segments[0]
    amps, where = [], []
    clipped = total = 0
    for f in frames:
        a, r = reflector_amplitude(f.iq(), frontend, range_m=range_m, window_m=window_m, k_sf=k_sf)
        amps.append(a)
        where.append(r)
        c, n = f.clipped_samples()
        clipped += c
        total += n
    if len(amps) < 2:
        raise ValueError("the reflector measurement needs at least two frames")
    if clipped > max_clipped_fraction * total:
        raise ValueError(f"the ADC clips on {clipped / total:.1%} of the samples (full scale): a clipped echo reads "
                         "low, so C cannot be measured; move the reflector farther or use a smaller one (if the "
                         "TX->RX leakage alone clips, lower the board's TX power level first: radar-edge calibrate --headroom)")
    a = np.asarray(amps)
    beat = 2.0 * abs(seg.slope_hz_per_s) * range_m / SPEED_OF_LIGHT_MPS
    comp = float(if_highpass_compensation(beat, if_corner_hz))
    per_frame_db = 20.0 * np.log10(a * comp) + 40.0 * math.log10(range_m) - 10.0 * math.log10(rcs_m2)
    c_db = float(10.0 * np.log10(np.mean((a * comp) ** 2)) + 40.0 * math.log10(range_m) - 10.0 * math.log10(rcs_m2))
    stat_sd = float(per_frame_db.std(ddof=1) / math.sqrt(a.size))
    range_term_sd = 40.0 / math.log(10.0) * range_sd_m / range_m
    peak_range = float(np.median(where))
    return {
        "c_db": c_db,
        "c_sd_db": float(math.hypot(stat_sd, range_term_sd)),
        "c_sd_frames_db": stat_sd,
        "c_sd_range_db": range_term_sd,
        "per_frame_sd_db": float(per_frame_db.std(ddof=1)),
        "amplitude_counts": float(np.sqrt(np.mean(a**2))),
        "if_highpass_compensation": comp,
        "rcs_m2": float(rcs_m2),
        "range_m": float(range_m),
        "measured_peak_range_m": peak_range,
        "clipped_fraction": clipped / total,
        "frames": int(a.size),
    }


def rcs_gain_factor(c_db: float, reference_c_db: float = DATASHEET_C_DB) -> float:
    """Power factor that refers an eq. 17 value of a board of constant ``c_db`` to the board the reference set was
    built on (``reference_c_db``): 10^((C_ref - C) / 10); 1 for the datasheet board."""
    return float(10.0 ** ((reference_c_db - c_db) / 10.0))
