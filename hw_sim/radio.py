"""RF and receiver model of a simulated board: what turns a scatterer into ADC counts.

Amplitudes follow the radar equation for each scatterer,

    P_r = P_t G_t(az, el) G_r(az, el) lambda^2 sigma / ((4 pi)^3 R^4 L_sys)

against thermal noise ``k T0 B F`` with ``B`` the complex sample rate. Receiver gain staging puts
the thermal noise at ``noise_rms_counts`` ADC counts RMS per I and Q rail (the designer's choice, a
few LSB above quantisation); every signal is scaled by the same factor, so SNR is physical and the
ADC clips where a real one would.

Antenna patterns are Gaussian main lobes with the 3 dB beamwidths given, floored at the sidelobe
level: a documented simplification of Lim Fig. 2 (Taylor-weighted series-fed patches) and of the
Distance2Go's 4x2 patch arrays.

Propagation over the road (:func:`road_bounce_factor`) and the receiver's imperfections
(:class:`ReceiverImperfections`) are the ``[physics]`` choices of :mod:`hw_sim.physics`; the board applies
them in :func:`hw_sim.boards.apply_physics`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

BOLTZMANN = 1.380649e-23
T0_K = 290.0


@dataclass(frozen=True)
class AntennaPattern:
    """Gaussian main lobe, floored at ``-sidelobe_db`` (all gains in dB / dBi)."""

    gain_dbi: float
    az_beamwidth_deg: float
    el_beamwidth_deg: float
    sidelobe_db: float
    #: level behind the antenna (|azimuth| > 90 deg) below the peak; 0 = the sidelobe floor all round
    front_to_back_db: float = 0.0

    def gain_linear(self, az_rad: np.ndarray, el_rad: np.ndarray) -> np.ndarray:
        """Power gain (linear) towards azimuth/elevation off boresight, same shape as inputs."""
        az = np.degrees(az_rad) / self.az_beamwidth_deg
        el = np.degrees(el_rad) / self.el_beamwidth_deg
        rel_db = -12.0 * (az * az + el * el)  # -3 dB at half the beamwidth off axis
        rel_db = np.maximum(rel_db, -self.sidelobe_db)
        if self.front_to_back_db > self.sidelobe_db:
            rel_db = np.where(np.abs(az_rad) > 0.5 * np.pi, -self.front_to_back_db, rel_db)
        return 10.0 ** ((self.gain_dbi + rel_db) / 10.0)


@dataclass(frozen=True)
class RadioModel:
    """Transmitter, antennas and receiver of a simulated board."""

    tx_power_dbm: float
    tx: AntennaPattern
    rx: AntennaPattern
    noise_figure_db: float
    system_loss_db: float
    noise_rms_counts: float
    leakage_power_dbm: float
    leakage_range_m: float
    #: corner of the first-order IF high-pass in front of the ADC (0 = none); Tavanti eq. (17) f_c
    if_highpass_hz: float = 0.0
    #: RMS chirp-to-chirp complex gain jitter of static returns (TX->RX leakage, clutter) relative to
    #: the return, in dBc; it models VCO/supply drift between chirps and is what remains of static
    #: returns after an MTI canceller (-300 = none)
    static_jitter_dbc: float = -300.0
    #: noise above kTB*NF in the IF band actually used (the homodyne mixer's 1/f noise at kHz beat
    #: frequencies, phase noise of the leakage, ADC); 0 = thermal only
    if_excess_noise_db: float = 0.0
    #: unit-to-unit / radome / temperature offset of the receive chain (dB): scales every echo and the
    #: leakage (:meth:`signal_counts_gain`), not the thermal noise
    gain_offset_db: float = 0.0
    #: TX output power set below ``tx_power_dbm`` (dB; the board's TX power level, :func:`hw_sim.boards.with_tx_power`):
    #: scales every echo and the TX->RX leakage alike, not the noise
    tx_backoff_db: float = 0.0

    def noise_power_w(self, bandwidth_hz: float) -> float:
        return BOLTZMANN * T0_K * bandwidth_hz * 10.0 ** ((self.noise_figure_db + self.if_excess_noise_db) / 10.0)

    def received_power_w(
        self, rcs_m2: np.ndarray, range_m: np.ndarray, az_rad: np.ndarray, el_rad: np.ndarray, wavelength_m: float
    ) -> np.ndarray:
        pt = 10.0 ** ((self.tx_power_dbm - 30.0) / 10.0)
        gt = self.tx.gain_linear(az_rad, el_rad)
        gr = self.rx.gain_linear(az_rad, el_rad)
        loss = 10.0 ** (self.system_loss_db / 10.0)
        r4 = np.maximum(range_m, 0.1) ** 4
        return pt * gt * gr * wavelength_m**2 * rcs_m2 / ((4.0 * math.pi) ** 3 * r4 * loss)

    def counts_per_sqrt_w(self, bandwidth_hz: float) -> float:
        """Receiver voltage gain: sqrt(W) at the antenna -> ADC counts (complex amplitude)."""
        # complex noise of power N has std sqrt(N/2) per rail; map that to noise_rms_counts
        return self.noise_rms_counts / math.sqrt(self.noise_power_w(bandwidth_hz) / 2.0)

    def signal_counts_gain(self, bandwidth_hz: float) -> float:
        """:meth:`counts_per_sqrt_w` with the board's gain offset and TX back-off: the gain echoes and leakage see."""
        return self.counts_per_sqrt_w(bandwidth_hz) * 10.0 ** ((self.gain_offset_db - self.tx_backoff_db) / 20.0)


