"""Configuration of the lane profile's tracker (section ``track.pdaf``), one dataclass per role.

:class:`PdafConfig` is the TOML section: it holds every role's fields under their flat keys
(``track.pdaf.KEY``). :func:`edge.track.roles.build_roles` hands each role only its own section(s)
(:func:`section`), so a role cannot read another role's settings. Measured effects and their history:
``docs/decisions/0002-lane-tracker-roles.md`` and the rule inventory.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import TypeVar

__all__ = ["AssociationConfig", "MeasurementConfig", "MotionConfig", "SameVehicleConfig", "FieldOfViewConfig",
           "InitiatorConfig", "ConfirmerConfig", "DeleterConfig", "LateralSmootherConfig", "ReanchorConfig",
           "PublishConfig", "PdafConfig", "ROLE_SECTIONS", "section"]


def _f(default, doc: str, unit: str | None = None, lo=None, hi=None, choices: tuple | None = None):
    """A config field with its doc, unit, bounds and choices in the metadata :mod:`edge.config` reads."""
    meta: dict = {"doc": doc}
    if unit is not None:
        meta["unit"] = unit
    if choices is not None:
        meta["choices"] = choices
    if lo is not None:
        meta["min"] = lo
    if hi is not None:
        meta["max"] = hi
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class AssociationConfig:
    """Gate and association weights (Lim et al. §III-B, eqs. 17-19)."""

    association: str = _f("jpda", "pdaf: Lim eqs. 17-19 per track; jpda: Fitzgerald's cheap JPDA, the same weights "
                                  "shared between tracks whose gates hold the same detection",
                          choices=("pdaf", "jpda"))
    prob_detect: float = _f(0.9, "P_D of eqs. 18-19: probability that a tracked vehicle gives a detection in a frame",
                            lo=0.05, hi=0.999)
    prob_gate: float = _f(0.99, "P_G of eq. 17: probability that the gate holds the true detection; sets the gate "
                                "threshold gamma", lo=0.5, hi=0.99999)
    init_exclusion_prob: float = _f(0.99999, "a detection inside this (wider) chi-square gate of a track never seeds "
                                             "a new track", lo=0.5, hi=0.9999999)
    seed_exclusion_noise: str = _f("constant", "noise model of that exclusion gate with measurement_noise = snr: "
                                               "constant (range_sigma_m, azimuth_sigma_deg; wider for strong "
                                               "detections between two unresolved vehicles) or snr",
                                   choices=("constant", "snr"))
    scatterer_height_sigma_m: float = _f(1.0, "sd of a vehicle scatterer's height about the pipeline's "
                                              "target_height_m (bumpers to truck roofs): near the radar a higher "
                                              "scatterer appears nearer and faster, so the constant exclusion noise, "
                                              "the confirm block's and the re-anchoring's speed tests (2 sd) and the "
                                              "seeds' least range allow for it",
                                         "m", 0.0, 5.0)


@dataclass(frozen=True)
class MeasurementConfig:
    """The measurement model: converted polar position [and ground radial speed] with its noise ``R``."""

    use_radial_speed: bool = _f(True, "add the measured ground radial speed to the measurement (an EKF row)")
    measurement_noise: str = _f("snr", "constant: one R per track from range_sigma_m and azimuth_sigma_deg at its "
                                       "prediction (Lim); snr: one R per detection from its SNR, sigma^2 = "
                                       "sigma0^2 / SNR + floor^2 (the Cramer-Rao form)", choices=("constant", "snr"))
    range_sigma_m: float = _f(0.15, "range sd of the constant noise model", "m", 0.001, 10.0)
    azimuth_sigma_deg: float = _f(0.5, "azimuth sd of the constant noise model (also sizes the same-vehicle box)",
                                  "deg", 0.001, 20.0)
    radial_speed_sigma_mps: float = _f(0.3, "radial speed sd", "m/s", 0.001, 20.0)
    extent_sigma_m: float = _f(0.3, "isotropic position sd of an extended vehicle (which scatterer gives the peak), "
                                    "constant noise model", "m", 0.0, 10.0)
    extent_along_sigma_m: float = _f(1.3, "initial spread of a vehicle's detections along its heading (a 4.5 m car: "
                                          "4.5 / sqrt(12)); then learned per track", "m", 0.0, 20.0)
    extent_alpha: float = _f(0.05, "smoothing factor of the learned along-heading spread (0 = not learned)",
                             lo=0.0, hi=1.0)
    extent_max_sigma_m: float = _f(6.0, "upper bound of the learned along-heading spread (a 20 m truck: 5.8 m)",
                                   "m", 0.1, 50.0)
    extent_near_side_factor: float = _f(0.0, "fraction of the along-heading spread kept in the state update of a "
                                             "detection nearer than the track's prediction: the track follows the "
                                             "near face and the body lies behind it (1 = symmetric); needs "
                                             "motion_model = imm and measurement_noise = snr", lo=0.0, hi=1.0)
    snr_azimuth_sigma_deg: float = _f(0.88, "snr noise: azimuth sd at 0 dB SNR (fitted on the simulated board; the "
                                            "Cramer-Rao bound of the 4-channel array is 0.96)", "deg", 0.001, 20.0)
    snr_azimuth_floor_deg: float = _f(0.03, "snr noise: azimuth sd added in quadrature (calibration, glint)",
                                      "deg", 0.0, 5.0)
    snr_range_sigma_m: float = _f(0.165, "snr noise: range sd at 0 dB SNR", "m", 0.001, 10.0)
    snr_range_floor_m: float = _f(0.015, "snr noise: range sd added in quadrature", "m", 0.0, 5.0)
    snr_extent_sigma_m: float = _f(0.47, "snr noise: isotropic position sd of an extended vehicle's scatterers "
                                         "(fitted on simulated car bodies)", "m", 0.0, 10.0)
    snr_min_db: float = _f(6.0, "snr noise: an SNR below this (or not finite) counts as this", "dB", -20.0, 60.0)
    snr_max_db: float = _f(45.0, "snr noise: an SNR above this counts as this", "dB", -20.0, 100.0)


@dataclass(frozen=True)
class MotionConfig:
    """The predictor: one constant-velocity model (cv) or an IMM of lane keeping and manoeuvring (imm)."""

    motion_model: str = _f("imm", "cv: one constant-velocity Kalman filter; imm: lane keeping (velocity across the "
                                  "road decaying to zero) and manoeuvring (cv), mixed by an IMM (edge.track.imm)",
                           choices=("cv", "imm"))
    q_lateral_m2ps3: float = _f(0.5, "cv model: white-noise acceleration density across the boresight",
                                "m^2/s^3", 1e-6, 1000.0)
    q_along_m2ps3: float = _f(2.0, "white-noise acceleration density along the boresight (both models)",
                              "m^2/s^3", 1e-6, 1000.0)
    imm_keep_q_across_m2ps3: float = _f(0.002, "lane keeping: white-noise acceleration density across the road",
                                        "m^2/s^3", 1e-9, 10.0)
    imm_keep_tau_s: float = _f(1.0, "lane keeping: time constant of the decay of the velocity across the road "
                                    "(0 = no decay)", "s", 0.0, 100.0)
    imm_manoeuvre_q_lateral_m2ps3: float = _f(2.0, "manoeuvring: white-noise acceleration density across the "
                                                   "boresight", "m^2/s^3", 1e-6, 1000.0)
    imm_p_keep_to_manoeuvre: float = _f(0.02, "per-frame probability that a lane-keeping vehicle starts to manoeuvre",
                                        lo=1e-6, hi=0.5)
    imm_far_p_keep_to_manoeuvre: float = _f(0.002, "that probability far away (from imm_far_from_m to imm_far_to_m, "
                                                   "log-linear), where the mode likelihoods carry no information; "
                                                   "= imm_p_keep_to_manoeuvre: off", lo=1e-6, hi=0.5)
    imm_far_from_m: float = _f(150.0, "ground range from which the switching probability falls", "m", 0.0, 1000.0)
    imm_far_to_m: float = _f(220.0, "ground range from which it is imm_far_p_keep_to_manoeuvre", "m", 0.0, 2000.0)
    imm_p_manoeuvre_to_keep: float = _f(0.02, "per-frame probability that a manoeuvre ends", lo=1e-6, hi=0.5)
    imm_init_keep_prob: float = _f(0.5, "lane-keeping probability of a new track", lo=0.0, hi=1.0)
    imm_keep_init_lateral_speed_sigma_mps: float = _f(0.5, "initial speed sd across the road of a seed's lane-keeping "
                                                           "mode (0 = init_lateral_speed_sigma_mps)",
                                                      "m/s", 0.0, 100.0)
    imm_min_mode_prob: float = _f(1e-3, "floor of either mode's probability", lo=0.0, hi=0.1)


@dataclass(frozen=True)
class SameVehicleConfig:
    """The same-vehicle box: how close a point or track must be to a track to be the same vehicle."""

    merge_lateral_m: float = _f(1.5, "half-width across the boresight of the same-vehicle box (near the radar)",
                                "m", 0.0, 20.0)
    merge_lateral_sigmas: float = _f(2.0, "... growing with range as this many azimuth sds (azimuth_sigma_deg)",
                                     lo=0.0, hi=10.0)
    merge_lateral_max_m: float = _f(3.0, "... up to this half-width", "m", 0.0, 20.0)
    merge_along_m: float = _f(5.0, "half-length along the boresight of the box, at least", "m", 0.0, 50.0)
    merge_headway_s: float = _f(0.5, "... or the track's speed times this headway", "s", 0.0, 5.0)
    merge_extent_factor: float = _f(3.5, "... or this many sds of the track's learned along-heading spread",
                                    lo=0.0, hi=10.0)
    merge_speed_mps: float = _f(2.0, "speed difference along the heading below which two tracks may be one vehicle",
                                "m/s", 0.0, 50.0)


@dataclass(frozen=True)
class FieldOfViewConfig:
    """Where tracks may be born and live."""

    min_range_m: float = _f(2.0, "tracks live beyond this ground range", "m", 0.0, 100.0)
    max_range_m: float = _f(370.0, "tracks live within this ground range", "m", 1.0, 2000.0)
    max_azimuth_deg: float = _f(40.0, "tracks live within this azimuth off the boresight", "deg", 1.0, 90.0)


@dataclass(frozen=True)
class InitiatorConfig:
    """Seeding tentative tracks from detections no track explains."""

    seed_min_radial_speed_mps: float = _f(1.0, "slower detections (ground radial speed) never seed: standing "
                                               "clutter", "m/s", 0.0, 20.0)
    seed_merge_speed_mps: float = _f(5.0, "radial-speed difference below which a detection in a track's "
                                          "same-vehicle box, or next to a stronger seed, does not seed",
                                     "m/s", 0.0, 50.0)
    init_merge_along_m: float = _f(10.0, "half-length along the boresight of one frame's seed-merge box",
                                   "m", 0.0, 50.0)
    init_along_speed_sigma_mps: float = _f(2.0, "initial speed sd along the road when the radial speed seeds it",
                                           "m/s", 0.01, 100.0)
    init_lateral_speed_sigma_mps: float = _f(1.5, "initial speed sd across the road", "m/s", 0.01, 100.0)
    init_speed_sigma_mps: float = _f(40.0, "initial speed sd when no radial speed is measured", "m/s", 0.1, 200.0)
    max_tracks: int = _f(128, "tentative and confirmed tracks held at most", lo=1, hi=4096)


@dataclass(frozen=True)
class ConfirmerConfig:
    """Confirmation (and the end of tentative tracks that cannot confirm)."""

    confirmation: str = _f("m_of_n", "m_of_n: confirm_m hits in the last confirm_n frames; score: the sequential "
                                     "log-likelihood-ratio track score reaches Wald's threshold (edge.track.score); "
                                     "either: whichever comes first", choices=("m_of_n", "score", "either"))
    confirm_m: int = _f(5, "M of the M-of-N confirmation", lo=1, hi=32)
    confirm_n: int = _f(10, "N of the M-of-N confirmation (frames)", lo=1, hi=32)
    score_prob_detect: float = _f(0.6, "P_D of the track score: detection probability where tracks are born",
                                  lo=0.05, hi=0.999)
    score_false_confirm_prob: float = _f(1e-4, "alpha of the score's sequential test (a false track confirms)",
                                         lo=1e-12, hi=0.5)
    score_true_reject_prob: float = _f(0.01, "beta of the score's sequential test (a vehicle's track is dropped)",
                                       lo=1e-9, hi=0.5)
    score_false_density_m2: float = _f(3e-2, "density of false moving detections per frame on the ground (the "
                                             "score's clutter density)", "1/m^2", 1e-12, 10.0)
    score_speed_span_mps: float = _f(139.0, "span of radial speeds over which false detections spread (the score's "
                                            "clutter density in the speed row)", "m/s", 0.1, 1000.0)
    moving_prob: float = _f(0.9999, "a track confirms only once its velocity differs from zero at this chi-square "
                                    "(2 dof) probability", lo=0.5, hi=0.9999999)
    confirm_min_speed_mps: float = _f(1.0, "... and its speed is at least this", "m/s", 0.0, 50.0)
    confirm_block_along_m: float = _f(17.0, "a tentative track does not confirm while a confirmed track moving alike "
                                            "lies within this along the boresight (a long vehicle seeded twice); "
                                            "0 = off", "m", 0.0, 100.0)
    confirm_block_lateral_m: float = _f(3.5, "... nor while one lies within this across, behind its near face, at "
                                             "its speed (a vehicle body's glint in the next lane)", "m", 0.0, 20.0)
    confirm_block_speed_mps: float = _f(1.0, "speed difference along of that glint test", "m/s", 0.0, 10.0)
    confirm_block_behind_m: float = _f(2.0, "the glint test counts tentative tracks at least this farther than the "
                                            "confirmed one", "m", 0.0, 50.0)
    tentative_keep_from_m: float = _f(200.0, "beyond this ground range a tentative track that cannot make M of N "
                                             "is kept while it has tentative_keep_min_hits in its last N frames",
                                      "m", 0.0, 2000.0)
    tentative_keep_min_hits: int = _f(1, "hits in the last confirm_n frames that keep a far tentative track",
                                      lo=1, hi=32)
    max_track_id: int = _f(255, "published ids are 1..max_track_id, reused oldest-released first", lo=1, hi=65535)


@dataclass(frozen=True)
class DeleterConfig:
    """Deleting tracks: misses, divergence, duplicates of another track."""

    delete_after_misses: int = _f(20, "a track is deleted after this many frames in a row without a detection",
                                  lo=1, hi=1000)
    max_position_sigma_m: float = _f(8.0, "... or once its position sd exceeds this", "m", 0.1, 1000.0)
    merge_state_prob: float = _f(0.99, "two tracks whose states differ less than this chi-square (4 dof) quantile "
                                       "are one vehicle", lo=0.5, hi=0.999999)
    merge_lateral_speed_mps: float = _f(2.0, "speed difference across the heading below which two tracks may be one "
                                             "vehicle", "m/s", 0.0, 50.0)
    merge_persist_frames: int = _f(30, "two tracks in one same-vehicle box for this many frames are one vehicle "
                                       "whatever their speeds across", lo=1, hi=10000)


@dataclass(frozen=True)
class LateralSmootherConfig:
    """Post-step: a straight-line filter across the boresight that gives the published lateral position."""

    lateral_smoother: bool = _f(True, "publish the lateral position of a straight-line filter per track that runs "
                                      "beside the motion model with the association's weights (a vehicle keeping "
                                      "its lane drives a straight line); everything else stays the motion model's")
    lateral_smoother_q_m2ps3: float = _f(1e-4, "its white-noise acceleration density", "m^2/s^3", 0.0, 10.0)
    lateral_smoother_init_speed_sigma_mps: float = _f(0.03, "a new track's line starts along the road direction "
                                                            "with at most this lateral speed sd", "m/s", 0.001, 100.0)
    lateral_smoother_hold_manoeuvre_prob: float = _f(0.6, "the line is held at the motion model's position while the "
                                                          "IMM's manoeuvring mode is more probable than this (1: "
                                                          "never)", lo=0.0, hi=1.0)
    lateral_smoother_hold_unresolved: bool = _f(True, "... and while the detection carrying the track is an "
                                                      "unresolved pair (two sources in one cell, not split)")
    lateral_smoother_reset_prob: float = _f(0.99, "the line restarts from the motion model's estimate when they "
                                                  "differ beyond this chi-square (1 dof) quantile (a Hausman test)",
                                            lo=0.5, hi=0.9999999)
    lateral_smoother_cusum_nats: float = _f(4.0, "... or when the CUSUM of the log-likelihood ratio motion model vs "
                                                 "line exceeds this; the published position moves towards the "
                                                 "motion model's as it grows", "nats", 0.0, 1e6)
    lateral_smoother_min_var_fraction: float = _f(0.1, "the Hausman test's variance is at least this fraction of the "
                                                       "motion model's", lo=1e-4, hi=1.0)


@dataclass(frozen=True)
class ReanchorConfig:
    """Post-step: a confirmed track that missed moves to its vehicle's near face."""

    reanchor_m: float = _f(17.0, "a confirmed track without a detection moves to an unclaimed detection up to this "
                                 "much nearer, in line with it and at its radial speed (it sat on the body; 0 = off)",
                           "m", 0.0, 100.0)
    reanchor_min_m: float = _f(1.0, "... and at least this much nearer", "m", 0.0, 100.0)
    reanchor_receding_only: bool = _f(True, "only receding tracks re-anchor (an approaching track is on its near "
                                            "face from afar)")
    reanchor_speed_mps: float = _f(1.0, "radial-speed difference within which the detection is the track's vehicle "
                                        "(near the radar wider by the scatterer height's speed error, 2 sd)",
                                   "m/s", 0.0, 20.0)


