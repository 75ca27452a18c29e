"""The lane tracker's roles (after Stone Soup's ``MultiTargetTracker``) and the factory that builds them from the
per-role sections of :class:`edge.track.config.PdafConfig`. Each role gets only its own section(s)."""

from __future__ import annotations

from dataclasses import dataclass

from edge.track.config import (AssociationConfig, ConfirmerConfig, DeleterConfig, FieldOfViewConfig,
                               InitiatorConfig, LateralSmootherConfig, MeasurementConfig, MotionConfig, PdafConfig,
                               ReanchorConfig, SameVehicleConfig, section)
from edge.track.roles.associate import Hypotheses, PdaAssociator
from edge.track.roles.box import SameVehicleBox
from edge.track.roles.confirm import Confirmer
from edge.track.roles.delete import TrackDeleter, resolved_pairs
from edge.track.roles.initiate import SeedInitiator
from edge.track.roles.measure import (ConstantNoiseModel, MeasurementModel, MeasurementPrediction, Prediction,
                                      SnrNoiseModel)
from edge.track.roles.post import Frame, LateralSmoother, Reanchor
from edge.track.roles.predict import CvPredictor, ImmPdaUpdater, ImmPredictor, PdaUpdater

__all__ = ["Roles", "build_roles", "Frame", "Hypotheses", "Prediction", "MeasurementPrediction", "resolved_pairs",
           "CvPredictor", "ImmPredictor", "PdaUpdater", "ImmPdaUpdater", "MeasurementModel", "ConstantNoiseModel",
           "SnrNoiseModel", "PdaAssociator", "SeedInitiator", "Confirmer", "TrackDeleter", "LateralSmoother",
           "Reanchor", "SameVehicleBox"]


@dataclass
class Roles:
    """The role objects of one tracker; ``post_steps`` run in order after the hit counters."""

    predictor: CvPredictor | ImmPredictor
    measurement_model: MeasurementModel
    associator: PdaAssociator
    updater: PdaUpdater | ImmPdaUpdater
    initiator: SeedInitiator
    confirmer: Confirmer
    deleter: TrackDeleter
    post_steps: tuple
    #: roles that keep per-track state of their own, restarted on rows a post-step moved
    stateful: tuple


def build_roles(cfg: PdafConfig) -> Roles:
    """The roles ``cfg`` selects: ``motion_model`` picks the predictor and its updater, ``measurement_noise`` the
    measurement model; ``lateral_smoother`` and ``reanchor_m`` > 0 add the post-steps."""
    motion, meas_cfg = section(cfg, MotionConfig), section(cfg, MeasurementConfig)
    assoc, fov = section(cfg, AssociationConfig), section(cfg, FieldOfViewConfig)
    box = SameVehicleBox(section(cfg, SameVehicleConfig), meas_cfg.azimuth_sigma_deg)
    mm = SnrNoiseModel(meas_cfg) if meas_cfg.measurement_noise == "snr" else ConstantNoiseModel(meas_cfg)
    associator = PdaAssociator(assoc)
    if motion.motion_model == "imm":
        predictor, updater = ImmPredictor(motion), ImmPdaUpdater(assoc, motion, mm, associator.gamma)
    else:
        predictor, updater = CvPredictor(motion), PdaUpdater(mm)
    post, stateful = [], [predictor]
    smoother = section(cfg, LateralSmootherConfig)
    if smoother.lateral_smoother:
        post.append(LateralSmoother(smoother, predictor))
        stateful.append(post[-1])
    reanchor = section(cfg, ReanchorConfig)
    if reanchor.reanchor_m > 0:
        post.append(Reanchor(reanchor, box, mm, 2.0 * assoc.scatterer_height_sigma_m, fov.min_range_m))
    return Roles(predictor, mm, associator, updater,
                 SeedInitiator(section(cfg, InitiatorConfig), fov, box, mm, predictor,
                               assoc.scatterer_height_sigma_m),
                 Confirmer(section(cfg, ConfirmerConfig), assoc, box),
                 TrackDeleter(section(cfg, DeleterConfig), fov, box), tuple(post), tuple(stateful))
