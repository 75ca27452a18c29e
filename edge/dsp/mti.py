"""Clutter and leakage removal: Tavanti's IIR canceller with step initialisation (DESIGN §5).

Along slow time (chirp index ``n``) within one frame::

    w[n] = q[n] + K_c w[n-1]
    u[n] = w[n] - w[n-1]

with the state initialised to ``w[-1] = q[0] / (1 - K_c)`` so that ``u[0] = 0`` (step
initialisation: a static return is a step at ``n = 0`` and produces no transient). The first output
chirp is therefore always zero and is dropped: ``N_c`` chirps in, ``N_c - 1`` out (``T_CPI,eff``).
``K_c = 0`` is the single delay-line canceller ``u[n] = q[n] - q[n-1]``.

The filter is linear and the frame short (21 chirps on the Distance2Go), so it is applied as one
precomputed ``(N_c - 1, N_c)`` real matrix: ``u = H @ q`` — no loop over chirps at run time.
"""

from __future__ import annotations

import numpy as np


def iir_canceller_matrix(n_chirps: int, k_c: float) -> np.ndarray:
    """``(n_chirps - 1, n_chirps)`` float32 matrix ``H`` with ``u[1:] = H @ q`` (``u[0] = 0`` dropped).

    Built once per waveform by running the recursion on the identity (float64, then cast).
    """
    if not 0.0 <= k_c < 1.0:
        raise ValueError(f"K_c must be in [0, 1) for a stable canceller, got {k_c!r}")
    if n_chirps < 2:
        raise ValueError("the canceller needs at least two chirps per frame")
    q = np.eye(n_chirps)
    w_prev = q[0] / (1.0 - k_c)  # step initialisation
    rows = []
    for n in range(n_chirps):
        w = q[n] + k_c * w_prev
        rows.append(w - w_prev)
        w_prev = w
    h = np.array(rows)
    return h[1:].astype(np.float32)


def iir_canceller(q: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Apply the canceller along the chirp axis.

    ``q``: complex64 ``(..., n_chirps, n_samples)``; ``h`` from :func:`iir_canceller_matrix`.
    Returns complex64 ``(..., n_chirps - 1, n_samples)``: the filtered chirps 1..N_c-1.
    """
    return np.matmul(h.astype(q.real.dtype, copy=False), q)


def iir_canceller_reference(q: np.ndarray, k_c: float) -> np.ndarray:
    """The recursion itself, chirp by chirp, all ``N_c`` outputs (``u[0]`` included): for tests."""
    q = np.asarray(q, dtype=np.complex128)
    u = np.empty_like(q)
    w_prev = q[..., 0, :] / (1.0 - k_c)
    for n in range(q.shape[-2]):
        w = q[..., n, :] + k_c * w_prev
        u[..., n, :] = w - w_prev
        w_prev = w
    return u
