"""One conformance suite, run unchanged on every backend (python-can back2back style).

Each backend is described by a factory returning a source URL (and cleaning up after itself). The
real Distance2Go joins when ``RADAR_EDGE_HW_URL`` names it (opt-in: the Pi bench runs what CI runs).
"""

from __future__ import annotations

import contextlib
import os

import numpy as np
import pytest

from hal import FrameFormatError, RawFrame, SourceNotOpenError, SourceTimeoutError, open_radar
from hal.base import RadarSource, RawRead
from hal.clock import FakeClock
from hal.recording import RecordingWriter


@contextlib.contextmanager
def _sim(board):
    yield f"sim://{board}?seed=2&realtime=0"


@contextlib.contextmanager
def _replay(tmp_path_factory):
    path = tmp_path_factory.mktemp("rec") / "simo.npz"
    with open_radar("sim://simo?scenario=single-car&seed=4&realtime=0&frames=12") as src:
        w = RecordingWriter(src.frontend, meta={"scenario": "single-car"})
        for f in src:
            w.add(f)
    w.save(path)
    yield f"replay://{path}?speed=0"


def _backends():
    out = [pytest.param("simo", id="sim-simo"), pytest.param("d2g", id="sim-d2g"), pytest.param("replay", id="replay")]
    out.append(pytest.param("d2g-emulator", id="d2g-emulator"))
    if os.environ.get("RADAR_EDGE_HW_URL"):
        out.append(pytest.param("hardware", id="hardware", marks=pytest.mark.hardware))
    return out


@pytest.fixture(params=_backends())
def source_url(request, tmp_path_factory):
    kind = request.param
    if kind in ("simo", "d2g"):
        cm = _sim(kind)
    elif kind == "replay":
        cm = _replay(tmp_path_factory)
    elif kind == "d2g-emulator":
        try:
            from tests.hal.d2g_emulator import emulated_d2g_url
        except ImportError:
            pytest.skip("the Distance2Go emulator is not available in this build")
        cm = emulated_d2g_url(scenario="tavanti-test1", seed=2)
    else:
        cm = contextlib.nullcontext(os.environ["RADAR_EDGE_HW_URL"])
    with cm as url:
        yield url


def test_not_opened_in_constructor_and_read_needs_open(source_url):
    src = open_radar(source_url)
    assert not src.is_open
    with pytest.raises(SourceNotOpenError):
        src.read_frame(timeout=0.5)


def test_frames_match_the_frontend(source_url):
    with open_radar(source_url) as src:
        fe = src.frontend
        frames = [src.read_frame(timeout=5.0) for _ in range(3)]
    for f in frames:
        assert isinstance(f, RawFrame)
        assert f.i.dtype == np.int16 and f.q.dtype == np.int16
        assert f.i.shape == fe.frame_shape == f.q.shape
        assert fe.adc_min <= int(f.i.min()) and int(f.i.max()) <= fe.adc_max
        assert f.frontend == fe
        z = f.iq()
        assert z.dtype == np.complex64 and z.shape == fe.frame_shape
        assert np.array_equal(z.real, f.i.astype(np.float32))


def test_monotonic_timestamps_and_sequence(source_url):
    with open_radar(source_url) as src:
        frames = [src.read_frame(timeout=5.0) for _ in range(4)]
    t = [f.t_ns for f in frames]
    s = [f.seq for f in frames]
    assert all(b >= a for a, b in zip(t, t[1:]))
    assert all(b > a for a, b in zip(s, s[1:]))
    assert src.stats.frames == 4
    assert src.stats.dropped_frames == sum(b - a - 1 for a, b in zip(s, s[1:]))


def test_context_manager_closes_and_reopens(source_url):
    src = open_radar(source_url)
    with src:
        src.read_frame(timeout=5.0)
    assert not src.is_open
    with src:
        assert src.read_frame(timeout=5.0).i.shape == src.frontend.frame_shape


def test_signal_is_not_constant(source_url):
    with open_radar(source_url) as src:
        f = src.read_frame(timeout=5.0)
    assert f.i.std() > 0.5 and f.q.std() > 0.5  # noise at least: a dead ADC would fail


# --- the base class's generic behaviour, on a fake backend -----------------------------------


class _Fake(RadarSource):
    scheme = "fake"

    def __init__(self, reads):
        super().__init__(clock_ns=FakeClock().now_ns)
        self._reads = list(reads)
        from hal.waveform import d2g_frontend

        self._fe = d2g_frontend()

    @property
    def frontend(self):
        return self._fe

    def _open(self):
        pass

    def _read_raw(self, timeout_s):
        return self._reads.pop(0) if self._reads else None

    def _close(self):
        pass


def _raw(seq, shape=(1, 21, 64), dtype=np.int16, value=0):
    a = np.full(shape, value, dtype=dtype)
    return RawRead(seq=seq, i=a, q=a.copy())


def test_base_counts_gaps_as_dropped_frames():
    with _Fake([_raw(5), _raw(6), _raw(9), _raw(10)]) as src:
        seqs = [src.read_frame().seq for _ in range(4)]
        with pytest.raises(SourceTimeoutError):
            src.read_frame(timeout=0.01)
    assert seqs == [5, 6, 9, 10]
    assert src.stats.dropped_frames == 2
    assert src.stats.timeouts == 1


@pytest.mark.parametrize(
    "raw, match",
    [
        (_raw(1, shape=(1, 20, 64)), "shape"),
        (_raw(1, dtype=np.int32), "int16"),
        (_raw(1, value=3000), "ADC range"),
    ],
)
def test_base_checks_shape_dtype_range(raw, match):
    with _Fake([raw]) as src:
        with pytest.raises(FrameFormatError, match=match):
            src.read_frame()
