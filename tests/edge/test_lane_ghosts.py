"""Ghosts beside vehicles from the side-by-side resolver (edge.lane.resolve) and the checks that refuse them: a
split is kept only when its two directions lie in adjacent lanes about the boundary between them.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from edge.pipelines.lane import LaneConfig, LanePipeline
from edge.traffic import TrafficConfig
from hw_sim import SIMO_BOARD

FE = SIMO_BOARD.frontend


def _pipe(**kw) -> LanePipeline:
    return LanePipeline(FE, dataclasses.replace(LaneConfig(), **kw), None, TrafficConfig())


def _az(x_m: float, range_m: float, cfg: LaneConfig = LaneConfig()) -> float:
    return math.asin(x_m / range_m)


def _straddles(pipe, r, ang):
    from edge.lane.angles import SplitStraddlesLanes

    (rule,) = [f for f in pipe.resolve.split_filters if isinstance(f, SplitStraddlesLanes)]
    return rule.straddles(r, ang, pipe.feedback())


def test_a_split_is_kept_only_about_the_boundary_of_two_adjacent_lanes():
    pipe = _pipe()
    assert pipe.traffic is not None and len(pipe.traffic.lanes) == 4  # centres -5.25, -1.75, 1.75, 5.25 m
    r = np.array([40.0] * 5, np.float32)
    #        lanes 1|2         lanes 2|3        lanes 0|1          lanes 0|2 (not adjacent)  both in lane 2
    pairs = [(-1.75, 1.75), (1.75, 5.25), (-5.25, -1.75), (-5.25, 1.75), (1.2, 2.4)]
    ang = np.arcsin(np.array(pairs) / 40.0).astype(np.float32)
    assert _straddles(pipe, r, ang).tolist() == [True, True, True, False, False]
    # lanes 1|2 both times; the midpoint must lie within resolve_boundary_fraction (0.25) of the lane spacing
    # (0.875 m) of their boundary: 1.15 m off it, refused; 0.75 m, kept
    off = np.arcsin(np.array([(-0.2, 2.5), (-0.5, 2.0)]) / 40.0).astype(np.float32)
    assert _straddles(pipe, r[:2], off).tolist() == [False, True]


# --- the resolver's memory follows the direction of its vehicle -----------------------------------------------

def _sweep(follow: bool, seed: int, lateral_m=(1.75,), offsets_m=(-0.9, -0.63, 0.0, 0.63, 0.9), r0_m=10.0,
           dr_m=1.0, n_frames=40, snr_db=25.0) -> list[bool]:
    """A receding vehicle (or two side by side) at fixed lateral positions, range growing by ``dr_m`` per frame:
    its direction cosine x / R sweeps. Scatterers at ``lateral + offsets`` (a car's rear face and sides) with
    new random phases every frame, coherent in the four looks of a frame."""
    from edge.dsp.angle import steering_matrix
    from edge.lane.resolve import CellResolver, ResolverConfig

    lam = FE.waveform.wavelength_m
    grid = np.arange(-math.radians(19.0), math.radians(19.0) + 1e-9, math.radians(0.25)).astype(np.float32)
    res = CellResolver(ResolverConfig(follow_direction=follow), steering_matrix(4, FE.rx_spacing_m, lam, grid), grid,
                       FE.waveform.frame_period_s, FE.rx_spacing_m / lam)
    rng = np.random.default_rng(seed)
    xs = np.add.outer(np.asarray(lateral_m), np.asarray(offsets_m)).ravel()
    out = []
    for k in range(n_frames):
        r = r0_m + dr_m * k
        a = steering_matrix(4, FE.rx_spacing_m, lam, np.arcsin(xs / r)) * 2.0
        x = (np.exp(2j * np.pi * rng.random(xs.size))[:, None] * a).sum(axis=0)
        looks = x[None, :] * np.exp(2j * np.pi * rng.random(4))[:, None]
        looks = looks + 10 ** (-snr_db / 20) * math.sqrt(xs.size) * (
            rng.standard_normal((4, 4)) + 1j * rng.standard_normal((4, 4))) / math.sqrt(2)
        az = np.array([math.asin(float(np.mean(lateral_m)) / r)], np.float32)
        split, _ = res.step(np.array([r]), np.array([30.0]), looks[None].astype(np.complex64), az)
        out.append(bool(split[0]))
    return out


def test_a_receding_car_near_the_radar_is_not_split_into_itself_and_its_earlier_direction():
    """Leaving the overpass at 30 m/s, a car in lane 2 sweeps from 10 deg at 10 m to 2.4 deg at 50 m. A memory
    that does not follow the direction held the earlier one as a second source (splits in several of the seeds);
    steered along, the car stays one source."""
    still = [sum(_sweep(False, s)) for s in range(10)]
    follow = [sum(_sweep(True, s)) for s in range(10)]
    assert sum(1 for n in still if n) >= 3
    assert follow == [0] * 10


def test_two_cars_side_by_side_receding_are_still_split_with_the_memory_following():
    for s in range(3):
        split = _sweep(True, s, lateral_m=(1.75, 5.25), offsets_m=(0.0,), r0_m=40.0, n_frames=30)
        assert sum(split[10:]) >= 15


# --- a look shared with another vehicle is not a second source ------------------------------------------------

def _split_beside_car_120(skip_shared: bool, static_factor: float | None = None) -> tuple[int, int]:
    """highway4-traffic seed 7012, frames 14700-14910 (frames are simulated independently: a run can start
    anywhere): car 120 approaches in lane 0 (x -5.25 m) from 80 to 43 m. Car 266 (lane 1, 10 m/s faster, 12-16 m
    nearer) shares the slow down-chirp's bin with it from frame 14876 on, and car 599 (lane 3, receding) its fast
    down-chirp's around 14888. Returns (split detections beside car 120, frames with a confirmed track in lane 1
    at its range and speed)."""
    from edge.config import load_config
    from edge.evaluation.lane import _installer_config
    from edge.pipeline import StageTimer
    from hal.frame import RawFrame
    from hw_sim.scenario import load_scenario
    from hw_sim.simulator import FrameSimulator

    # figures measured on the v1 instrument; the corpus reports the physical defaults
    sc = load_scenario("highway4-traffic", {"physics": {"preset": "v1"}})
    over = {"pipeline.lane.angle_skip_shared_looks": skip_shared}
    if static_factor is not None:
        over["pipeline.lane.clutter_map_static_factor"] = static_factor
    config = load_config(env={}, overrides=over)
    sim = FrameSimulator(SIMO_BOARD, sc.build_scene(7012), 7012)
    pipe = LanePipeline(FE, *_installer_config(config, sc))
    timer = StageTimer(window=8)
    splits = phantom = 0
    for n in range(14700, 14910):
        f = sim.frame(n)
        out = pipe.process(RawFrame(n, int(round(f.t_s * 1e9)), f.i, f.q, FE, f.truth), timer)
        d = out.detections
        pair = d.extra["resolved_pair"]
        splits += int(np.count_nonzero((pair >= 0) & (d.x_m < 0) & (d.y_m > 30) & (d.y_m < 80)))
        phantom += any(t.confirmed and -3.5 < t.x_m < 0.0 and 30.0 < t.y_m < 80.0 and abs(t.vy_mps + 18.8) < 1.5
                       for t in out.tracks)  # (car 266 in lane 1 is 10 m/s faster)
    return splits, phantom


@pytest.mark.slow
def test_a_vehicle_in_one_segment_of_another_does_not_split_it_into_a_phantom():
    """With the shared looks left out (``angle_skip_shared_looks``) nothing beside car 120 is split and no phantom
    is confirmed in lane 1, with the clutter map this was measured with (every bin learning,
    ``clutter_map_static_factor = 0``) and with the default one.

    With the OS-CFAR noise estimate capped (before decision 0049), and without the shared looks left out, the
    resolver's memory of car 120 held car 266 (and car 599) as a second source at -2.4 m and split it from frame
    14893 on (4+ split detections, a phantom in 5+ frames, counted in lane 1: the +2 of lane 1 at stop 21).
    Uncapped, this scene splits nothing either way; the rule's holdout effect is in docs/lane-rules.md."""
    assert _split_beside_car_120(True, static_factor=0.0) == (0, 0)
    assert _split_beside_car_120(True) == (0, 0)
