"""End to end: the lane pipeline with the detection kernels (edge/native/_peaks.pyx, ...) and with their numpy
references gives identical detections and published tracks on a seeded highway4-traffic run."""

from __future__ import annotations

import numpy as np
import pytest

from edge import native
from edge.pipeline import StageTimer

#: the kernels this check covers
DETECT_KERNELS = ("_spectra", "_peaks", "_track", "_pairs", "_angles", "_resolve", "_faces", "_aided", "_anglesout",
                  "_unalias", "_traffic")
#: relative tolerance on track floats: the tracker kernel's small matrix products sum in another order than BLAS
TRACK_RTOL = 1e-9


def _same_tracks(ta, tb) -> bool:
    """Equal ids, counts, flags and lanes; floats within TRACK_RTOL (absolute 1e-9 near zero)."""
    if len(ta) != len(tb):
        return False
    for a, b in zip(ta, tb):
        for name, va in vars(a).items():
            vb = getattr(b, name)
            if isinstance(va, float) and isinstance(vb, float):
                if not np.isclose(va, vb, rtol=TRACK_RTOL, atol=1e-9, equal_nan=True):
                    return False
            elif va != vb:
                return False
    return True


def test_kernels_and_reference_give_identical_detections_and_tracks(monkeypatch):
    if not native.enabled():
        pytest.skip("RADAR_EDGE_KERNELS=0: the numpy reference is in use")
    for k in DETECT_KERNELS:
        assert native.load(k) is not None, f"edge.native.{k} is not built (pip install -e . with a C compiler)"
    from tests.edge import lane_golden as g

    fast, frames = g.build("highway4-traffic", 1, 5.0)
    monkeypatch.setenv("RADAR_EDGE_KERNELS", "0")
    slow, _ = g.build("highway4-traffic", 1, 5.0)
    monkeypatch.delenv("RADAR_EDGE_KERNELS")
    assert fast.peaks.kernel is not None and slow.peaks.kernel is None
    assert fast.pairs.kernel is not None and slow.pairs.kernel is None
    assert fast.angles.kernel is not None and slow.angles.kernel is None
    assert fast.resolve.resolver.kernel is not None and slow.resolve.resolver.kernel is None
    assert fast.detections.filters[0].kernel is not None and slow.detections.filters[0].kernel is None
    assert fast.pairs._k_aided_pred is not None and slow.pairs._k_aided_pred is None
    assert fast.angles._k_out is not None and slow.angles._k_out is None
    ta, tb = StageTimer(16), StageTimer(16)
    n_det = n_trk = 0
    for f in frames(120):
        a, b = fast.process(f, ta), slow.process(f, tb)
        for name in ("range_m", "radial_speed_mps", "az_rad", "snr_db", "x_m", "y_m"):
            np.testing.assert_array_equal(getattr(a.detections, name), getattr(b.detections, name),
                                          err_msg=f"frame {f.seq} {name}")
        assert _same_tracks(a.tracks, b.tracks), f"frame {f.seq}"
        n_det += len(a.detections)
        n_trk += sum(t.confirmed for t in a.tracks)
    assert n_det > 1000 and n_trk > 500