#: Lim et al. Table 1 antennas and TX power. Elevation beamwidths are not given in the paper; the
#: series-fed columns make them narrow: 12 deg (TX) and 14 deg (RX) are assumed. NF 12 dB is typical
#: of 24 GHz MMIC receivers; 12 dB of system loss (radome, feed, processing, fluctuation margin)
#: makes a 10 m^2 car fall below the OS-CFAR threshold not far beyond 300 m. Measured with the lane
#: pipeline's defaults (pfa 1e-3, four segments must pair), radar 7 m up, tilt 1.5 deg, a non-fluctuating
#: 10 m^2 point target 0.5 m above lane 1 moving 5 m/s, 60 frames per range (2 s, 10 m of travel):
#: detection probability 1.00 at 290 m, 0.97 at 310 m, 0.92 at 330 m, 0.68 at 350 m, 0.55 at 370 m,
#: 0.00 at 390 m. Post-FFT SNR of that target is about 21 dB at 150 m (12 dB at 300 m).
#: Behind the patch arrays' ground plane the level is 30 dB below the peak (front-to-back ratio of a patch
#: array in a metal housing; without it, a vehicle that has just passed under the overpass, 10-20 m behind
#: the radar, came back through the sidelobe floor as a "mirror" vehicle in front of it).
SIMO_RADIO = RadioModel(
    tx_power_dbm=19.7,
    tx=AntennaPattern(gain_dbi=13.6, az_beamwidth_deg=18.56, el_beamwidth_deg=12.0, sidelobe_db=18.8,
                      front_to_back_db=30.0),
    rx=AntennaPattern(gain_dbi=10.8, az_beamwidth_deg=36.35, el_beamwidth_deg=14.0, sidelobe_db=23.0,
                      front_to_back_db=30.0),
    noise_figure_db=12.0,
    system_loss_db=12.0,
    noise_rms_counts=2.0,
    leakage_power_dbm=-55.0,
    leakage_range_m=0.15,
)

#: Distance2Go (Tavanti Table I/II): 12 dBi, 42 x 20 deg; BGT24MTR11 transmits about 11 dBm; NF 12 dB.
#: The datasheet NF (12 dB) holds at high IF; at the Distance2Go's beat frequencies (0-21 kHz) the
#: homodyne mixer's 1/f noise dominates: 24 dB of excess noise puts the detection range of a 0.5 m^2
#: pedestrian near the 13.5 m Tavanti observed (cars and trucks: the whole 24 m).
#: The TX->RX leakage between the two patch arrays is strong (the reason for the IIR canceller):
#: -42 dBm referred to the antenna, ~56 dB over the noise of one sample (~1300 of 2047 counts).
#: Chirp-to-chirp gain jitter of the static returns (-55 dBc, VCO tuning and supply drift of the
#: open-loop BGT24 VCO) is what the canceller cannot remove: it leaves a faint ridge across Doppler at
#: the leakage and clutter ranges, the "background scene spuriously returned by the IIR filter" from
#: which Tavanti sets th_RD. The IF amplifier's first-order high-pass corner (1 kHz, ~1.1 m of beat
#: frequency) is the f_c of Tavanti eq. (17).
D2G_RADIO = RadioModel(
    tx_power_dbm=11.0,
    tx=AntennaPattern(gain_dbi=12.0, az_beamwidth_deg=42.0, el_beamwidth_deg=20.0, sidelobe_db=15.0),
    rx=AntennaPattern(gain_dbi=12.0, az_beamwidth_deg=42.0, el_beamwidth_deg=20.0, sidelobe_db=15.0),
    noise_figure_db=12.0,
    system_loss_db=6.0,
    noise_rms_counts=3.0,
    leakage_power_dbm=-42.0,
    leakage_range_m=0.1,
    if_highpass_hz=1000.0,
    static_jitter_dbc=-55.0,
    if_excess_noise_db=24.0,
)


