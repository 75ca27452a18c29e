"""Physics model choices of the simulator: one record per scenario, the ``[physics]`` table.

Every field is a documented modelling choice (its basis in the field's comment). The defaults are the
more physical choice; ``preset = "v1"`` restores the model every figure before the evaluation corpus was
measured on (white glint, near face 70 % of the RCS, narrow elevation beams, no road bounce, an ideal
receiver), so tests that guard figures measured on it keep their instrument.

Schema::

    [physics]
    preset = "v1"        # optional: start from a named preset, then apply the keys below
    # ... one key per field of Physics
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Physics:
    """Modelling choices of the simulated world and board (see module docstring)."""

    #: name of the preset the record started from ("" = the defaults)
    preset: str = ""

    # --- antennas, propagation, receiver (hw_sim.radio, hw_sim.synth, hw_sim.boards.apply_physics) ---
    #: elevation beamwidths of the SIMO board's antennas (Lim et al. 2021 give none): "gain-implied" =
    #: the widths that Table 1's gains and azimuth widths imply with Kraus' 32000 / (th_az th_el)
    #: (TX 75 deg, RX 73 deg; arithmetic in hw_sim.radio.elevation_beamwidth_deg), "wide" = the lossless
    #: upper bound 41253 / (th_az th_el) (TX 97 deg, RX 94 deg), "narrow" = 12 / 14 deg (the v1 assumption).
    #: The Distance2Go keeps its datasheet 42 x 20 deg whatever this says.
    elevation: str = "gain-implied"
    #: road-bounce multipath: every scatterer's echo is multiplied by the four-path (two-ray each way)
    #: propagation factor over a flat road (hw_sim.radio.road_bounce_factor)
    road_bounce: bool = True
    #: relative permittivity and loss tangent of the road surface at 24 GHz (dry asphalt, about 3-5 with a
    #: small loss; Li & Sarabandi, IEEE TAP 47(5) 1999, measured about 3.2 - j0.1 at millimetre waves)
    road_permittivity: float = 3.2
    road_loss_tangent: float = 0.03
    #: RMS height of the road surface's roughness (mm), for the Ament/Rayleigh factor of the specular
    #: reflection exp(-2 (2 pi sigma_h sin psi / lambda)^2); dense asphalt texture is 1-3 mm
    road_roughness_mm: float = 2.0
    #: polarisation of the antennas relative to the road: "horizontal" (E parallel to the road, |Gamma| near
    #: 1 at grazing, no Brewster angle: the stronger multipath) or "vertical"
    polarisation: str = "horizontal"
    #: receiver I/Q imbalance: gain of Q relative to I (dB) and quadrature phase error (deg); a few tenths
    #: of a dB and a few degrees are typical of 24 GHz homodyne MMICs (Infineon BGT24MTR12/BGT24LTR11 class)
    iq_gain_imbalance_db: float = 0.3
    iq_phase_imbalance_deg: float = 3.0
    #: DC offset per I and Q rail after the IF amplifier and ADC (counts RMS over units, drawn per seed and
    #: channel): the ADC's offset error and the residual mixer DC, a few LSB on a 12-bit converter
    dc_offset_counts: float = 4.0
    #: per-chirp residual phase noise after range correlation (deg RMS), common to the RX channels (one LO);
    #: the arithmetic is in hw_sim.radio (above ReceiverImperfections)
    phase_noise_deg_rms: float = 0.2
    #: per-element gain (dB RMS) and phase (deg RMS) errors left uncorrected by the board's calibration
    #: vector (drift with temperature and ageing after factory calibration), drawn per seed
    channel_mismatch_db: float = 0.5
    channel_mismatch_deg: float = 5.0
    #: unit-to-unit / radome / temperature offset of the whole receive chain (dB): scales every echo and the
    #: TX->RX leakage, not the thermal noise
    gain_offset_db: float = 0.0

    # --- vehicles (hw_sim.vehicles, hw_sim.scene, hw_sim.traffic) ---
    #: scattering phase and amplitude of a moving vehicle's scattering centres: "aspect" = smooth random
    #: functions of the aspect angle (correlation width lambda / (2 d) for a centre of size d) plus a slow
    #: body vibration, so glint is correlated over frames (extended-target glint: Delano, Proc. IRE 41, 1953;
    #: Skolnik (ed.), Radar Handbook 3rd ed. 2008, on RCS fluctuation); "white" = new random phases every frame
    glint: str = "aspect"
    #: rms body vibration (mm) of each scattering centre along the line of sight ("aspect" glint only), a
    #: Gaussian process scaled with speed up to 10 m/s: suspension and body modes of road vehicles
    #: (1-2 Hz heave/pitch, panel vibration) move points by millimetres (Gillespie, Fundamentals of Vehicle
    #: Dynamics, SAE 1992, ch. 5)
    glint_vibration_mm: float = 1.0
    #: correlation time (s) of that vibration (Gaussian correlation exp(-t^2 / 2 T^2)); ~1/(2 pi f) for the
    #: 1-1.5 Hz sprung-mass mode
    glint_vibration_s: float = 0.15
    #: vehicle scatterer layout: "centres" = scattering centres at several heights per body type (bumper,
    #: licence plate, lights, wheel houses, mirrors, pillars, roof edge; cab, box edges; wheels, fork,
    #: engine, rider), the near face below half the RCS; "near-face" = three near-face points with 70 %
    #: of the RCS, sides 25 %, far face 5 %
    body: str = "centres"
    #: a scatterer whose line of sight to the radar passes through another vehicle's body box is attenuated by
    #: ``shadow_loss_db`` (knife-edge diffraction over a vehicle body at 24 GHz: the Fresnel radius a few
    #: metres behind it is ~0.2-0.4 m, so a point well inside the shadow sees the ITU-R P.526 knife-edge
    #: loss J(v) ~ 20 dB at v ~ 2)
    shadowing: bool = True
    #: attenuation (dB, two-way power) of a shadowed scatterer
    shadow_loss_db: float = 20.0
    #: random traffic: "idm" = Intelligent Driver Model car following (Treiber, Hennecke & Helbing, Phys.
    #: Rev. E 62, 1805, 2000) with MOBIL-like lane changes (Kesting, Treiber & Helbing, Transp. Res.
    #: Rec. 1999, 86, 2007);
    #: "v1" = constant-speed platoons without overtaking
    traffic_model: str = "idm"
    #: default SDLP (m) of random drivers' weave inside the lane (a ``[[traffic]]`` key overrides it);
    #: on-road motorway driving measures ~0.2 m (Verster & Roth, Int. J. Gen. Med. 4, 359, 2011)
    weave_sdlp_m: float = 0.2
    #: default sd (m) of each random driver's own offset from the lane centre ([[traffic]] overrides it)
    lateral_offset_sd_m: float = 0.25

    # --- surveillance site (Distance2Go, hw_sim.events / hw_sim.pedestrian) ---
    #: pedestrian micro-Doppler model: "boulic" = limb kinematics of Boulic, Magnenat-Thalmann & Thalmann
    #: 1990 (The Visual Computer 6:344-358; joint trajectories fitted to measured gait as functions of the
    #: relative velocity, the model of Chen, The Micro-Doppler Effect in Radar, 2011, ch. 5) with ellipsoid
    #: segments; "sinusoid" = eight point scatterers swinging sinusoidally (hw_sim.pedestrian, v1)
    gait: str = "boulic"
    #: vehicle scatterers on flat panels (bumpers, doors, tailgate) have a flat plate's aspect lobe
    #: cos^2 * sinc^2 (Knott, Shaeffer & Tuley, Radar Cross Section, 2nd ed. 2004, ch. 6) above a diffuse
    #: floor; false = every scatterer isotropic (v1)
    vehicle_lobes: bool = True
    #: vehicle wheels rotate: rim and tread scatterers with the rim's tangential velocity, so the wheel's
    #: micro-Doppler spans 0..2v (Chen 2011, ch. 4); false = static wheel-arch points only (v1)
    wheels: bool = True
    #: static surroundings of the surveillance site: "urban" = the v1 objects plus parked cars (several
    #: scatterers each), a fence with posts every 2 m, a building wall and trees/bushes whose leaves sway in
    #: the wind (Billingsley, Low-Angle Radar Land Clutter, 2002, ch. 6); "v1" = the seven point objects only
    site_clutter: str = "urban"

    def __post_init__(self) -> None:
        for key, allowed in _CHOICES.items():
            if getattr(self, key) not in allowed:
                raise ValueError(f"{key} must be one of {list(allowed)}, got {getattr(self, key)!r}")
        for key in ("road_permittivity",):
            if getattr(self, key) < 1.0:
                raise ValueError(f"{key} must be >= 1, got {getattr(self, key)!r}")
        for key in ("road_loss_tangent", "road_roughness_mm", "dc_offset_counts", "phase_noise_deg_rms",
                    "channel_mismatch_db", "channel_mismatch_deg"):
            if getattr(self, key) < 0.0:
                raise ValueError(f"{key} must be >= 0, got {getattr(self, key)!r}")
        if self.glint_vibration_s <= 0 or min(self.glint_vibration_mm, self.shadow_loss_db, self.weave_sdlp_m,
                                              self.lateral_offset_sd_m) < 0:
            raise ValueError("glint_vibration_s must be > 0; glint_vibration_mm, shadow_loss_db, weave_sdlp_m and "
                             "lateral_offset_sd_m >= 0")


#: allowed values of the string fields
_CHOICES: dict[str, tuple[str, ...]] = {
    "elevation": ("gain-implied", "wide", "narrow"),
    "polarisation": ("horizontal", "vertical"),
    "glint": ("aspect", "white"),
    "body": ("centres", "near-face"),
    "traffic_model": ("idm", "v1"),
    "gait": ("boulic", "sinusoid"),
    "site_clutter": ("urban", "v1"),
}


#: named presets: field -> value (fields not listed keep their defaults)
PRESETS: dict[str, dict[str, Any]] = {
    "v1": {
        "elevation": "narrow",
        "road_bounce": False,
        "iq_gain_imbalance_db": 0.0,
        "iq_phase_imbalance_deg": 0.0,
        "dc_offset_counts": 0.0,
        "phase_noise_deg_rms": 0.0,
        "channel_mismatch_db": 0.0,
        "channel_mismatch_deg": 0.0,
        "glint": "white", "body": "near-face", "shadowing": False, "traffic_model": "v1",
        "weave_sdlp_m": 0.0, "lateral_offset_sd_m": 0.0,
        "gait": "sinusoid", "vehicle_lobes": False, "wheels": False, "site_clutter": "v1",
    },
}


class PhysicsError(ValueError):
    """A ``[physics]`` table names an unknown key or preset, or a value of the wrong type."""


def parse_physics(table: dict[str, Any] | None, where: str = "physics.") -> Physics:
    """The :class:`Physics` of a scenario's ``[physics]`` table (``None`` or empty: the defaults)."""
    table = dict(table or {})
    fields = {f.name: f for f in dataclasses.fields(Physics)}
    values: dict[str, Any] = {}
    preset = table.pop("preset", "")
    if preset:
        if preset not in PRESETS:
            raise PhysicsError(f"{where}preset must be one of {sorted(PRESETS)}, got {preset!r}")
        values.update(PRESETS[preset])
        values["preset"] = preset
    for key, val in table.items():
        if key not in fields:
            raise PhysicsError(f"{where}{key}: unknown key; known: {sorted(k for k in fields if k != 'preset')}")
        default = fields[key].default
        if isinstance(default, bool):
            ok = isinstance(val, bool)
        elif isinstance(default, (int, float)):
            ok = isinstance(val, (int, float)) and not isinstance(val, bool)
            val = type(default)(val) if ok and isinstance(default, float) else val
        elif isinstance(default, str):
            ok = isinstance(val, str)
        elif isinstance(default, tuple):
            ok = isinstance(val, (list, tuple))
            val = tuple(val) if ok else val
        else:
            ok = True
        if not ok:
            raise PhysicsError(f"{where}{key} must be like {default!r}, got {val!r}")
        values[key] = val
    try:
        return Physics(**values)
    except (TypeError, ValueError) as exc:
        raise PhysicsError(f"{where}{exc}") from None
