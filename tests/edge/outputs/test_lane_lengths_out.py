"""The lane registers publish the traffic layer's measured mean length, and n/a when none was measured."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from edge.outputs import registers as R
from edge.outputs.state import OutputState
from tests.edge.outputs.helpers import health, make_lane_stats, make_result

T0 = 1_000_000_000


def test_mean_length_register_reads_the_measured_mean_or_na():
    """It read n/a always (the old builder wrote None whatever the interval held)."""
    rng = np.random.default_rng(3)
    lanes = make_lane_stats(rng, 2, seq=4)
    lanes = (dataclasses.replace(lanes[0], mean_length_m=6.37), dataclasses.replace(lanes[1], mean_length_m=float("nan")))
    img = R.ImageBuilder(2, serial_number=1, wall_clock=lambda: 1.7e9, temperature=lambda: None).build(
        OutputState(2).update(make_result(1, T0, (), (False, False), lanes), health(T0, T0, frames=1)))
    got = [R.decode_block(R.LANE, img[R.LANE.base + k * R.LANE.stride: R.LANE.base + k * R.LANE.stride + R.LANE.size])
           ["mean_length"] for k in range(2)]
    assert got[0] == pytest.approx(6.4, abs=0.051) and got[1] is None