# --- elevation beamwidth implied by the antenna gains ----------------------------------------------------

#: Kraus' practical directivity constant (deg^2): G ~ 32000 / (th_az th_el) for a main lobe of half-power
#: widths th_az, th_el in degrees (Kraus, *Antennas*, 2nd ed., 1988, sec. 2-22); it is eta * 41253 with an
#: effective efficiency eta = 0.78 (aperture efficiency, feed and dielectric losses of a patch array)
KRAUS_DEG2 = 32000.0
#: 41253 deg^2 = 4 pi sr: the lossless bound (the whole power inside the half-power solid angle)
SPHERE_DEG2 = 41253.0


def elevation_beamwidth_deg(gain_dbi: float, az_beamwidth_deg: float, constant_deg2: float = KRAUS_DEG2) -> float:
    """Elevation half-power width (deg) implied by a gain and an azimuth width: ``constant / (G th_az)``.

    Lim et al. 2021 Table 1 give the SIMO board's antenna gains and azimuth widths but no elevation width.
    With Kraus' constant (:data:`KRAUS_DEG2`):

    * TX 13.6 dBi (G = 22.9), 18.56 deg: 32000 / (22.9 * 18.56) = 75.3 deg;
    * RX 10.8 dBi (G = 12.0), 36.35 deg: 32000 / (12.0 * 36.35) = 73.2 deg;

    with the lossless bound (:data:`SPHERE_DEG2`) 97.1 and 94.4 deg. Either way one patch row in elevation
    (a series-fed array along azimuth), not the 12 / 14 deg of a column the v1 instrument assumed.
    """
    return constant_deg2 / (10.0 ** (gain_dbi / 10.0) * az_beamwidth_deg)


#: ``physics.elevation`` -> directivity constant (None: keep the pattern's own elevation width)
ELEVATION_CONSTANTS: dict[str, float | None] = {"gain-implied": KRAUS_DEG2, "wide": SPHERE_DEG2, "narrow": None}


def with_elevation(radio: RadioModel, choice: str) -> RadioModel:
    """``radio`` with both antennas' elevation widths as ``physics.elevation`` says.

    What it changes near the radar: a car's face 15 m out (0.5 m high; elevation -21.9 deg from a 7 m radar
    tilted 1.5 deg down) returns 39.7 dB more power with "gain-implied" than with "narrow" (40.5 dB with
    "wide"): 59 dB above the noise after the 1024-point range FFT instead of 20 dB. The 12-bit ADC does not
    clip on it (10 m^2: 82 counts against the 1400 counts of the TX->RX leakage; the rails reach 1500 of
    2047); ``tests/hw_sim/test_radio_physics.py`` holds these figures.
    """
    const = ELEVATION_CONSTANTS[choice]
    if const is None:
        return radio
    tx = dataclasses.replace(radio.tx, el_beamwidth_deg=elevation_beamwidth_deg(radio.tx.gain_dbi, radio.tx.az_beamwidth_deg, const))
    rx = dataclasses.replace(radio.rx, el_beamwidth_deg=elevation_beamwidth_deg(radio.rx.gain_dbi, radio.rx.az_beamwidth_deg, const))
    return dataclasses.replace(radio, tx=tx, rx=rx)


# --- road-bounce multipath ------------------------------------------------------------------------------


