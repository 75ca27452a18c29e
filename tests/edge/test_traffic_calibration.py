"""The traffic self-calibration kept across restarts: file format, atomic writes, restore, re-aim."""

from __future__ import annotations

import json
import logging
import math

import pytest

from edge.traffic import Lane, TrafficConfig, TrafficMonitor
from edge.traffic.calibration import (FORMAT, Calibration, CalibrationError, CalibrationWriter, load_calibration)
from tests.edge.test_traffic import DT_NS, LANES_X, _synthetic_tracks, _ts

LANES = tuple(Lane(c, 3.5, d) for c, d in zip(LANES_X, (-1, -1, 1, 1)))


def _cal(yaw_deg=3.0, se_deg=0.02, mode="learned", lanes=LANES):
    return Calibration(math.radians(yaw_deg), math.radians(se_deg), 150, mode, lanes, 1.7e9)


def _save(path, cal):
    w = CalibrationWriter(path)
    w.submit(cal)
    w.close()
    return w


def test_round_trip_through_an_atomic_write(tmp_path):
    path = tmp_path / "cal.json"
    w = _save(path, _cal())
    assert (w.saved, w.errors) == (1, 0)
    assert [p.name for p in tmp_path.iterdir()] == ["cal.json"]  # no temporary file left behind
    doc = json.loads(path.read_text())
    assert doc["format"] == FORMAT and doc["yaw_deg"] == pytest.approx(3.0) and len(doc["lanes"]) == 4
    got = load_calibration(path)
    assert got.lanes == LANES and got.lane_mode == "learned" and got.yaw_votes == 150
    assert math.degrees(got.yaw_rad) == pytest.approx(3.0) and math.degrees(got.yaw_stderr_rad) == pytest.approx(0.02)


def test_the_newest_state_wins_and_close_flushes_it(tmp_path):
    path = tmp_path / "cal.json"
    w = CalibrationWriter(path)
    for yaw in (1.0, 2.0, 2.5):
        w.submit(_cal(yaw))
    w.close()
    assert 1 <= w.saved <= 3 and math.degrees(load_calibration(path).yaw_rad) == pytest.approx(2.5)


@pytest.mark.parametrize("text,why", [
    ("{not json", "not JSON"),
    ('{"format": "something-else", "version": 1}', "format"),
    (json.dumps({**_cal().to_json(), "version": 99}), "version"),
    (json.dumps({**_cal().to_json(), "yaw_deg": 80.0}), "yaw_deg"),
    (json.dumps({**_cal().to_json(), "lanes": [{"center_m": 0.0, "width_m": 3.5, "direction": "sideways"}]}),
     "direction"),
    (json.dumps({k: v for k, v in _cal().to_json().items() if k != "yaw_stderr_deg"}), "yaw_stderr_deg"),
])
def test_unusable_files_are_refused_with_the_reason(tmp_path, text, why):
    path = tmp_path / "cal.json"
    path.write_text(text)
    with pytest.raises(CalibrationError, match=why):
        load_calibration(path)


def test_missing_file_is_no_calibration(tmp_path):
    assert load_calibration(tmp_path / "nothing.json") is None


def test_a_write_error_is_counted_not_raised(tmp_path, caplog):
    w = CalibrationWriter(tmp_path / "no-such-dir" / "cal.json")
    with caplog.at_level(logging.WARNING):
        w.submit(_cal())
        w.close()
    assert (w.saved, w.errors) == (0, 1) and "cannot save the traffic calibration" in caplog.text


def test_monitor_starts_from_the_saved_calibration(tmp_path):
    """Learned lanes and a 3 deg yaw restored: the first frame already has lanes, and the wrong-way gate
    trusts the saved yaw (0.02 deg) -- a wrong-way car 150 m away raises the alarm after 15 frames
    instead of waiting until it is near."""
    path = tmp_path / "cal.json"
    _save(path, _cal(3.0, 0.02))
    cfg = TrafficConfig(lane_mode="learned", calibration_file=str(path), wrong_way_min_frames=15)
    mon = TrafficMonitor(cfg)
    assert mon.lanes == LANES and math.degrees(mon.yaw_rad) == pytest.approx(3.0)
    yaw = math.radians(3.0)
    events = []
    for k in range(20):
        u, s = 5.25, 150.0 - 25.0 * k * 0.1  # lane 3 runs away from the radar; this car comes toward it
        x, y = u * math.cos(yaw) - s * math.sin(yaw), u * math.sin(yaw) + s * math.cos(yaw)
        vx, vy = 25.0 * math.sin(yaw), -25.0 * math.cos(yaw)
        events += [(k, e.kind) for e in mon.update((_ts(7, x, y, vx, vy, k + 1),), k * DT_NS).events]
    mon.close()
    assert events == [(14, "wrong_way")]
    uncal = TrafficMonitor(TrafficConfig(lane_mode="learned", wrong_way_min_frames=15))
    assert uncal.lanes == ()


def test_monitor_saves_what_it_learned_and_a_restart_uses_it(tmp_path):
    path = tmp_path / "cal.json"
    cfg = TrafficConfig(lane_mode="learned", relearn_every_s=5.0, calibration_file=str(path),
                        calibration_save_every_s=10.0)
    mon = TrafficMonitor(cfg)
    for t_ns, tracks in _synthetic_tracks(2.0, 12, seed=5):
        mon.update(tracks, t_ns)
    assert mon._writer is not None
    mon.close()
    cal = load_calibration(path)
    assert cal is not None and math.degrees(cal.yaw_rad) == pytest.approx(2.0, abs=0.3)
    assert len(cal.lanes) == 4 and cal.yaw_votes >= 30 and 0 < math.degrees(cal.yaw_stderr_rad) < 0.3
    again = TrafficMonitor(cfg)
    assert again.lanes == cal.lanes and again.yaw_rad == pytest.approx(cal.yaw_rad)
    again.close()


def test_a_re_aimed_radar_drops_the_saved_yaw(tmp_path, caplog):
    """Saved: 0 deg. The radar now looks 3 deg off: once yaw_min_tracks tracks ended, the estimate is
    further than calibration_moved_deg from the saved yaw and replaces it."""
    path = tmp_path / "cal.json"
    _save(path, _cal(0.0, 0.02, mode="configured"))
    mon = TrafficMonitor(TrafficConfig(calibration_file=str(path)))
    assert mon.saved_calibration is not None
    with caplog.at_level(logging.WARNING):
        for t_ns, tracks in _synthetic_tracks(3.0, 6, seed=7):
            mon.update(tracks, t_ns)
    mon.close()
    assert mon.saved_calibration is None and "re-aimed" in caplog.text
    assert math.degrees(mon.yaw_rad) == pytest.approx(3.0, abs=0.3)


def test_a_corrupt_or_foreign_file_starts_uncalibrated(tmp_path, caplog):
    path = tmp_path / "cal.json"
    path.write_text("\x00\x01garbage")
    with caplog.at_level(logging.WARNING):
        mon = TrafficMonitor(TrafficConfig(lane_mode="learned", calibration_file=str(path)))
    assert mon.saved_calibration is None and mon.lanes == () and "calibration ignored" in caplog.text
    mon.close()  # never updated: nothing to save, the broken file stays for a look
    assert path.read_text() == "\x00\x01garbage"
    _save(path, _cal(mode="configured"))
    with caplog.at_level(logging.WARNING):
        mon = TrafficMonitor(TrafficConfig(lane_mode="learned", calibration_file=str(path)))
    assert mon.saved_calibration is None and "lane_mode" in caplog.text
    mon.close()
