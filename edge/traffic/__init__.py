"""Traffic: lanes, per-lane interval statistics, events (lane profile, after Lim et al. and side-fire practice).

    from edge.traffic import TrafficConfig, TrafficMonitor
    monitor = TrafficMonitor(cfg.section("traffic"))
    upd = monitor.update(tracks, t_ns)   # -> TrafficUpdate(tracks, presence, lane_stats, events)

See :mod:`edge.traffic.monitor` (contract), :mod:`edge.traffic.lanes` (road frame, yaw estimate, lane
learning), :mod:`edge.traffic.stats` (definitions of every statistic) and :mod:`edge.traffic.calibration`
(the self-calibration kept across restarts).
"""

from edge.traffic.config import TrafficConfig
from edge.traffic.lanes import Lane
from edge.traffic.monitor import TrafficMonitor, TrafficUpdate

__all__ = ["Lane", "TrafficConfig", "TrafficMonitor", "TrafficUpdate"]
