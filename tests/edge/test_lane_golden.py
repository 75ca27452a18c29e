"""The lane pipeline computes what it computed when the fixture was recorded (speed-ups must not change it).

The fixtures (``data/lane_golden_misaimed_s31.npz``: 200 frames of ``highway4-misaimed``, seed 31, with
track-aided pairings, the yaw self-calibrating and lane statistics; ``data/lane_golden_side_by_side_s31.npz``:
300 frames of ``side-by-side``, seed 31, with resolved side-by-side pairs; ``data/lane_golden_wrong_way_s6.npz``:
240 frames of ``wrong-way``, seed 6, with its wrong-way event) hold the detections, tracks,
lane statistics and events of the pipeline as recorded by ``tests/edge/lane_golden.py``.
Ids, counts, lanes and flags must match exactly; floats within float32 round-off (positions 1e-4 m).
A deliberate change of what the lane pipeline computes re-records it:
``PYTHONPATH=. python -m tests.edge.lane_golden record tests/edge/data/lane_golden_misaimed_s31.npz
--scenario highway4-misaimed --seed 31 --frames 200 --no-spectra`` and
``PYTHONPATH=. python -m tests.edge.lane_golden record tests/edge/data/lane_golden_side_by_side_s31.npz
--scenario side-by-side --seed 31 --frames 300 --no-spectra`` and
``PYTHONPATH=. python -m tests.edge.lane_golden record tests/edge/data/lane_golden_wrong_way_s6.npz
--scenario wrong-way --seed 6 --frames 240 --no-spectra``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.edge import lane_golden

FIXTURE = Path(__file__).parent / "data" / "lane_golden_misaimed_s31.npz"
SIDE_BY_SIDE = Path(__file__).parent / "data" / "lane_golden_side_by_side_s31.npz"
WRONG_WAY = Path(__file__).parent / "data" / "lane_golden_wrong_way_s6.npz"


@pytest.mark.parametrize("fixture", [FIXTURE, SIDE_BY_SIDE, WRONG_WAY], ids=lambda p: p.stem)
def test_lane_pipeline_reproduces_recorded_outputs(fixture):
    errs = lane_golden.check(fixture)
    assert not errs, "lane pipeline outputs changed:\n" + "\n".join(errs)


def test_the_fixtures_cover_resolved_pairs_and_events():
    sbs, _ = lane_golden.load(SIDE_BY_SIDE)
    ids, rows = np.unique(sbs["trk_track_id"], return_counts=True)
    # two tracks carry the two cars (since the SNR measurement noise a third lives for 3 frames as they pass
    # under the bridge, 146-148)
    assert (sbs["det_resolved_pair"] >= 0).sum() > 50 and (rows > 50).sum() == 2 and len(ids) <= 3
    ww, _ = lane_golden.load(WRONG_WAY)
    assert ww["ev_frame"].size == 1 and str(ww["ev_kind"][0]) == "wrong_way"


def test_compare_detects_a_changed_id_and_a_moved_track():
    ref, _ = lane_golden.load(FIXTURE)
    assert ref["trk_track_id"].size > 100
    new = {k: v.copy() for k, v in ref.items()}
    new["trk_track_id"][5] += 1
    new["trk_x_m"][7] += 2e-4
    errs = lane_golden.compare(ref, new)
    assert len(errs) == 2 and errs[0].startswith("trk_track_id") and errs[1].startswith("trk_x_m")
    new = {k: v.copy() for k, v in ref.items()}
    new["trk_x_m"][7] += 5e-5  # float32 round-off at 300 m is 3e-5 m
    assert lane_golden.compare(ref, new) == []
    assert np.isfinite(ref["det_x_m"]).all()
