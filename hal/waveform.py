"""Waveform and front-end description, and the radar characteristics derived from them.

A :class:`Waveform` describes what the board transmits and samples in one frame: a list of
:class:`ChirpSegment` (direction, ramp time, bandwidth, samples, sample rate, how many identical
chirps at which repetition interval). :class:`FrontendInfo` adds the receive array and the ADC.
Everything a pipeline needs to know about the hardware comes from these two frozen objects, and the
derived figures (range resolution, unambiguous range, velocity limits, field of view) are computed,
never typed in: :func:`characteristics` reproduces Lim et al. Table 2 for the SIMO board and
Tavanti et al. Table II for the Distance2Go.

Conventions (DESIGN §5): units in names; radial velocity positive when receding; Doppler
``f_D = -2 v_r / lambda``. The complex IF of a scatterer at delay ``tau`` is
``exp(+j 2 pi (S tau - f_D) t)`` for a ramp of signed slope ``S``: up-chirps put targets at positive
beat frequencies, down-chirps at negative ones.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from typing import Any

SPEED_OF_LIGHT_MPS = 299_792_458.0


@dataclass(frozen=True)
class ChirpSegment:
    """One group of identical linear chirps inside a frame.

    ``direction`` is +1 for an up-chirp, -1 for a down-chirp. The ramp sweeps ``bandwidth_hz`` in
    ``ramp_s`` starting at ``f_start_hz`` (the lowest frequency for an up-chirp, the highest for a
    down-chirp). ``n_samples`` complex samples are taken at ``sample_rate_hz`` starting
    ``sample_offset_s`` after the ramp starts. The group repeats ``n_chirps`` times every ``pri_s``
    seconds, beginning ``t_start_s`` after the frame start.
    """

    direction: int
    ramp_s: float
    bandwidth_hz: float
    f_start_hz: float
    n_samples: int
    sample_rate_hz: float
    t_start_s: float = 0.0
    n_chirps: int = 1
    pri_s: float = 0.0
    sample_offset_s: float = 0.0

    def __post_init__(self) -> None:
        if self.direction not in (1, -1):
            raise ValueError(f"ChirpSegment.direction must be +1 or -1, got {self.direction!r}")
        if self.n_samples <= 0 or self.n_chirps <= 0:
            raise ValueError("ChirpSegment needs n_samples > 0 and n_chirps > 0")
        if self.sample_offset_s + self.n_samples / self.sample_rate_hz > self.ramp_s * (1 + 1e-9):
            raise ValueError("ChirpSegment samples extend beyond the ramp")
        if self.n_chirps > 1 and self.pri_s < self.ramp_s:
            raise ValueError("ChirpSegment.pri_s must be at least ramp_s when n_chirps > 1")

    @property
    def slope_hz_per_s(self) -> float:
        """Signed ramp slope S (Hz/s): positive for up-chirps."""
        return self.direction * self.bandwidth_hz / self.ramp_s

    @property
    def f_center_hz(self) -> float:
        return self.f_start_hz + self.direction * self.bandwidth_hz / 2.0

    @property
    def sampled_bandwidth_hz(self) -> float:
        """Bandwidth actually swept while sampling (sets the range resolution)."""
        return self.bandwidth_hz * (self.n_samples / self.sample_rate_hz) / self.ramp_s

    @property
    def duration_s(self) -> float:
        """Time from the first chirp start to the end of the last ramp."""
        return (self.n_chirps - 1) * self.pri_s + self.ramp_s


@dataclass(frozen=True)
class Waveform:
    """What one frame transmits and samples. ``segments`` are in time order."""

    name: str
    carrier_hz: float  # reference frequency for the wavelength (the centre, or the paper's f0)
    segments: tuple[ChirpSegment, ...]
    frame_period_s: float
    design_range_m: float = field(default=0.0, metadata={"doc": "range the waveform is designed for"})

    def __post_init__(self) -> None:
        if not self.segments:
            raise ValueError("Waveform needs at least one chirp segment")
        n = {s.n_samples for s in self.segments}
        if len(n) != 1:
            raise ValueError("all segments of a Waveform must take the same number of samples")
        end = max(s.t_start_s + s.duration_s for s in self.segments)
        if end > self.frame_period_s * (1 + 1e-9):
            raise ValueError("chirp schedule is longer than the frame period")

    @property
    def wavelength_m(self) -> float:
        return SPEED_OF_LIGHT_MPS / self.carrier_hz

    @property
    def n_chirps(self) -> int:
        """Total number of chirps in a frame (rows of the ``iq`` array)."""
        return sum(s.n_chirps for s in self.segments)

    @property
    def n_samples(self) -> int:
        return self.segments[0].n_samples

    @property
    def bandwidth_hz(self) -> float:
        return max(s.bandwidth_hz for s in self.segments)

    def chirp_segment_index(self) -> tuple[int, ...]:
        """Segment index of every chirp row, in frame order."""
        out: list[int] = []
        for k, s in enumerate(self.segments):
            out.extend([k] * s.n_chirps)
        return tuple(out)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["segments"] = [asdict(s) for s in self.segments]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Waveform":
        d = dict(d)
        d["segments"] = tuple(ChirpSegment(**s) for s in d["segments"])
        return cls(**d)


@dataclass(frozen=True)
class FrontendInfo:
    """The board as a pipeline sees it: waveform, receive array, ADC."""

    board: str
    waveform: Waveform
    n_rx: int
    rx_spacing_m: float
    adc_bits: int = 12
    complex_iq: bool = True
    fov_deg: float = 0.0
    notes: str = ""

    @property
    def frame_shape(self) -> tuple[int, int, int]:
        """Shape of ``RawFrame.i`` and ``RawFrame.q``: (n_rx, n_chirps, n_samples)."""
        return (self.n_rx, self.waveform.n_chirps, self.waveform.n_samples)

    @property
    def adc_max(self) -> int:
        return 2 ** (self.adc_bits - 1) - 1

    @property
    def adc_min(self) -> int:
        return -(2 ** (self.adc_bits - 1))

    def to_json(self) -> str:
        d = asdict(self)
        d["waveform"] = self.waveform.to_dict()
        return json.dumps(d, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> "FrontendInfo":
        d = json.loads(text)
        d["waveform"] = Waveform.from_dict(d["waveform"])
        return cls(**d)


@dataclass(frozen=True)
class RadarCharacteristics:
    """Figures derived from a :class:`FrontendInfo` (see :func:`characteristics`)."""

    wavelength_m: float
    range_resolution_m: float
    max_unambiguous_range_m: float
    max_radial_speed_mps: float
    radial_speed_resolution_mps: float
    unambiguous_angle_deg: float | None
    fov_deg: float
    frame_period_s: float
    speed_limit_basis: str

    def as_rows(self) -> list[tuple[str, str]]:
        rows = [
            ("wavelength", f"{self.wavelength_m * 100:.3f} cm"),
            ("range resolution c/(2B)", f"{self.range_resolution_m:.3f} m"),
            ("max unambiguous range", f"{self.max_unambiguous_range_m:.1f} m"),
            (
                "max radial speed",
                f"±{self.max_radial_speed_mps:.2f} m/s (±{self.max_radial_speed_mps * 3.6:.2f} km/h)"
                f" [{self.speed_limit_basis}]",
            ),
            (
                "radial speed resolution",
                f"{self.radial_speed_resolution_mps:.3f} m/s ({self.radial_speed_resolution_mps * 3.6:.2f} km/h)",
            ),
        ]
        if self.unambiguous_angle_deg is not None:
            rows.append(("unambiguous angle", f"±{self.unambiguous_angle_deg:.1f}°"))
        rows.append(("field of view", f"±{self.fov_deg / 2:.1f}°"))
        rows.append(("frame period", f"{self.frame_period_s * 1000:.1f} ms"))
        return rows


def characteristics(fe: FrontendInfo) -> RadarCharacteristics:
    """Derive the radar characteristics of a front end.

    * Range resolution: ``c / (2 B)`` with the swept bandwidth.
    * Max unambiguous range: the range whose beat frequency reaches the edge of the sampled band,
      worst segment. Complex I/Q sampling gives a band of ±fs/2; a real ADC, or a pipeline that keeps
      only the positive-range half as Tavanti does, gives fs/2 (Tavanti's ``N_s c / (4 B)``).
    * Speed, multi-chirp (Doppler across chirps, Tavanti): ``lambda / (4 T_PRI)``; resolution
      ``lambda / (2 T_CPI,eff)`` with the first chirp dropped by the clutter filter.
    * Speed, single-chirp segments (Lim's multi-slope FMCW): the Doppler shift must keep the beat
      of a target at the design range inside the band: ``(fs/2 - |S| 2 R_d / c) lambda / 2``,
      worst segment; resolution ``lambda / (2 T)`` with the shortest segment's sampling time.
    * Unambiguous angle of a uniform linear array: ``asin(lambda / (2 d))``.
    """

    wf = fe.waveform
    lam = wf.wavelength_m
    c = SPEED_OF_LIGHT_MPS
    rng_res = c / (2.0 * max(s.sampled_bandwidth_hz for s in wf.segments))
    half_band = [(s.sample_rate_hz / 2.0) for s in wf.segments]
    r_max = min(hb / abs(s.slope_hz_per_s) * c / 2.0 for hb, s in zip(half_band, wf.segments))
    multi = [s for s in wf.segments if s.n_chirps > 1]
    if multi:
        s = multi[0]
        v_max = lam / (4.0 * s.pri_s)
        v_res = lam / (2.0 * (s.n_chirps - 1) * s.pri_s)
        basis = "Doppler across chirps, lambda/(4 T_PRI)"
    else:
        rd = wf.design_range_m
        v_max = min(
            (hb - abs(s.slope_hz_per_s) * 2.0 * rd / c) * lam / 2.0 for hb, s in zip(half_band, wf.segments)
        )
        t_min = min(s.n_samples / s.sample_rate_hz for s in wf.segments)
        v_res = lam / (2.0 * t_min)
        basis = f"beat band at {rd:.0f} m"
    ang = None
    if fe.n_rx > 1 and fe.rx_spacing_m > 0:
        ang = math.degrees(math.asin(min(1.0, lam / (2.0 * fe.rx_spacing_m))))
    return RadarCharacteristics(
        wavelength_m=lam,
        range_resolution_m=rng_res,
        max_unambiguous_range_m=r_max,
        max_radial_speed_mps=v_max,
        radial_speed_resolution_mps=v_res,
        unambiguous_angle_deg=ang,
        fov_deg=fe.fov_deg,
        frame_period_s=wf.frame_period_s,
        speed_limit_basis=basis,
    )


# --- the two boards of the product ------------------------------------------------------------

#: SIMO ADC rate for the fast (5 ms) segments. The slow (10 ms) segments are decimated by two in the
#: front end, so every segment yields 1024 complex samples and 200 Hz / 100 Hz bins = 0.75 m.
#: 204.8 kS/s complex keeps a 300 m target (80 kHz beat on the fast ramps, 40 kHz on the slow ones)
#: plus a ±250 km/h Doppler shift (±11.2 kHz) inside ±fs/2 on every segment.
SIMO_SAMPLE_RATE_HZ = 204_800.0


def simo_frontend() -> FrontendInfo:
    """Lim et al.'s 1 TX x 4 RX SIMO board: 24.1 GHz, 200 MHz, up 5 / down 5 / up 10 / down 10 ms."""
    fc = 24.1e9
    bw = 200e6
    lo, hi = fc - bw / 2, fc + bw / 2
    fs_fast = SIMO_SAMPLE_RATE_HZ
    fs_slow = SIMO_SAMPLE_RATE_HZ / 2
    segs = (
        ChirpSegment(+1, 5e-3, bw, lo, 1024, fs_fast, t_start_s=0.0),
        ChirpSegment(-1, 5e-3, bw, hi, 1024, fs_fast, t_start_s=5e-3),
        ChirpSegment(+1, 10e-3, bw, lo, 1024, fs_slow, t_start_s=10e-3),
        ChirpSegment(-1, 10e-3, bw, hi, 1024, fs_slow, t_start_s=20e-3),
    )
    wf = Waveform("lim-simo-4seg", fc, segs, frame_period_s=0.033, design_range_m=300.0)
    lam = wf.wavelength_m
    return FrontendInfo(
        board="simo",
        waveform=wf,
        n_rx=4,
        rx_spacing_m=1.5 * lam,
        adc_bits=12,
        complex_iq=True,
        fov_deg=30.0,
        notes="Lim et al. 2021, Table 1/2; simulated board",
    )


def d2g_frontend() -> FrontendInfo:
    """Infineon Distance2Go as configured by Tavanti et al. Table I (21 up-chirps, 64 samples)."""
    fc = 24.025e9
    bw = 200e6
    t_c = 1.5e-3
    n_s = 64
    # Tavanti's f0 is where the ramp starts (the board sweeps 24.025-24.225 GHz); the paper's
    # Table II expressions use lambda0 = c / f0, so f0 is also the waveform's reference frequency
    seg = ChirpSegment(+1, t_c, bw, fc, n_s, n_s / t_c, t_start_s=0.0, n_chirps=21, pri_s=2.1e-3)
    wf = Waveform("tavanti-d2g", fc, (seg,), frame_period_s=0.2, design_range_m=24.0)
    return FrontendInfo(
        board="d2g",
        waveform=wf,
        n_rx=1,
        rx_spacing_m=0.0,
        adc_bits=12,
        complex_iq=True,
        fov_deg=42.0,
        notes="Tavanti et al. 2022, Table I/II; BGT24MTR11, I and Q sampled by the XMC4200 12-bit ADC",
    )
