"""The lane stages take what they know of earlier frames from one declared record (edge.lane.records.Feedback), and
the road-geometry filters are objects switched by their config keys."""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest

from edge.lane.angles import SplitStraddlesLanes
from edge.lane.detections import NearFaces, UnaliasByLane
from edge.lane.records import Feedback
from edge.pipeline import StageTimer
from edge.pipelines.lane import LaneConfig, LanePipeline
from hw_sim.boards import SIMO_BOARD
from tests.edge import lane_golden as g

FE = SIMO_BOARD.frontend


class _Trap:
    """Stands in for the tracker and the traffic layer: any use fails the test."""

    def __getattr__(self, name):
        raise AssertionError(f"detection read .{name} of the tracker or the traffic layer")


def test_detection_reads_earlier_frames_only_through_the_feedback_record():
    """A pipeline runs 30 frames of highway4-traffic (v1: confirmed tracks, configured lanes) and is copied; on the
    next frame one detects normally and the other from its feedback record with its tracker and traffic layer
    replaced by traps: the same detections, and the feedback held tracks, confirmed ones and lanes (so every rule
    that uses it was reachable)."""
    a, frames = g.build("highway4-traffic", 5, 5.0, patch=g.V1_PATCH)
    timer = StageTimer(16)
    it = frames(31)
    for _ in range(30):
        a.process(next(it), timer)
    b = copy.deepcopy(a)
    f = next(it)
    fb = b.feedback()
    assert fb.n_tracks > 0 and fb.confirmed.any() and fb.lanes and fb.t_ns is not None
    det_a, inter_a = a.detect(f, timer)
    b.tracker, b.traffic = _Trap(), _Trap()
    det_b, inter_b = b.detect(f, timer, fb)
    assert len(det_a) > 0
    for name in ("range_m", "radial_speed_mps", "az_rad", "snr_db", "x_m", "y_m"):
        np.testing.assert_array_equal(getattr(det_a, name), getattr(det_b, name))
    assert sorted(det_a.extra) == sorted(det_b.extra)
    for k in det_a.extra:
        np.testing.assert_array_equal(det_a.extra[k], det_b.extra[k])
    assert inter_a["n_aided_pairs"] == inter_b["n_aided_pairs"]


def test_no_tracker_gives_an_empty_feedback():
    p = LanePipeline(FE, LaneConfig(tracking=False))
    fb = p.feedback()
    assert fb.n_tracks == 0 and fb.lanes == () and fb.t_ns is None
    assert Feedback.none().track_state.shape == (0, 4)


def _kinds(p: LanePipeline) -> set[type]:
    fs = list(p.detections.direction_filters) + list(p.detections.filters)
    if p.resolve is not None:
        fs += list(p.resolve.split_filters)
    return {type(f) for f in fs}


@pytest.mark.parametrize("override,gone", [
    ({}, set()),
    ({"unalias_by_lane": False}, {UnaliasByLane}),
    ({"cluster_length_m": 0.0}, {NearFaces}),
    ({"resolve_pairs": False}, {SplitStraddlesLanes}),
])
def test_each_road_geometry_filter_is_switched_by_its_config_key(override, gone):
    every = {UnaliasByLane, NearFaces, SplitStraddlesLanes}
    p = LanePipeline(FE, dataclasses.replace(LaneConfig(), **override), None, None)
    assert _kinds(p) == every - gone
