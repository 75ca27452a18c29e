"""Traffic: lanes, per-lane interval statistics, events."""
