"""Hypothesiser/associator role: the gate (Lim eq. 17) and the association weights (eqs. 18-19, or cheap JPDA),
with seniority (a tentative track only uses detections no more senior track validated), and the wider exclusion
gate that keeps a tracked vehicle's detections from seeding."""

from __future__ import annotations

from dataclasses import dataclass

import math

import numpy as np

from edge import native
from edge.track.config import AssociationConfig
from edge.track.pdaf import Innovations, InnovationsEach, association_weights, gate_threshold, unit_ball_volume
from edge.track.table import Measurements

__all__ = ["Hypotheses", "PdaAssociator"]


@dataclass
class Hypotheses:
    """``beta`` (T, M) association weights, ``beta0`` (T,) the no-detection weight, ``gated`` (T, M) validated pairs."""

    beta: np.ndarray
    beta0: np.ndarray
    gated: np.ndarray


class PdaAssociator(native.KernelUser):
    """Gate and association probabilities of every track x detection pair."""

    def __init__(self, cfg: AssociationConfig) -> None:
        self.cfg = cfg
        self._gamma = {n: gate_threshold(cfg.prob_gate, n) for n in (2, 3)}
        self.gamma = self._gamma.__getitem__  # gamma(n): the validation gate threshold of eq. 17
        self.exclusion_gamma = {n: gate_threshold(max(cfg.init_exclusion_prob, cfg.prob_gate), n) for n in (2, 3)}
        #: the exact pre-gate (:func:`edge.track.pdaf.innovations_each`); off only to test that it changes nothing
        self.pregate = True
        #: the compiled association (``edge.native._track``) for one ``S`` per pair, or None: numpy
        self.kernel = native.load("_track")

    def prune_gamma(self, n: int) -> float | None:
        """The largest gate threshold applied to the association's distances (the validation gate, or the
        exclusion gate when it uses the same noise): pairs surely outside it need no exact distance."""
        if not self.pregate:
            return None
        return self.exclusion_gamma[n] if self.cfg.seed_exclusion_noise == "snr" else self._gamma[n]

    def associate(self, meas: Measurements, inn: Innovations, confirmed: np.ndarray,
                  seniority: np.ndarray) -> Hypotheses:
        """Confirmed tracks share detections (PDAF/JPDA); a tentative track only sees detections that no more senior
        track validated (confirmed first, then more hits), unless the detection is one of a resolved pair."""
        gamma = self._gamma[meas.z.shape[1]]
        if self.kernel is not None and isinstance(inn, InnovationsEach) and inn.d2.size:
            return self._associate_kernel(meas, inn, gamma, confirmed, seniority)
        if confirmed.all():  # no tentative track: every track may use every detection
            allowed = None
        else:
            rank = np.where(confirmed, np.inf, seniority.astype(float))
            owner = np.where(inn.d2 <= gamma, rank[:, None], -np.inf).max(axis=0)
            allowed = confirmed[:, None] | (rank[:, None] >= owner[None, :])
            if meas.pair is not None:  # one of two vehicles resolved in angle: the junior track may be the other one
                allowed |= (meas.pair >= 0)[None, :]
        beta, beta0, gated = association_weights(inn, gamma, self.cfg.prob_detect, self.cfg.prob_gate,
                                                 self.cfg.association, allowed)
        return Hypotheses(beta, beta0, gated)

    def _associate_kernel(self, meas: Measurements, inn: InnovationsEach, gamma: float, confirmed: np.ndarray,
                          seniority: np.ndarray) -> Hypotheses:
        """:meth:`associate` in the compiled kernel (the same arithmetic and summation order as numpy's)."""
        c = self.cfg
        n = meas.z.shape[1]
        if c.association not in ("pdaf", "jpda"):
            raise ValueError(f"unknown association method {c.association!r}: choose pdaf or jpda")
        beta, beta0, gated, vol = self.kernel.associate_each(
            inn.d2, inn.det_s, gamma, unit_ball_volume(n) * gamma ** (n / 2.0), (2.0 * math.pi) ** (n / 2.0),
            c.prob_detect, 1.0 - c.prob_gate * c.prob_detect, c.association == "jpda", confirmed, seniority, meas.pair)
        inn.gate_volume = vol
        return Hypotheses(beta, beta0, gated)

    def claimed(self, mp, xp: np.ndarray, measurement_model) -> np.ndarray:
        """(M,) detections inside some track's exclusion gate (they never seed): the association's distances, or
        with ``seed_exclusion_noise = "constant"`` those of the constant noise model with the scatterer height's term
        (:meth:`edge.track.roles.measure.MeasurementModel.seed_exclusion_d2`)."""
        return measurement_model.seed_exclusion_claimed(mp, xp, self.cfg.seed_exclusion_noise == "constant",
                                                        self.exclusion_gamma[mp.zh.shape[1]],
                                                        self.cfg.scatterer_height_sigma_m**2)
