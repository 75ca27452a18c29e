"""The lane pipeline computes what it computed when the fixture was recorded (speed-ups must not change it).

The fixtures (:data:`tests.edge.lane_golden.FIXTURES`: 200 frames of ``highway4-misaimed``, seed 31, with
track-aided pairings, the yaw self-calibrating and lane statistics; 300 frames of ``side-by-side``, seed 31,
with resolved side-by-side pairs; 240 frames of ``wrong-way``, seed 6, with its wrong-way event) hold the
detections, tracks, lane statistics and events of the pipeline as recorded by ``tests/edge/lane_golden.py``.
Ids, counts, lanes and flags must match exactly; floats within float32 round-off (positions 1e-4 m).
They are kept per machine kind (BLAS kernel and numpy SIMD targets, ``data/golden/<machine>/``; see
:mod:`tests.edge.lane_golden`): on a machine without its own the comparison is skipped, saying so.
A deliberate change of what the lane pipeline computes re-records them:
``PYTHONPATH=. python -m tests.edge.lane_golden record-all``.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.edge import lane_golden


def _here(stem: str):
    path = lane_golden.fixture_path(stem)
    if not path.is_file():
        pytest.skip(f"no lane golden fixture for this machine's floating point ({lane_golden.machine()}; recorded: "
                    f"{', '.join(lane_golden.recorded_kinds()) or 'none'}): other BLAS kernels and SIMD paths round "
                    "differently and the runs diverge; record this machine's on the code before a change with "
                    "'PYTHONPATH=. python -m tests.edge.lane_golden record-all'")
    return path


def _any(stem: str):
    """This machine's fixture, else any recorded one (for tests of the fixtures' content, not of the pipeline)."""
    here = lane_golden.fixture_path(stem)
    if here.is_file():
        return here
    for kind in lane_golden.recorded_kinds():
        path = lane_golden.fixture_path(stem, kind)
        if path.is_file():
            return path
    pytest.fail(f"no recorded {stem}.npz under {lane_golden.DATA_DIR}")


@pytest.mark.parametrize("stem", list(lane_golden.FIXTURES))
def test_lane_pipeline_reproduces_recorded_outputs(stem):
    errs = lane_golden.check(_here(stem))
    assert not errs, "lane pipeline outputs changed:\n" + "\n".join(errs)


def test_fixtures_record_what_they_say():
    for stem, args in lane_golden.FIXTURES.items():
        _, meta = lane_golden.load(_any(stem))
        assert {k: meta[k] for k in args} == args and meta["spectra"] is False


def test_the_fixtures_cover_resolved_pairs_and_events():
    sbs, _ = lane_golden.load(_any("lane_golden_side_by_side_s31"))
    ids, rows = np.unique(sbs["trk_track_id"], return_counts=True)
    # two tracks carry the two cars (since the SNR measurement noise a third lives for 3 frames as they pass
    # under the bridge, 146-148)
    assert (sbs["det_resolved_pair"] >= 0).sum() > 50 and (rows > 50).sum() == 2 and len(ids) <= 3
    ww, _ = lane_golden.load(_any("lane_golden_wrong_way_s6"))
    assert ww["ev_frame"].size == 1 and str(ww["ev_kind"][0]) == "wrong_way"


def test_compare_detects_a_changed_id_and_a_moved_track():
    ref, _ = lane_golden.load(_any("lane_golden_misaimed_s31"))
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


def test_a_machine_without_fixtures_skips_and_says_how_to_record(monkeypatch):
    monkeypatch.setattr(lane_golden, "machine", lambda: "someblas-othercpu_x86_v4")
    with pytest.raises(pytest.skip.Exception, match="someblas-othercpu_x86_v4.*record-all"):
        _here("lane_golden_misaimed_s31")
    assert _any("lane_golden_misaimed_s31").is_file()  # the content tests still find a recorded one
