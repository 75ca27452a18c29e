"""radar-edge plot: every figure renders from a full result set and from the minimal pipeline's."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from edge.cli import main  # noqa: E402
from edge.config import load_config  # noqa: E402
from edge.ops import plots  # noqa: E402
from edge.types import Detections, FrameResult, LaneStats, TrackState  # noqa: E402
from hal import open_radar  # noqa: E402
from hal.recording import RecordingWriter  # noqa: E402

PNG = b"\x89PNG\r\n\x1a\n"


def _record(url: str, n: int, path, meta=None):
    with open_radar(url) as src:
        w = RecordingWriter(src.frontend, meta=meta or {})
        for _ in range(n):
            w.add(src.read_frame(timeout=None))
    return w.save(path)


@pytest.fixture(scope="module")
def d2g_rec(tmp_path_factory):
    p = tmp_path_factory.mktemp("rec") / "d2g.npz"
    return _record("sim://d2g?scenario=tavanti-test1&frames=25&realtime=0", 25, p, {"scenario": "tavanti-test1"})


@pytest.fixture(scope="module")
def simo_rec(tmp_path_factory):
    p = tmp_path_factory.mktemp("rec") / "simo.npz"
    return _record("sim://simo?scenario=highway4&frames=12&realtime=0", 12, p, {"scenario": "highway4"})


def _rich_results(n: int, period_ns: int) -> list[FrameResult]:
    """What a full lane pipeline would give: positions, clusters, tracks with classes, presence, stats."""
    rng = np.random.default_rng(3)
    out = []
    for k in range(n):
        r = np.array([10.0 - 0.2 * k, 6.0 + 0.1 * k, 12.0], dtype=np.float32)
        az = np.array([0.1, -0.15, np.nan], dtype=np.float32)
        v = np.array([-1.0, 0.5, 0.0], dtype=np.float32)
        det = Detections.from_polar(r, v, az, rng.uniform(10, 20, 3), extra={"cluster": np.array([0, 1, -1])})
        tracks = (
            TrackState(1, float(det.x_m[0]), float(det.y_m[0]), 0.0, -1.0, float(r[0]), -1.0, 0.1, k, k, cls="car"),
            TrackState(2, float(det.x_m[1]), float(det.y_m[1]), 0.0, 0.5, float(r[1]), 0.5, -0.15, k, k, lane=1),
        )
        stats = ()
        if k % 5 == 4:
            stats = tuple(LaneStats(lane=ln, interval_start_ns=(k - 4) * period_ns, interval_s=5 * period_ns / 1e9,
                                    sequence=k // 5, volume=ln + k // 5, occupancy_pct=10.0 * ln, mean_speed_kmh=50.0 + ln,
                                    speed_p85_kmh=60.0, headway_s=2.0, gap_s=1.5) for ln in range(2))
        out.append(FrameResult("lane", k, k * period_ns, det, tracks=tracks, presence=(k % 3 == 0, True),
                               lane_stats=stats))
    return out


def _check_pngs(paths, names):
    assert [p.name for p in paths] == names
    for p in paths:
        data = p.read_bytes()
        assert data[:8] == PNG and len(data) > 10_000, p


def test_minimal_pipeline_degrades_gracefully(d2g_rec, tmp_path):
    rep = plots.replay(d2g_rec, load_config(env={}), "minimal")
    assert rep.profile == "minimal" and len(rep.results) == 25
    assert np.allclose(np.diff(rep.t_s), 0.2)  # frame period, not the back-to-back host times
    made = plots.render(rep, tmp_path)
    _check_pngs(made, [f"d2g-{n}.png" for n in plots.FIGURES])


def test_full_results_on_both_boards(d2g_rec, simo_rec, tmp_path):
    from hal.recording import Recording

    for path in (d2g_rec, simo_rec):
        rec = Recording(path)
        period = int(rec.frontend.waveform.frame_period_s * 1e9)
        results = _rich_results(len(rec), period)
        results[3].intermediates["rd_map"] = np.abs(np.random.default_rng(0).normal(size=(64, 32))).astype(np.float32)
        rep = plots.Replayed(path, rec, "lane", results, plots._lanes(rec, None))
        assert rep.lanes or rec.meta["scenario"] == "tavanti-test1"
        made = plots.render(rep, tmp_path / path.stem, frame=3)
        _check_pngs(made, [f"{path.stem}-{n}.png" for n in plots.FIGURES])
        # frame 3 carries a pipeline map: it is the one drawn
        assert plots._intermediate_map(results[3])[3] == "rd_map"


def test_cli_plot(d2g_rec, tmp_path, capsys):
    rc = main(["plot", str(d2g_rec), "--out", str(tmp_path), "--figure", "range-time", "--frames", "10"])
    assert rc == 0
    assert capsys.readouterr().out.strip().endswith("d2g-range-time.png")
    assert (tmp_path / "d2g-range-time.png").read_bytes()[:8] == PNG


def test_missing_matplotlib_is_a_clear_error(monkeypatch, d2g_rec, tmp_path, capsys):
    import builtins

    real = builtins.__import__

    def no_mpl(name, *a, **kw):
        if name.startswith("matplotlib"):
            raise ImportError("No module named 'matplotlib'")
        return real(name, *a, **kw)

    monkeypatch.setattr(builtins, "__import__", no_mpl)
    rc = main(["plot", str(d2g_rec), "--out", str(tmp_path)])
    assert rc == 2 and "pip install 'radar-edge[plot]'" in capsys.readouterr().out


def test_default_map_axes_match_the_surveillance_front_end():
    """A pipeline map without axes is drawn on the axes of edge.dsp.range_doppler's layout."""
    rd = pytest.importorskip("edge.dsp.range_doppler", reason="surveillance front end not in this build")
    from hal.waveform import d2g_frontend

    fe = d2g_frontend()
    proc = rd.RangeDopplerProcessor(fe)
    rng, spd = plots._default_rd_axes(fe, proc.shape)
    np.testing.assert_allclose(rng, proc.range_m, rtol=1e-4)
    np.testing.assert_allclose(spd * 3.6, proc.radial_speed_kmh, rtol=1e-4, atol=1e-4)


