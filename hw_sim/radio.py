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
"""

from __future__ import annotations

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
