"""The lane profile's fast paths against the plain implementations they replace (same results)."""

from __future__ import annotations

import numpy as np
import pytest

from edge.dsp.cfar import circular_pad, os_cfar, os_cfar_at, os_cfar_at_padded, reference_index


@pytest.mark.parametrize("n_train,n_guard,rank", [(16, 2, 24), (4, 0, 3), (8, 1, 16), (3, 5, 1)])
def test_os_cfar_at_padded_equals_os_cfar(n_train, n_guard, rank):
    rng = np.random.default_rng(7)
    power = rng.gamma(4.0, size=(4, 256)).astype(np.float32)
    power[1, 40:60] *= 100.0  # an extended target
    power[2, :5] = 0.0  # exact zeros sort like any other value
    ref = reference_index(256, n_train, n_guard)
    _, _, full = os_cfar(power, ref, rank, 3.0)
    rows, cols = np.nonzero(rng.random(power.shape) < 0.3)
    rows = np.concatenate([rows, [0, 3, 3]])
    cols = np.concatenate([cols, [0, 255, 1]])  # both ends (circular windows)
    noise, cells = os_cfar_at_padded(circular_pad(power, n_train + n_guard), rows, cols, n_train, n_guard, rank)
    assert noise.dtype == np.float32 and cells.dtype == np.float32
    np.testing.assert_array_equal(noise, full[rows, cols])
    np.testing.assert_array_equal(noise, os_cfar_at(power, rows, cols, ref, rank))
    np.testing.assert_array_equal(cells, np.stack([power[rows, (cols + o) % 256] for o in (-1, 0, 1)], axis=1))
    empty = os_cfar_at_padded(circular_pad(power, n_train + n_guard), rows[:0], cols[:0], n_train, n_guard, rank)
    assert empty[0].shape == (0,) and empty[1].shape == (0, 3)
