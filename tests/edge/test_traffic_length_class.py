"""IntervalStatistics.length_class (a bisect on Python floats) against numpy.searchsorted(side="right"), the rule
it replaced: the same class for lengths on, just off and between the class edges."""

from __future__ import annotations

import numpy as np

from edge.traffic import TrafficConfig
from edge.traffic.stats import IntervalStatistics


def test_length_class_equals_searchsorted_right():
    cfg = TrafficConfig()
    st = IntervalStatistics(cfg)
    edges = np.asarray(cfg.length_class_edges_m, dtype=np.float64)
    assert edges.size >= 2
    rng = np.random.default_rng(3)
    lengths = np.concatenate([edges, np.nextafter(edges, -np.inf), np.nextafter(edges, np.inf),
                              rng.uniform(0.0, 30.0, 500), [0.0, -1.0, 1e9]])
    for v in lengths.tolist():
        assert st.length_class(v) == st.class_names[int(np.searchsorted(edges, v, side="right"))], v
    assert st.length_class(np.float64(edges[0])) == st.class_names[1]
    assert st.length_class(None) == st.length_class(float("nan")) == "unknown"
