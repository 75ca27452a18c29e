"""The surveillance pipeline's provisional classes with the feature and classifier caches equal those computed
afresh every frame (TrackFeatureAccumulator.features kept until the next add; the classifier asked again only
when the frame's feature rows change)."""

from __future__ import annotations

import math

import numpy as np

from edge.classify.features import TrackFeatureAccumulator


def test_accumulator_features_cached_until_next_add():
    rng = np.random.default_rng(7)
    acc = TrackFeatureAccumulator(90.0, vmax_kmh=5.35)
    for k in range(40):
        acc.add(0.1 * k, float(rng.uniform(0, 1)), float(rng.uniform(0, 10)), 5.0 + 0.3 * k,
                float(rng.uniform(0, 4)) if k % 3 else math.nan, float(rng.uniform(-5.35, 5.35)))
        first = acc.features()
        np.testing.assert_array_equal(first, acc._compute_features())
        first[:] = -1.0  # the caller's copy: the cache is not changed through it
        again = acc.features()
        np.testing.assert_array_equal(again, acc._compute_features())
        assert not np.any(again == -1.0)
    before = acc.features()
    acc.add(4.0, 0.5, 3.0, 20.0, 2.0, 1.0)
    after = acc.features()
    assert not np.array_equal(before, after, equal_nan=True)  # the cache was dropped by add
    np.testing.assert_array_equal(after, acc._compute_features())


def _run(frames, cfg, fresh: bool):
    from edge.bench import build_pipeline

    pipe = build_pipeline("surveillance", frames[0].frontend, cfg)
    clf = pipe.tracker.classifier
    calls = []
    orig = clf.predict_proba

    def counted(x):
        calls.append(len(x))
        return orig(x)

    clf.predict_proba = counted
    from edge.pipeline import StageTimer

    timer = StageTimer(16)
    out = []
    for f in frames:
        if fresh:  # no classifier cache, and every accumulator recomputes its features
            pipe._last_query = None
            for a in pipe.tracker._acc.values():
                a._features = None
        res = pipe.process(f, timer)
        out.append([(t.track_id, t.cls, t.class_probability) for t in res.tracks])
    return out, calls


def test_provisional_classes_same_with_and_without_caches():
    from edge.bench import synth_frames
    from edge.config import load_config

    frames = synth_frames("d2g", "tavanti-test1", 1, 140)
    cfg = load_config(env={})
    cached, n_cached = _run(frames, cfg, fresh=False)
    fresh, n_fresh = _run(frames, cfg, fresh=True)
    assert cached == fresh
    assert sum(1 for frame in cached for t in frame if t[1] is not None) > 100  # classes were published
    assert len(n_cached) < len(n_fresh)  # some frames reused the previous answer