@dataclass(frozen=True)
class RoadSurface:
    """A flat road at ``z = 0`` that reflects specularly (Fresnel coefficient times a roughness factor)."""

    permittivity: float = 3.2
    loss_tangent: float = 0.03
    roughness_mm: float = 2.0
    #: "horizontal" (E parallel to the road: perpendicular/TE to the plane of incidence) or "vertical"
    polarisation: str = "horizontal"

    def reflection(self, sin_psi: np.ndarray, wavelength_m: float) -> np.ndarray:
        """Complex specular reflection coefficient at grazing angle ``psi`` (``sin psi`` given).

        Fresnel (e.g. Balanis, *Advanced Engineering Electromagnetics*, ch. 5) with
        ``eps = eps_r (1 - j tan delta)``, grazing angle ``psi``:
        horizontal ``(sin psi - sqrt(eps - cos^2 psi)) / (sin psi + sqrt(eps - cos^2 psi))``, vertical
        ``(eps sin psi - sqrt(...)) / (eps sin psi + sqrt(...))`` (-1 at grazing for both; the vertical one
        passes through a minimum at the Brewster angle, about 29 deg grazing for eps 3.2). Times the Ament
        roughness factor ``exp(-2 (2 pi sigma_h sin psi / lambda)^2)`` (Beckmann & Spizzichino 1963; ITU-R
        P.1057 / P.530 use the same form): with sigma_h = 2 mm it is 0.94 at 10 deg, 0.60 at 30 deg.
        """
        eps = self.permittivity * (1.0 - 1j * self.loss_tangent)
        s = np.asarray(sin_psi, dtype=np.float64)
        root = np.sqrt(eps - (1.0 - s * s))
        if self.polarisation == "vertical":
            gamma = (eps * s - root) / (eps * s + root)
        else:
            gamma = (s - root) / (s + root)
        k_sigma = 2.0 * math.pi * self.roughness_mm * 1e-3 * s / wavelength_m
        return gamma * np.exp(-2.0 * k_sigma * k_sigma)


def road_bounce_factor(
    radio: RadioModel, road: RoadSurface, radar_pos: np.ndarray, rot: np.ndarray, p: np.ndarray, wavelength_m: float
) -> np.ndarray:
    """Complex factor on each scatterer's echo amplitude from the road bounce, shape ``p.shape[:-1]``.

    Each way (TX -> scatterer, scatterer -> RX) the field is the direct ray plus the ray reflected by the
    road, i.e. coming from the scatterer's image below the road (the two-ray model, e.g. Skolnik, *Radar
    Handbook*, 3rd ed., ch. 26)::

        F = (1 + Gamma rho a_t exp(j 2 pi Delta / lambda)) (1 + Gamma rho a_r exp(j 2 pi Delta / lambda))

    a product of the four paths of a monostatic radar (direct-direct, two mixed, bounce-bounce).
    ``Delta = R_image - R_direct`` (about ``2 h z / d``), ``rho = R_direct / R_image`` the spreading of the
    longer ray, ``a = sqrt(G(image direction) / G(direct direction))`` of that antenna, ``Gamma`` the
    road's :meth:`RoadSurface.reflection` at the grazing angle ``sin psi = (h + z) / R_image``. The sign of
    the phase follows :mod:`hw_sim.synth` (a longer path advances the IF phase, ``+f tau``). The extra delay
    (centimetres) is far below a range bin, so a complex factor per scatterer (and chirp) is exact enough.
    A scatterer on the road (``z = 0``) gets ``(1 + Gamma)^2``: near grazing it vanishes, as it should.

    ``radar_pos`` (3,) world, ``rot`` the pose's rotation (rows: radar axes), ``p`` (..., 3) world.
    """
    p = np.asarray(p, dtype=np.float64)
    img = p * np.array([1.0, 1.0, -1.0])
    img[..., 2] = -np.maximum(p[..., 2], 0.0)
    d_dir = p - radar_pos
    d_img = img - radar_pos
    r_dir = np.maximum(np.linalg.norm(d_dir, axis=-1), 1e-6)
    r_img = np.maximum(np.linalg.norm(d_img, axis=-1), 1e-6)
    sin_psi = np.clip((radar_pos[2] - img[..., 2]) / r_img, 0.0, 1.0)
    gamma = road.reflection(sin_psi, wavelength_m)
    rel_d = d_dir @ rot.T
    rel_i = d_img @ rot.T

    def _az_el(rel):
        return np.arctan2(rel[..., 0], rel[..., 1]), np.arctan2(rel[..., 2], np.hypot(rel[..., 0], rel[..., 1]))

    az_d, el_d = _az_el(rel_d)
    az_i, el_i = _az_el(rel_i)
    a_t = np.sqrt(radio.tx.gain_linear(az_i, el_i) / radio.tx.gain_linear(az_d, el_d))
    a_r = np.sqrt(radio.rx.gain_linear(az_i, el_i) / radio.rx.gain_linear(az_d, el_d))
    delta = r_img - r_dir
    ray = gamma * (r_dir / r_img) * np.exp(2j * math.pi * ((delta / wavelength_m) % 1.0))
    return (1.0 + ray * a_t) * (1.0 + ray * a_r)


# --- receiver imperfections ---------------------------------------------------------------------------

