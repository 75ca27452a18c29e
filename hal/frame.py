"""The raw frame every backend delivers."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hal.waveform import FrontendInfo

#: a frame with more than this share of its I and Q samples at the ADC's full scale is saturated (doctor, the frame
#: loop's degraded status, calibrate --rcs)
SATURATED_FRACTION = 1e-4


@dataclass(frozen=True, eq=False)
class RawFrame:
    """One frame of ADC samples.

    ``i`` and ``q`` are int16 arrays shaped ``(n_rx, n_chirps, n_samples)`` holding centred ADC counts
    (within the ADC's signed range). ``seq`` is the board's frame counter as seen by the host
    (monotonic, gaps mean dropped frames); ``t_ns`` the host monotonic time at which the frame was
    received. ``truth`` carries simulator ground truth when there is any (see
    :class:`hw_sim.scene.GroundTruth`), else ``None``. ``frontend`` is the description the frame was
    taken with.
    """

    seq: int
    t_ns: int
    i: np.ndarray
    q: np.ndarray
    frontend: FrontendInfo
    truth: Any = None
    meta: dict[str, Any] = field(default_factory=dict)

    def iq(self) -> np.ndarray:
        """Complex64 view ``I + jQ`` shaped ``(n_rx, n_chirps, n_samples)`` (made once per call)."""
        out = np.empty(self.i.shape, dtype=np.complex64)
        out.real = self.i
        out.imag = self.q
        return out

    def clipped_samples(self) -> tuple[int, int]:
        """``(clipped, total)``: the I and Q samples at the ADC's full scale (its smallest or largest code), and all."""
        lo, hi = self.frontend.adc_min, self.frontend.adc_max
        rails = (np.asarray(self.i), np.asarray(self.q))
        return sum(int(np.count_nonzero((a <= lo) | (a >= hi))) for a in rails), sum(a.size for a in rails)

    def peak_counts(self) -> tuple[int, int]:
        """``(peak, full_scale)``: the largest |I| or |Q| of the frame and the ADC's full scale, in counts."""
        peak = max(int(np.max(np.abs(np.asarray(a, dtype=np.int32)))) for a in (self.i, self.q))
        return peak, max(self.frontend.adc_max, -self.frontend.adc_min)

    @property
    def waveform(self):
        return self.frontend.waveform
