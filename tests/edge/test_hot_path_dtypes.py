"""No float64 in the frame hot path: every array a pipeline produces per frame is single precision."""

import numpy as np
import pytest

from edge.config import load_config
from edge.pipeline import PIPELINES, StageTimer, build_pipeline
from hal import open_radar


def _arrays(obj, prefix=""):
    if isinstance(obj, np.ndarray):
        yield prefix, obj
    elif isinstance(obj, dict):
        for k, v in obj.items():
            yield from _arrays(v, f"{prefix}.{k}")
    elif hasattr(obj, "__dataclass_fields__"):
        for k in obj.__dataclass_fields__:
            yield from _arrays(getattr(obj, k), f"{prefix}.{k}")


@pytest.mark.parametrize("profile", sorted(PIPELINES))
@pytest.mark.parametrize("board", ["simo", "d2g"])
def test_pipeline_outputs_are_single_precision(profile, board, monkeypatch):
    from edge.pipeline import BOARD_PROFILE

    if profile != "minimal" and BOARD_PROFILE[board] != profile:
        pytest.skip(f"{profile} does not run on {board}")
    cfg = load_config(env={})
    with open_radar(f"sim://{board}?realtime=0&frames=3") as src:
        pipe = build_pipeline(profile, src.frontend, cfg)
        results = [pipe.process(f, StageTimer()) for f in src]
    for r in results:
        for name, a in _arrays(r.detections, "detections"):
            assert a.dtype not in (np.float64, np.complex128), f"{profile}: {name} is {a.dtype}"
        for name, a in _arrays(r.intermediates, "intermediates"):
            assert a.dtype not in (np.float64, np.complex128), f"{profile}: {name} is {a.dtype}"


def test_range_fft_stays_complex64():
    from edge.dsp.range_fft import make_window, range_fft

    x = (np.ones((4, 4, 1024)) + 1j).astype(np.complex64)
    y = range_fft(x, make_window("hann", 1024))
    assert y.dtype == np.complex64
    assert make_window("kaiser", 64).dtype == np.float32
