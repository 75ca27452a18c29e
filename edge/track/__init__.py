"""Tracking: thin trackers orchestrating role objects (predict, gate, associate, update, initiate, delete).

Lane profile (Lim et al. §III-B)::

    from edge.track import PdafConfig, PdafTracker
    tracker = PdafTracker(cfg.section("track.pdaf"))
    tracks = tracker.step(detections, t_ns)   # tuple[edge.types.TrackState, ...]

See :mod:`edge.track.tracker` for the contract and the algorithm, :mod:`edge.track.roles` for the roles it runs
(built from the per-role sections of :mod:`edge.track.config`), :mod:`edge.track.pdaf` for eqs. 17-19 and
:mod:`edge.track.kalman` for the constant-velocity filter, :mod:`edge.track.imm` for the interacting
multiple models (lane keeping / manoeuvring) that run on top of it by default.
"""

from edge.track.config import PdafConfig
from edge.track.tracker import IdPool, PdafTracker, TrackTable

__all__ = ["IdPool", "PdafConfig", "PdafTracker", "TrackTable"]
