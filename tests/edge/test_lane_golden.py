"""The lane pipeline computes what it computed when the fixture was recorded (speed-ups must not change it).

The fixtures (:data:`tests.edge.lane_golden.FIXTURES`: 200 frames of ``highway4-misaimed``, seed 31, with
track-aided pairings, the yaw self-calibrating and lane statistics; 300 frames of ``side-by-side``, seed 31,
with resolved side-by-side pairs; 240 frames of ``wrong-way``, seed 6, with its wrong-way event) hold the
detections, tracks, lane statistics and events of the pipeline as recorded by ``tests/edge/lane_golden.py``.
Ids, counts, lanes and flags must match exactly; floats within float32 round-off (positions 1e-4 m).
They are kept per machine kind (BLAS kernel and numpy SIMD targets, ``data/golden/<machine>/``; see
:mod:`tests.edge.lane_golden`): a machine without its own checks ``openblas-haswell_x86_v3``'s, held to that
kind's instruction set in a subprocess, where its CPU can (AVX2 and FMA); elsewhere the comparison is skipped,
saying so.
A deliberate change of what the lane pipeline computes re-records them:
``PYTHONPATH=. python -m tests.edge.lane_golden record-all``.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.edge import lane_golden

REPO = Path(__file__).resolve().parents[2]


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


def _stand_in_kind() -> str | None:
    """The machine kind this CPU reports when held to :data:`lane_golden.STAND_IN_ENV` (None if it has no fixtures
    of that kind or the CPU lacks AVX2/FMA)."""
    import numpy._core._multiarray_umath as um

    feats = um.__cpu_features__
    if not (feats.get("AVX2") and feats.get("FMA3")) or not lane_golden.fixture_path(
            next(iter(lane_golden.FIXTURES)), lane_golden.STAND_IN_KIND).is_file():
        return None
    out = subprocess.run([sys.executable, "-m", "tests.edge.lane_golden", "machine"], capture_output=True, text=True,
                         env={**os.environ, **lane_golden.STAND_IN_ENV}, cwd=REPO, timeout=120)
    return out.stdout.strip() or None


@pytest.mark.parametrize("stem", list(lane_golden.FIXTURES))
def test_lane_pipeline_reproduces_recorded_outputs(stem):
    if lane_golden.fixture_path(stem).is_file():
        errs = lane_golden.check(_here(stem))
        assert not errs, "lane pipeline outputs changed:\n" + "\n".join(errs)
        return
    # no fixture of this machine's own kind: a newer x86-64 CPU checks the older kind's, held to its instruction set
    if _stand_in_kind() != lane_golden.STAND_IN_KIND:
        _here(stem)  # skips, saying why and how to record
    path = lane_golden.fixture_path(stem, lane_golden.STAND_IN_KIND)
    out = subprocess.run([sys.executable, "-m", "tests.edge.lane_golden", "check", str(path)], capture_output=True,
                         text=True, env={**os.environ, **lane_golden.STAND_IN_ENV}, cwd=REPO, timeout=280)
    assert out.returncode == 0, f"lane pipeline outputs changed ({lane_golden.STAND_IN_KIND} stand-in):\n{out.stdout}{out.stderr}"


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


def test_a_machine_without_its_own_fixtures_checks_the_stand_in_kind(monkeypatch):
    """The route a newer CPU takes (an AVX-512 machine): the stand-in subprocess reports the recorded kind and its
    check passes; here the machine's own kind is hidden so that the route runs on any machine that can take it."""
    monkeypatch.setattr(lane_golden, "machine", lambda: "openblas-newer_x86_v4")
    kind = _stand_in_kind()
    if kind is None:
        pytest.skip("this CPU has no AVX2/FMA: it cannot stand in for openblas-haswell_x86_v3")
    assert kind == lane_golden.STAND_IN_KIND
    test_lane_pipeline_reproduces_recorded_outputs("lane_golden_wrong_way_s6")
