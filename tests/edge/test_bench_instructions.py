"""bench --instructions: callgrind counts of a replay child, after warm-up."""

import shutil

import pytest

from edge.bench import board_of, synth_frames
from edge.bench import instructions as ins


def test_missing_valgrind_is_one_line(monkeypatch):
    monkeypatch.setattr(shutil, "which", lambda name: None)
    msg = ins.valgrind_missing()
    assert msg is not None and "\n" not in msg and "apt-get install valgrind" in msg
    with pytest.raises(RuntimeError, match="valgrind"):
        ins.measure([object()] * 3, "lane", warmup=1, frames=1)


def test_too_few_frames_refused():
    with pytest.raises(ValueError, match="need 5 frames"):
        ins.measure([object()] * 4, "lane", warmup=1, frames=2)


@pytest.mark.slow
def test_lane_counts_are_plausible():
    # CI installs valgrind (.ci/run): a missing valgrind fails here instead of skipping
    assert ins.valgrind_missing() is None, ins.valgrind_missing()
    frames = synth_frames(board_of("lane"), "highway4", 3, 2 + 2 * 3)
    rep = ins.measure(frames, "lane", warmup=2, frames=3)
    fft, pipe = rep["fft_bound_per_frame"], rep["pipeline_per_frame"]
    # one complex64 FFT of 4 channels x 4 segments: a few hundred thousand instructions, not millions
    assert 2e5 < fft < 3e6
    # the pipeline does the FFT and much more; the control region cancels the request path
    assert pipe > 3 * fft
    assert rep["ratio"] == pytest.approx(pipe / fft)