def test_device_recording_without_truth_or_scenario(tmp_path):
    """What the on-device recorder writes: no ground truth, no scenario, receive times only."""
    from hal.frame import RawFrame

    with open_radar("sim://d2g?scenario=tavanti-test1&frames=8&realtime=0") as src:
        w = RecordingWriter(src.frontend, meta={"profile": "surveillance"})
        for k in range(8):
            f = src.read_frame(timeout=None)
            w.add(RawFrame(seq=f.seq, t_ns=1_000_000_000 + k * 200_000_000, i=f.i, q=f.q, frontend=f.frontend))
    path = w.save(tmp_path / "device.npz")
    rep = plots.replay(path, load_config(env={}), "minimal")
    assert not rep.recording.has_truth and rep.lanes == []
    np.testing.assert_allclose(rep.t_s, np.arange(8) * 0.2)
    _check_pngs(plots.render(rep, tmp_path / "out"), [f"device-{n}.png" for n in plots.FIGURES])


def test_pipeline_sees_the_recordings_time_line(d2g_rec, monkeypatch):
    """Frames reach the pipeline spaced by simulation time, not by the host times of a fast recording."""
    import edge.pipeline
    from edge.pipelines.minimal import MinimalConfig, MinimalPipeline

    seen = []

    class Spy(MinimalPipeline):
        def process(self, frame, timer):
            seen.append(frame.t_ns)
            return super().process(frame, timer)

    monkeypatch.setattr(edge.pipeline, "build_pipeline", lambda prof, fe, cfg: Spy(fe, MinimalConfig()))
    from dataclasses import replace

    from hal.recording import Recording

    # a recording made faster than real time with host receive times (5 ms apart; offline sources now
    # stamp the board's timeline, so rewrite the times)
    rec = Recording(d2g_rec)
    with open_radar(f"replay://{d2g_rec}?speed=0") as src:
        frames = [src.read_frame(timeout=None) for _ in range(len(rec))]
    w = RecordingWriter(rec.frontend, meta={"scenario": "tavanti-test1"})
    for k, f in enumerate(frames):
        w.add(replace(f, t_ns=1_000_000_000 + k * 5_000_000, meta={}))
    fast = w.save(d2g_rec.with_name("d2g-host-times.npz"))
    host = np.diff(Recording(fast).t_ns) / 1e6
    assert host.mean() < 100  # recorded faster than real time
    plots.replay(fast, load_config(env={}), "minimal")
    np.testing.assert_allclose(np.diff(seen) / 1e6, 200.0)
