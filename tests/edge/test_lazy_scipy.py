"""The OS-CFAR scale and the PDAF gate without scipy.stats / scipy.optimize at import (start-up time, issue 30):
the same numbers as the scipy.stats distributions they replace."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import scipy.optimize
import scipy.stats

from edge.dsp.cfar import os_cfar_pfa, os_cfar_scale
from edge.track.pdaf import gate_threshold


def _pfa_stats(scale: float, n_ref: int, rank: int, n_looks: int) -> float:
    """os_cfar_pfa as it was written with scipy.stats.gamma (the reference)."""
    import math

    g = scipy.stats.gamma(n_looks)
    u = np.linspace(0.0, 1.0, 20001)[1:-1]
    y = g.ppf(u)
    log_beta = (math.lgamma(n_ref + 1) - math.lgamma(rank) - math.lgamma(n_ref - rank + 1)
                + (rank - 1) * np.log(u) + (n_ref - rank) * np.log1p(-u))
    return float(np.trapezoid(np.exp(log_beta) * g.sf(scale * y), u))


@pytest.mark.parametrize("n_ref,rank,n_looks", [(32, 24, 4), (16, 12, 1), (24, 18, 2), (32, 28, 4)])
@pytest.mark.parametrize("scale", [0.7, 3.0, 11.5])
def test_os_cfar_pfa_equals_scipy_stats_gamma(scale, n_ref, rank, n_looks):
    assert os_cfar_pfa(scale, n_ref, rank, n_looks) == _pfa_stats(scale, n_ref, rank, n_looks)


@pytest.mark.parametrize("pfa", [1e-3, 1e-5, 3e-7])
def test_os_cfar_scale_is_the_root_of_the_reference_pfa(pfa):
    a = os_cfar_scale(pfa, 32, 24, n_looks=4)
    f = lambda s: np.log(max(_pfa_stats(s, 32, 24, 4), 1e-300)) - np.log(pfa)  # noqa: E731
    hi = 1.0
    while f(hi) > 0:
        hi *= 2.0
    assert abs(a - scipy.optimize.brentq(f, 1e-9, hi, xtol=1e-6, rtol=1e-9)) <= 1e-12


@pytest.mark.parametrize("p_g", [0.9, 0.99, 0.999, 0.9999])
@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_gate_threshold_equals_chi2_ppf(p_g, n):
    assert gate_threshold(p_g, n) == float(scipy.stats.chi2.ppf(p_g, n))


def test_cfar_and_pdaf_import_neither_scipy_stats_nor_optimize():
    code = ("import sys, edge.dsp.cfar, edge.track.pdaf\n"
            "print(','.join(m for m in ('scipy.stats', 'scipy.optimize') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == ""
