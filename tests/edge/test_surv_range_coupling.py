"""The surveillance profile's published range is corrected for the range-Doppler coupling of the Distance2Go's
1.5 ms up-chirp: a radial speed v shifts the beat by 2 v / lambda, which reads as v f_c / S (0.18 s) of range."""

from __future__ import annotations

import numpy as np
import pytest

from edge.config import load_config
from edge.pipeline import StageTimer, build_pipeline
from edge.track.surveillance import SurveillanceTracker
from edge.types import RawFrame
from hal.waveform import SPEED_OF_LIGHT_MPS, d2g_frontend
from hw_sim.boards import D2G_BOARD
from hw_sim.scene import LinearTrajectory, RadarPose, Scene, Target
from hw_sim.simulator import FrameSimulator
from tests.edge.survscene import blob, points

FE = d2g_frontend()
SEG = FE.waveform.segments[0]
T = FE.waveform.frame_period_s


def test_the_coupling_constant_is_the_beat_shift_of_a_radial_speed():
    # 2 v / lambda of beat frequency over the slope, as range (c / 2 per second of delay): v f_c / S
    v = 10.0
    beat_hz = 2.0 * v * SEG.f_start_hz / SPEED_OF_LIGHT_MPS
    shift_m = beat_hz / SEG.slope_hz_per_s * SPEED_OF_LIGHT_MPS / 2.0
    assert SurveillanceTracker(FE, 2.0, classify=False)._coupling_s * v == pytest.approx(shift_m, rel=1e-12)
    assert shift_m == pytest.approx(1.80, abs=0.01)


@pytest.mark.parametrize("v_kmh", [35.0, -35.0])
def test_published_range_takes_the_coupling_out_of_the_cluster_range(v_kmh):
    # hand-made clusters at the range the map shows: true range + 0.18 s x v
    st = SurveillanceTracker(FE, 2.0, classify=False)
    k = SEG.f_start_hz / SEG.slope_hz_per_s
    r0 = 6.0 if v_kmh > 0 else 22.0
    errs = []
    for n in range(8):
        r_true = r0 + v_kmh / 3.6 * T * n
        step = st.update(int(n * T * 1e9), points(blob(r_true + k * v_kmh / 3.6, v_kmh, 100, 0)), seq=n)
        for ts in step.tracks:
            if np.isfinite(ts.radial_speed_mps):
                errs.append(ts.range_m - r_true)
    assert len(errs) >= 3
    assert np.max(np.abs(errs)) < 0.2  # uncorrected: 1.75 m


def _one_point_receding(v_mps: float) -> Scene:
    sc = Scene(pose=RadarPose(height_m=1.0), seed=3)
    sc.add_target(Target(1, "car", LinearTrajectory((0.0, 5.0, 1.0), (0.0, v_mps, 0.0)), np.zeros((1, 3)), [10.0]))
    return sc


def test_a_simulated_receding_point_is_published_at_its_range():
    # the simulator synthesises the beat of a moving scatterer, coupling included; the profile takes it out
    v = 9.0
    scene = _one_point_receding(v)
    sim = FrameSimulator(D2G_BOARD, scene, 5)
    pipe = build_pipeline("surveillance", FE, load_config(None))
    timer = StageTimer(window=16)
    errs = []
    for n in range(12):
        f = sim.frame(n)
        res = pipe.process(RawFrame(seq=n, t_ns=int(round(n * T * 1e9)), i=f.i, q=f.q, frontend=FE, truth=f.truth),
                           timer)
        r_true = 5.0 + v * n * T
        for ts in res.tracks:
            if np.isfinite(ts.radial_speed_mps) and r_true < 20.0:
                errs.append(ts.range_m - r_true)
    assert len(errs) >= 4
    # range bins are 0.75 m; the coupling alone is 1.6 m at 9 m/s. What is left (about 0.2 m) is the time from the
    # frame's start to the middle of its chirps, which the simulator's and the board's time stamps place differently
    assert abs(float(np.median(errs))) < 0.4, errs
