"""The kernels' new arrays (``edge/native/_alloc.pxi``: PyArray_EMPTY / PyArray_ZEROS instead of np.empty /
np.zeros): on a lane run, every array the pipeline publishes and every track-table column has the dtype and shape of
the numpy reference's, and the kernels' own outputs are C-contiguous, aligned, writeable arrays that own their data."""

from __future__ import annotations

import numpy as np
import pytest

from edge.bench import synth_frames
from edge.config import load_config
from edge.native.check import kernels
from edge.npc import count_nonzero
from edge.pipeline import StageTimer, build_pipeline
from edge.track.table import TrackTable
from tests.native.conftest import require_kernel


def _arrays(o, path="r", out=None):
    """Every ndarray reachable from a FrameResult (dataclasses, tuples, lists, dicts) by its path."""
    import dataclasses

    out = {} if out is None else out
    if isinstance(o, np.ndarray):
        out[path] = o
    elif dataclasses.is_dataclass(o) and not isinstance(o, type):
        for f in dataclasses.fields(o):
            _arrays(getattr(o, f.name), f"{path}.{f.name}", out)
    elif isinstance(o, (list, tuple)):
        for k, v in enumerate(o):
            _arrays(v, f"{path}[{k}]", out)
    elif isinstance(o, dict):
        for k, v in o.items():
            _arrays(v, f"{path}[{k!r}]", out)
    return out


def _run(frames, on):
    with kernels(on):
        pipe = build_pipeline("lane", frames[0].frontend, load_config(env={}))
    res = [pipe.process(f, StageTimer(16)) for f in frames]
    return pipe, res


@pytest.fixture(scope="module")
def runs():
    require_kernel("_track")
    frames = synth_frames("simo", "stop-and-go", 1, 70)
    return _run(frames, True), _run(frames, False)


def test_published_arrays_have_the_reference_dtypes_and_shapes(runs):
    (_, fast), (_, ref) = runs
    n = 0
    for a, b in zip(fast, ref):
        fa, fb = _arrays(a), _arrays(b)
        assert fa.keys() == fb.keys()
        for k in fa:
            assert (fa[k].dtype, fa[k].shape) == (fb[k].dtype, fb[k].shape), k
            n += 1
    assert n > 1000


def test_track_table_columns_have_the_reference_dtypes(runs):
    (pf, _), (pr, _) = runs
    empty = TrackTable()
    for c in TrackTable._COLUMNS:
        a, b = getattr(pf.tracker.tracks, c), getattr(pr.tracker.tracks, c)
        assert a.dtype == b.dtype == getattr(empty, c).dtype, c
        assert a.shape[1:] == b.shape[1:] == getattr(empty, c).shape[1:], c
        assert a.flags.c_contiguous and a.flags.aligned and a.flags.writeable, c


def test_kernel_outputs_are_fresh_c_arrays():
    """A few of the kernels' outputs: new, C-contiguous, aligned, writeable arrays owning their data, of the
    reference's dtypes."""
    k = require_kernel("_track")
    rng = np.random.default_rng(3)
    t, m = 5, 7
    gated = rng.random((t, m)) < 0.3
    age, hits = np.arange(t, dtype=np.int32), np.ones(t, np.int32)
    misses, history = np.zeros(t, np.int32), np.ones(t, np.uint32)
    hit, mi, hi = k.count_hits(gated, age, hits, misses, history)
    for a, dt in ((hit, bool), (mi, np.int32), (hi, np.uint32)):
        assert a.dtype == dt and a.shape == (t,)
        assert a.flags.c_contiguous and a.flags.aligned and a.flags.writeable and a.flags.owndata
    zp, snr, pair, unr = k.measurements(*(rng.random(m).astype(np.float32) + 1 for _ in range(5)), True, None, None)
    assert zp.dtype == np.float64 and zp.shape == (m, 3) and zp.flags.c_contiguous and zp.flags.owndata
    assert snr.dtype == np.float64 and snr.shape == (m,) and snr.flags.owndata


@pytest.mark.parametrize("a", [np.zeros(0, bool), np.array([True, False, True]), np.array([[0, 2], [3, 0]]),
                               np.array([0.0, np.nan, -0.0, 1e-300]), np.zeros((3, 0)), np.arange(7)[::2]])
def test_count_nonzero_is_numpys(a):
    assert count_nonzero(a) == np.count_nonzero(a) and type(count_nonzero(a)) is type(np.count_nonzero(a))
