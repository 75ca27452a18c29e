"""Ghosts beside vehicles from the side-by-side resolver (edge.dsp.resolve) and the rules that refuse them.

A range-speed cell that lies behind a nearer detection of the same vehicle is that vehicle's body (its two
sides, or a side and its far face, in one range bin): the two-source fit of its rank-two covariance put one
direction 3-4 m beside the vehicle, in the next lane (highway4-traffic seed 31). And two vehicles in one cell
move the same way: a split across the median (lanes of opposite directions) is not two vehicles.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from edge.pipelines.lane import LaneConfig, LanePipeline
from edge.traffic import TrafficConfig
from hw_sim import SIMO_BOARD

FE = SIMO_BOARD.frontend


def _pipe(**kw) -> LanePipeline:
    return LanePipeline(FE, dataclasses.replace(LaneConfig(), **kw), None, TrafficConfig())


def _az(x_m: float, range_m: float, cfg: LaneConfig = LaneConfig()) -> float:
    return math.asin(x_m / range_m)


def test_split_cell_behind_the_near_face_of_its_vehicle_is_its_body():
    pipe = _pipe()
    # 0: a truck's near face at 50 m in lane 0; 1: a cell 12 m behind it at its speed (its far end);
    # 2: the same range at another speed (another vehicle); 3: the same range and speed two lanes over;
    # 4: a cell nearer than the near face (nothing nearer at its speed)
    rng = np.array([50.0, 62.0, 62.0, 62.0, 45.0], np.float32)
    vel = np.array([-23.0, -23.3, -27.0, -23.3, -23.0], np.float32)
    az = np.array([_az(-5.25, 50.0), _az(-4.6, 62.0), _az(-4.6, 62.0), _az(1.75, 62.0), _az(-5.25, 45.0)],
                  np.float32)
    split = np.array([False, True, True, True, True])
    body = pipe._split_is_body(rng, vel, az, split)
    assert body.tolist() == [False, True, False, False, False]
    # only split detections are judged
    assert not pipe._split_is_body(rng, vel, az, np.array([False, False, True, True, True])).any()


def test_a_body_cell_is_not_split_and_side_by_side_cells_still_are():
    """The rule in the pipeline: with ``resolve_skip_bodies`` the split of a body cell is undone (the
    resolver's own test is not involved: the decision is made on its output)."""
    on, off = _pipe(), _pipe(resolve_skip_bodies=False)
    rng = np.array([50.0, 62.0], np.float32)
    vel = np.array([-23.0, -23.3], np.float32)
    az = np.array([_az(-5.25, 50.0), _az(-4.6, 62.0)], np.float32)
    split = np.array([False, True])
    assert on.config.resolve_skip_bodies and not off.config.resolve_skip_bodies
    assert (split & ~on._split_is_body(rng, vel, az, split)).tolist() == [False, False]
    # two cars side by side at one range are the nearest detections of both: their cell is split
    rng2 = np.array([62.0], np.float32)
    vel2 = np.array([25.0], np.float32)
    az2 = np.array([_az(3.5, 62.0)], np.float32)
    assert not on._split_is_body(rng2, vel2, az2, np.array([True])).any()


def test_split_across_lanes_of_opposite_directions_is_refused():
    pipe = _pipe()
    assert pipe.traffic is not None and len(pipe.traffic.lanes) == 4  # toward, toward, away, away
    r = np.array([40.0, 40.0, 40.0], np.float32)
    ang = np.stack([np.arcsin(np.array([-1.75, 1.75, -5.25]) / 40.0),
                    np.arcsin(np.array([1.75, 5.25, -1.75]) / 40.0)], axis=1).astype(np.float32)
    receding = np.array([20.0, 20.0, 20.0], np.float32)
    approaching = -receding
    # lanes 1|2 straddle the median: never; lanes 2|3 (away) only for a receding cell; 0|1 (toward) only approaching
    assert pipe._split_straddles_lanes(r, receding, ang).tolist() == [False, True, False]
    assert pipe._split_straddles_lanes(r, approaching, ang).tolist() == [False, False, True]
    off = _pipe(resolve_same_direction=False)
    assert off._split_straddles_lanes(r, receding, ang).tolist() == [True, True, True]
