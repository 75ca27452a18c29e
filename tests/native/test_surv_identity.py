"""End to end: the surveillance pipeline with the DBSCAN kernel (edge/native/_dbscan.pyx) and with the numpy reference
gives identical detections, published tracks, provisional classes and classified events on a seeded run."""

from __future__ import annotations

from edge import native
from edge.native.check import agree, compare, outputs
from tests.native.conftest import require_kernel

#: the kernels the surveillance profile uses
SURV_KERNELS = ("_dbscan", "_survsig", "_alphabeta", "_aliasfit")


def test_surveillance_kernels_and_reference_give_identical_events():
    for k in SURV_KERNELS:
        require_kernel(k)
    from edge.bench import synth_frames
    from edge.config import load_config

    frames = synth_frames("d2g", "tavanti-test1", 1, 160)
    cfg = load_config(env={})
    fast = outputs("surveillance", frames, cfg, use_kernels=True)
    slow = outputs("surveillance", frames, cfg, use_kernels=False)
    assert native.enabled()  # the context manager restored the environment
    rep = compare(fast, slow)
    assert agree(rep, atol=0.0, track_atol=0.0), rep
    assert rep["detections"] > 150 and rep["confirmed_track_frames"] > 150 and rep["events"] >= 3