# Arithmetic behind the default ``physics.phase_noise_deg_rms`` (0.2 deg). The LO phase noise of a return
# of delay tau is differenced by the mixer: residual PSD S(f) 4 sin^2(pi f tau) ~ S(f) (2 pi f tau)^2. For a
# VCO/PLL of -85 dBc/Hz at 100 kHz falling 20 dB/decade (24 GHz ISM MMIC class), S(f) = 2 L(f) makes the
# residual white at 2 * 31.6 * (2 pi tau)^2 rad^2/Hz = 1.0e-8 rad^2/Hz at 300 m (tau = 2 us); averaged over a
# 5 ms ramp that leaves 1e-3 rad = 0.06 deg per chirp. 0.2 deg allows for ramp start-frequency jitter of the
# synthesiser on top; it is applied to every echo alike (not scaled by its delay), common to the RX channels
# (one LO), and not to the TX->RX leakage (0.15 m: fully correlated).


@dataclass(frozen=True)
class ReceiverImperfections:
    """What a real receive chain adds between the antennas and the ADC (all zero: an ideal receiver).

    Applied by :func:`hw_sim.synth.synthesize_if` after synthesis and before quantisation, per RX channel:
    channel mismatch, then I/Q imbalance, then DC offset; the phase noise multiplies the echoes per chirp.
    """

    #: gain of the Q rail relative to I (dB) and its quadrature phase error (deg): Q' = g (Q cos phi + I sin phi),
    #: i.e. y = mu x + nu conj(x) with mu = (1 + g e^{j phi}) / 2, nu = (1 - g e^{-j phi}) / 2: an image at the
    #: mirrored beat frequency |nu|^2 / |mu|^2 below the echo
    iq_gain_imbalance_db: float = 0.0
    iq_phase_imbalance_deg: float = 0.0
    #: DC offset per rail (counts RMS over units; drawn per seed and channel)
    dc_offset_counts: float = 0.0
    #: per-chirp phase error of the echoes (deg RMS), common to the channels, drawn per frame
    phase_noise_deg_rms: float = 0.0
    #: per-element gain (dB RMS) / phase (deg RMS) error left by the calibration, drawn per seed
    channel_mismatch_db: float = 0.0
    channel_mismatch_deg: float = 0.0

    @property
    def active(self) -> bool:
        return any(v != 0.0 for v in dataclasses.astuple(self))

    def iq_coefficients(self) -> tuple[complex, complex]:
        """``(mu, nu)`` of ``y = mu x + nu conj(x)`` for this I/Q imbalance."""
        g = 10.0 ** (self.iq_gain_imbalance_db / 20.0)
        phi = math.radians(self.iq_phase_imbalance_deg)
        return (1.0 + g * complex(math.cos(phi), math.sin(phi))) / 2.0, (1.0 - g * complex(math.cos(phi), -math.sin(phi))) / 2.0

    def board_errors(self, seed: int, n_rx: int) -> tuple[np.ndarray, np.ndarray]:
        """Per-seed draws: complex channel mismatch ``(n_rx,)`` and complex DC offset ``(n_rx,)`` (counts).

        From a generator seeded by the scene seed only, so a unit keeps its errors over all its frames.
        """
        g = np.random.default_rng([seed & 0x7FFFFFFF, 0xCA11B])
        gain_db = g.standard_normal(n_rx) * self.channel_mismatch_db
        phase = np.radians(g.standard_normal(n_rx) * self.channel_mismatch_deg)
        dc = g.standard_normal((n_rx, 2)) * self.dc_offset_counts
        mismatch = 10.0 ** (gain_db / 20.0) * np.exp(1j * phase)
        if n_rx == 1:  # one element: nothing to mismatch against (its gain error is gain_offset_db's)
            mismatch = np.ones(1, dtype=np.complex128)
        return mismatch, dc[:, 0] + 1j * dc[:, 1]

    def apply(self, x: np.ndarray, seed: int) -> np.ndarray:
        """Channel mismatch, I/Q imbalance and DC offset on ``x`` ``(n_rx, n_chirps, n_samples)`` (new array)."""
        mismatch, dc = self.board_errors(seed, x.shape[0])
        y = x * mismatch[:, None, None] if self.channel_mismatch_db or self.channel_mismatch_deg else x.copy()
        if self.iq_gain_imbalance_db or self.iq_phase_imbalance_deg:
            g = 10.0 ** (self.iq_gain_imbalance_db / 20.0)
            phi = math.radians(self.iq_phase_imbalance_deg)
            q = g * (y.imag * math.cos(phi) + y.real * math.sin(phi))
            y = y.real + 1j * q
        if self.dc_offset_counts:
            y = y + dc[:, None, None]
        return y
