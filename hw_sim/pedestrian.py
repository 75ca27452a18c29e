"""Articulated pedestrian: torso, head, swinging arms and legs (micro-Doppler at the gait frequency).

A walking or jogging person is modelled, after the usual kinematic simplifications of gait models
(Boulic et al.), as nine point scatterers in the body frame (``x`` right, ``y`` forward, ``z`` up)
around the reference point (the feet's mid-point on the ground):

===========  =================  ==========================================================
scatterer    share of the RCS   motion relative to the body
===========  =================  ==========================================================
torso        ~55 %              vertical bob at twice the stride frequency (2-3 cm)
head         ~5 %               follows the torso
hands (2)    ~5 % each          fore-aft swing in anti-phase with the leg of the same side
knees (2)    ~7.5 % each        fore-aft swing, half the foot excursion
feet (2)     ~7.5 % each        fore-aft swing with amplitude ``v / (2 pi f)``
===========  =================  ==========================================================

A foot swinging with amplitude ``A = v / (2 pi f)`` at the stride frequency ``f`` moves, in the world
frame, between standstill (stance) and twice the walking speed (swing), as real feet do, and one
stride covers ``v / f`` metres. Walking: ``f`` about 0.8-1.0 Hz at 1.0-1.7 m/s; jogging: 1.3-1.5 Hz at
2.2-3.5 m/s. The total RCS of an adult at 24 GHz is about -5 to 0 dBsm.

The limb velocities are the analytic derivatives of the offsets, so the synthesiser's intra-frame
motion and Doppler are consistent with the positions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hw_sim.scene import Target

#: body-frame rest positions (m) and RCS shares of the nine scatterers
_REST = np.array(
    [
        [0.0, 0.0, 1.25],  # torso
        [0.0, 0.0, 1.65],  # head
        [-0.25, 0.0, 0.95],  # left hand
        [0.25, 0.0, 0.95],  # right hand
        [-0.10, 0.0, 0.50],  # left knee
        [0.10, 0.0, 0.50],  # right knee
        [-0.10, 0.0, 0.10],  # left foot
        [0.10, 0.0, 0.10],  # right foot
    ]
)
_SHARE = np.array([0.55, 0.05, 0.05, 0.05, 0.075, 0.075, 0.075, 0.075])
_SHARE = _SHARE / _SHARE.sum()
#: fore-aft swing amplitude of each scatterer relative to the foot amplitude, signed by phase
#: (left foot +1, right foot -1, each hand in anti-phase with its own side's foot)
_SWING = np.array([0.0, 0.0, -0.45, 0.45, 0.5, -0.5, 1.0, -1.0])


@dataclass
class Pedestrian(Target):
    """A walking/jogging person; ``rcs_m2`` is split over the limbs by :data:`_SHARE`."""

    stride_hz: float = 0.9
    speed_mps: float = 1.3
    gait_phase_rad: float = 0.0
    bob_m: float = 0.025

    @classmethod
    def make(
        cls,
        target_id: int,
        trajectory,
        *,
        total_rcs_m2: float,
        speed_mps: float,
        stride_hz: float,
        gait_phase_rad: float = 0.0,
        swerling: int = 1,
        t_start_s: float = -math.inf,
        t_end_s: float = math.inf,
    ) -> "Pedestrian":
        return cls(
            id=target_id,
            cls="pedestrian",
            trajectory=trajectory,
            offsets_m=_REST.copy(),
            rcs_m2=_SHARE * total_rcs_m2,
            swerling=swerling,
            t_start_s=t_start_s,
            t_end_s=t_end_s,
            stride_hz=stride_hz,
            speed_mps=speed_mps,
            gait_phase_rad=gait_phase_rad,
        )

    @property
    def foot_amplitude_m(self) -> float:
        return self.speed_mps / (2.0 * math.pi * self.stride_hz)

    def scatterers(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        w = 2.0 * math.pi * self.stride_hz
        ph = w * t_s + self.gait_phase_rad
        a = self.foot_amplitude_m * _SWING
        off = self.offsets_m.copy()
        vel = np.zeros_like(off)
        off[:, 1] += a * math.sin(ph)
        vel[:, 1] = a * w * math.cos(ph)
        # torso and head bob twice per stride
        off[:2, 2] += self.bob_m * math.sin(2.0 * ph)
        vel[:2, 2] = self.bob_m * 2.0 * w * math.cos(2.0 * ph)
        return off, vel