@dataclass(frozen=True)
class PublishConfig:
    """What :meth:`PdafTracker.published` returns."""

    publish_max_misses: int = _f(20, "confirmed tracks are published while they missed at most this many frames in "
                                     "a row", lo=0, hi=1000)
    publish_length: bool = _f(True, "publish length_m = sqrt(12) x the learned along-heading spread of a moving "
                                    "track")
    publish_tentative: bool = _f(False, "also publish tentative tracks (confirmed=False, track_id=0)")


#: the role sections, in the order of the flat TOML section's fields
ROLE_SECTIONS = (AssociationConfig, MeasurementConfig, MotionConfig, SameVehicleConfig, FieldOfViewConfig,
                 InitiatorConfig, ConfirmerConfig, DeleterConfig, LateralSmootherConfig, ReanchorConfig, PublishConfig)


@dataclass(frozen=True)
class PdafConfig(PublishConfig, ReanchorConfig, LateralSmootherConfig, DeleterConfig, ConfirmerConfig,
                 InitiatorConfig, FieldOfViewConfig, SameVehicleConfig, MotionConfig, MeasurementConfig,
                 AssociationConfig):
    """Parameters of :class:`edge.track.PdafTracker` (TOML section ``track.pdaf``): every role section's fields
    under one flat key each; defaults follow Lim et al. §III-B where it gives them."""


_S = TypeVar("_S")


def section(cfg: PdafConfig, cls: type[_S]) -> _S:
    """The role section ``cls`` (one of :data:`ROLE_SECTIONS`) of ``cfg``, with ``cfg``'s values."""
    if type(cfg) is cls:
        return cfg
    return cls(**{f.name: getattr(cfg, f.name) for f in dataclasses.fields(cls)})
