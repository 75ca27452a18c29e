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


#: the Distance2Go's TX power levels: RFMC SET_CONFIGURATION ``tx_power`` 0..``max_tx_power`` (7, full power, the
#: D2G firmware's default)
D2G_MAX_TX_POWER = 7
#: output power per level, as the simulated firmware reports it (RBAS TX power: 1000 * level - 2000 mdBm)
D2G_TX_POWER_STEP_DB = 1.0


def with_tx_power(board: SimBoard, level: int) -> SimBoard:
    """The Distance2Go ``board`` transmitting at TX power ``level`` (0..:data:`D2G_MAX_TX_POWER`): every echo and
    the TX->RX leakage (:attr:`hw_sim.radio.RadioModel.tx_backoff_db`) fall by :data:`D2G_TX_POWER_STEP_DB` a level
    below the full power; the receiver noise does not."""
    level = int(level)
    if not 0 <= level <= D2G_MAX_TX_POWER:
        raise ValueError(f"TX power level {level} out of range 0..{D2G_MAX_TX_POWER}")
    backoff = (D2G_MAX_TX_POWER - level) * D2G_TX_POWER_STEP_DB
    if backoff == board.radio.tx_backoff_db:
        return board
    return dataclasses.replace(board, radio=dataclasses.replace(board.radio, tx_backoff_db=backoff))
