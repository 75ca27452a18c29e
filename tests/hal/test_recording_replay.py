import numpy as np
import pytest

from hal import RecordingError, SourceClosedError, SourceTimeoutError, open_radar
from hal.clock import FakeClock
from hal.recording import Recording, RecordingWriter
from hal.replay import Pacer


@pytest.fixture()
def rec_path(tmp_path):
    with open_radar("sim://d2g?scenario=tavanti-test1&seed=5&realtime=0&frames=6") as src:
        frames = list(src)
        w = RecordingWriter(src.frontend, meta={"scenario": "tavanti-test1", "seed": 5})
        for f in frames:
            w.add(f)
    return w.save(tmp_path / "d2g.npz"), frames


def test_round_trip_preserves_samples_timestamps_and_truth(rec_path):
    path, frames = rec_path
    rec = Recording(path)
    assert len(rec) == 6 and rec.meta["seed"] == 5 and rec.has_truth
    with open_radar(f"replay://{path}?speed=0") as src:
        back = list(src)
    assert [f.seq for f in back] == [f.seq for f in frames]
    for a, b in zip(frames, back):
        assert np.array_equal(a.i, b.i) and np.array_equal(a.q, b.q)
        assert b.meta["recorded_t_ns"] == a.t_ns
        assert a.truth.cls == b.truth.cls
        np.testing.assert_array_equal(a.truth.id, b.truth.id)
        np.testing.assert_allclose(a.truth.position_m, b.truth.position_m)
        np.testing.assert_allclose(a.truth.radial_speed_mps, b.truth.radial_speed_mps)


def test_replay_ends_with_closed_error_and_loops_on_request(rec_path):
    path, _ = rec_path
    with open_radar(f"replay://{path}?speed=0") as src:
        for _ in range(6):
            src.read_frame()
        with pytest.raises(SourceClosedError):
            src.read_frame()
    with open_radar(f"replay://{path}?speed=0&loop=1") as src:
        seqs = [src.read_frame().seq for _ in range(14)]
    assert seqs == list(range(14))
    assert src.stats.dropped_frames == 0


def test_paced_replay_follows_the_fake_clock(rec_path):
    path, _ = rec_path
    clk = FakeClock()
    with open_radar(f"replay://{path}?speed=2", clock=clk) as src:
        t0 = clk.now_ns()
        for _ in range(4):
            src.read_frame(timeout=1.0)
    # frames released 100 ms apart (200 ms period at speed 2): no drift
    assert clk.sleeps == [t0 + k * 100_000_000 for k in range(4)]


def test_pacer_times_out_without_losing_the_frame():
    clk = FakeClock()
    p = Pacer(clk, speed=1.0, period_ns=200_000_000)
    assert p.wait_for_next(timeout_s=1.0)  # first frame at once
    assert not p.wait_for_next(timeout_s=0.05)  # next one is 200 ms away
    assert p.wait_for_next(timeout_s=1.0)
    assert clk.now_ns() - 1_000_000_000 == 200_000_000


def test_corrupt_missing_and_future_files_are_refused(tmp_path, rec_path):
    with pytest.raises(RecordingError, match="not found"):
        Recording(tmp_path / "nope.npz")
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"PK\x03\x04 not really a zip")
    with pytest.raises(RecordingError, match="not a readable"):
        Recording(bad)
    path, _ = rec_path
    with np.load(path) as z:
        data = {k: z[k] for k in z.files}
    data["version"] = np.array(99)
    fut = tmp_path / "future.npz"
    np.savez(fut, **data)
    with pytest.raises(RecordingError, match="version 99"):
        Recording(fut)
    with pytest.raises(RecordingError):
        open_radar(f"replay://{fut}").open()


def test_realtime_sim_skips_frames_for_a_late_reader():
    clk = FakeClock()
    with open_radar("sim://d2g?seed=1", clock=clk) as src:
        a = src.read_frame(timeout=1.0)
        clk.advance_ns(650_000_000)  # the host was busy for 3+ frame periods
        b = src.read_frame(timeout=1.0)
        with pytest.raises(SourceTimeoutError):
            src.read_frame(timeout=0.01)
    assert a.seq == 0 and b.seq == 3
    assert src.stats.dropped_frames == 2
