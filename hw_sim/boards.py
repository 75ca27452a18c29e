"""The two simulated boards of the product."""

from __future__ import annotations

from hal.waveform import d2g_frontend, simo_frontend
from hw_sim.physics import Physics
import dataclasses

from hw_sim.radio import D2G_RADIO, SIMO_RADIO, ReceiverImperfections, RoadSurface, with_elevation
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
    """``board`` as ``physics`` sets it up (antenna patterns, road bounce, receiver imperfections, gain).

    * ``elevation``: the SIMO board's elevation widths (Lim gives none; :func:`hw_sim.radio.with_elevation`);
      the Distance2Go keeps its datasheet 42 x 20 deg (Tavanti Table I);
    * ``road_bounce``: a :class:`hw_sim.radio.RoadSurface` of the road's permittivity, loss, roughness and
      the antennas' polarisation;
    * the receiver fields: a :class:`hw_sim.radio.ReceiverImperfections` (None when all are zero);
    * ``gain_offset_db``: the radio's receive-chain gain offset.

    With ``preset = "v1"`` the board is ``board`` itself (every choice off), so v1 frames are bit-exact.
    """
    radio = board.radio
    if name == "simo":
        radio = with_elevation(radio, physics.elevation)
    if physics.gain_offset_db != 0.0:
        radio = dataclasses.replace(radio, gain_offset_db=radio.gain_offset_db + physics.gain_offset_db)
    road = None
    if physics.road_bounce:
        road = RoadSurface(permittivity=physics.road_permittivity, loss_tangent=physics.road_loss_tangent,
                           roughness_mm=physics.road_roughness_mm, polarisation=physics.polarisation)
    receiver = ReceiverImperfections(
        iq_gain_imbalance_db=physics.iq_gain_imbalance_db,
        iq_phase_imbalance_deg=physics.iq_phase_imbalance_deg,
        dc_offset_counts=physics.dc_offset_counts,
        phase_noise_deg_rms=physics.phase_noise_deg_rms,
        channel_mismatch_db=physics.channel_mismatch_db,
        channel_mismatch_deg=physics.channel_mismatch_deg,
    )
    if not receiver.active:
        receiver = None
    if radio is board.radio and road is None and receiver is None:
        return board
    return dataclasses.replace(board, radio=radio, road=road, receiver=receiver)
