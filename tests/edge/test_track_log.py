"""Track logs (``evaluate --record-tracks``) and ``radar-edge replay-traffic``: the traffic layer run again on the
recorded tracks reproduces the evaluation's counts, and changed traffic settings act as they should."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

from edge.cli import main
from edge.config import build_section, load_config
from edge.evaluation import evaluate as evaluate_any
from edge.evaluation.lane import _installer_config, evaluate
from edge.evaluation.track_log import TrackLogError, TrackLogRecorder, load_track_log, replay_traffic
from edge.pipeline import StageTimer
from edge.pipelines.lane import LanePipeline
from hal.frame import RawFrame
from hw_sim.boards import SIMO_BOARD
from hw_sim.scenario import load_scenario
from hw_sim.simulator import FrameSimulator


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """highway4 (10 s, seed 3): five vehicles cross the detection line at 50 m."""
    path = tmp_path_factory.mktemp("tracklog") / "h4.npz"
    rep = evaluate(load_scenario("highway4"), seed=3, config=load_config(env={}), record_tracks=path)
    return path, rep


def _traffic(log, **changes):
    return build_section("traffic", {**log.meta["traffic"], **changes})


def test_replay_with_the_recorded_settings_reproduces_the_evaluation(recorded):
    path, rep = recorded
    assert rep["track_log"] == str(path)
    log = load_track_log(path)
    s = rep["summary"]
    assert log.frames == rep["frames"] and log.meta["scenario"] == "highway4" and log.meta["seed"] == 3
    assert sum(s["volume_true_per_lane"]) >= 4  # the run has crossings to count
    out = replay_traffic(log, _traffic(log))
    c = out["counts"]
    assert c["count_error_per_lane"] == s["count_error_per_lane"]
    assert c["volume_true_per_lane"] == s["volume_true_per_lane"]
    assert c["volume_measured_per_lane"] == s["volume_measured_per_lane"]
    assert c["count_mismatches"] == s["count_mismatches"]
    assert out["events"] == s["events"]
    assert out["lane_centers_m"] == s["lane_centers_m"]
    assert out["estimated_yaw_deg"] == pytest.approx(s["estimated_yaw_deg"], abs=1e-12)


def test_replay_with_other_settings(recorded):
    log = load_track_log(recorded[0])
    base = replay_traffic(log, _traffic(log))["counts"]
    # shorter statistics intervals close more of them but count the same crossings
    short = replay_traffic(log, _traffic(log, interval_s=1.0))["counts"]
    assert short == base
    # every lane's direction reversed: no vehicle drives its lane's way, so none is counted
    # and the approaching and receding vehicles raise wrong-way alarms
    flipped = tuple("away" if d == "toward" else "toward" for d in log.meta["traffic"]["lane_directions"])
    out = replay_traffic(log, _traffic(log, lane_directions=flipped))
    assert out["counts"]["volume_measured_per_lane"] == [0, 0, 0, 0]
    assert len(out["counts"]["count_mismatches"]["missed"]) == sum(base["volume_true_per_lane"])
    assert any(e["kind"] == "wrong_way" for e in out["events"])


def test_the_log_holds_the_traffic_layers_input_exactly(tmp_path):
    sc = load_scenario("highway4")
    cfg = load_config(env={})
    lane_cfg, track_cfg, traffic_cfg = _installer_config(cfg, sc)
    pipe = LanePipeline(SIMO_BOARD.frontend, lane_cfg, track_cfg, traffic_cfg)
    seen = []
    rec = TrackLogRecorder(chunk_rows=7)  # several column chunks

    def tap(tracks, t_ns, mx):
        seen.append((t_ns, tracks, None if mx is None else np.array(mx)))
        rec(tracks, t_ns, mx)

    pipe.traffic_tap = tap
    sim = FrameSimulator(SIMO_BOARD, sc.build_scene(2), 2)
    timer = StageTimer()
    for n in range(40):
        f = sim.frame(n)
        pipe.process(RawFrame(n, int(round(f.t_s * 1e9)), f.i, f.q, SIMO_BOARD.frontend, f.truth), timer)
    meta = {"scenario": sc.name, "seed": 2, "frames": 40, "frame_period_s": 0.033, "n_lanes": 4,
            "traffic": {"detection_line_m": 50.0}, "counts": {}, "events": []}
    log = load_track_log(rec.save(tmp_path / "t.npz", meta, [(1, 0.5, 7, "car")]))
    got = list(log.frame_tracks())
    assert len(got) == 40 and sum(len(t) for _, t, _ in seen) > 40  # tracks confirmed within the 40 frames
    for (t0, tr0, mx0), (t1, tr1, mx1) in zip(seen, got):
        assert t0 == t1 and tr0 == tr1
        assert (mx0 is None) == (mx1 is None)
        if mx0 is not None:
            np.testing.assert_array_equal(mx0, mx1)
    assert log.true_crossings == [(1, 0.5, 7, "car")]


def test_bad_track_logs_and_settings_are_clear_errors(recorded, tmp_path, capsys):
    path, _ = recorded
    not_zip = tmp_path / "notes.npz"
    not_zip.write_text("hello")
    with pytest.raises(TrackLogError, match="not a track log"):
        load_track_log(not_zip)
    with pytest.raises(TrackLogError, match="no such file"):
        load_track_log(tmp_path / "missing.npz")
    raw = tmp_path / "raw.npz"
    np.savez(raw, iq=np.zeros(4, np.int16))
    with pytest.raises(TrackLogError, match="radar-edge replay"):
        load_track_log(raw)
    # a log cut short: a column missing
    cut = tmp_path / "cut.npz"
    with zipfile.ZipFile(path) as zin, zipfile.ZipFile(cut, "w") as zout:
        for item in zin.infolist():
            if item.filename != "track_hits.npy":
                zout.writestr(item, zin.read(item.filename))
    with pytest.raises(TrackLogError, match="incomplete track log: no track_hits"):
        load_track_log(cut)
    log = load_track_log(path)
    with pytest.raises(TrackLogError, match="detection_line_m"):
        replay_traffic(log, _traffic(log, detection_line_m=60.0))
    with pytest.raises(ValueError, match="lane profile"):
        evaluate_any("tavanti-test1", seed=1, frames=5, events=None, config=load_config(env={}),
                     record_tracks=str(tmp_path / "x.npz"))
    assert main(["replay-traffic", str(path), "--set", "track.pdaf.confirm_m=3"]) == 2
    assert "traffic layer only" in capsys.readouterr().err


def _rewrite_meta(src, dst, change):
    """A copy of the track log ``src`` at ``dst`` with ``change(meta)`` applied to its meta block."""
    with zipfile.ZipFile(src) as z:
        cols = {name[:-4]: np.load(z.open(name), allow_pickle=False) for name in z.namelist()}
    meta = json.loads(cols["meta"].tobytes().decode())
    change(meta)
    cols["meta"] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
    np.savez_compressed(dst, **cols)
    return dst


def test_replay_traffic_command(recorded, tmp_path, capsys):
    path, rep = recorded
    out = tmp_path / "r.json"
    assert main(["replay-traffic", str(path), "--set", "traffic.interval_s=10", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "changed: traffic.interval_s=10.0" in text and "count error per lane" in text
    doc = json.loads(out.read_text())
    assert doc["changed"] == {"interval_s": 10.0}
    assert doc["counts"]["count_error_per_lane"] == rep["summary"]["count_error_per_lane"]
    assert doc["recorded"]["counts"]["count_error_per_lane"] == rep["summary"]["count_error_per_lane"]


def test_replay_traffic_command_several_logs_and_other_versions(recorded, tmp_path, capsys):
    """Several logs give one table of count errors; a log written by a version with a traffic setting this one does
    not have replays with that setting dropped, and says so."""
    path, rep = recorded
    other = _rewrite_meta(path, tmp_path / "other.npz", lambda m: m["traffic"].update(count_future_rule_s=0.5))
    out = tmp_path / "both.json"
    assert main(["replay-traffic", str(path), str(other), "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "(dropped): traffic.count_future_rule_s" in text
    err = sum(map(abs, rep["summary"]["count_error_per_lane"]))
    assert text.rstrip().splitlines()[-1].split() == ["all", str(2 * err), "->", str(2 * err)]
    docs = json.loads(out.read_text())
    assert [d["dropped_recorded_settings"] for d in docs] == [[], ["count_future_rule_s"]]
    assert docs[0]["counts"] == docs[1]["counts"]


def test_a_log_written_before_the_quality_fields_still_loads(tmp_path):
    from edge.types import TrackState

    rec = TrackLogRecorder()
    t = TrackState(3, 1.0, 50.0, 0.0, -20.0, 50.01, -20.0, 0.02, 30, 28, x_sd_m=0.2, y_sd_m=0.1, vx_sd_mps=0.5,
                   vy_sd_mps=0.3, existence_probability=0.9999)
    meta = {"scenario": "x", "seed": 1, "frames": 1, "frame_period_s": 0.033, "n_lanes": 4,
            "traffic": {"detection_line_m": 50.0}, "counts": {}, "events": []}
    rec((t,), 0, None)
    path = rec.save(tmp_path / "new.npz", meta, [])
    assert next(load_track_log(path).frame_tracks())[1] == (t,)
    with np.load(path) as z:
        old = {k: z[k] for k in z.files if not k.endswith(("_sd_m", "_sd_mps", "existence_probability"))}
    np.savez(tmp_path / "old.npz", **old)
    (got,) = next(load_track_log(tmp_path / "old.npz").frame_tracks())[1]
    assert got.x_sd_m is None and got.existence_probability is None and got.y_m == 50.0
