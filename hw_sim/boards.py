"""The two simulated boards of the product."""

from __future__ import annotations

from hal.waveform import d2g_frontend, simo_frontend
from hw_sim.radio import D2G_RADIO, SIMO_RADIO
from hw_sim.synth import SimBoard

SIMO_BOARD = SimBoard(frontend=simo_frontend(), radio=SIMO_RADIO, fast_synthesis=True)
D2G_BOARD = SimBoard(frontend=d2g_frontend(), radio=D2G_RADIO)


def board_for(name: str) -> SimBoard:
    try:
        return {"simo": SIMO_BOARD, "d2g": D2G_BOARD}[name]
    except KeyError:
        raise ValueError(f"unknown simulated board {name!r}; expected 'simo' or 'd2g'") from None
