"""The lane pipeline on simulated SIMO frames: accuracy for a single car, dtypes, config, evaluation smoke test."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge.config import load_config
from edge.pipeline import StageTimer, build_pipeline
from edge.pipelines.lane import LaneConfig, LanePipeline
from hal.frame import RawFrame
from hw_sim import SIMO_BOARD, FrameSimulator, RadarPose, Scene, Target
from hw_sim.scene import LinearTrajectory

FE = SIMO_BOARD.frontend


def _single_car_frames(y_m=120.0, x_m=-1.75, vy=-25.0, n=8, seed=4):
    sc = Scene(RadarPose(height_m=7.0, tilt_deg=1.5), seed=seed)
    sc.add_target(Target(1, "car", LinearTrajectory((x_m, y_m, 0.5), (0.0, vy, 0.0)), np.zeros((1, 3)),
                         np.array([10.0]), swerling=0))
    sim = FrameSimulator(SIMO_BOARD, sc, seed)
    for k in range(n):
        f = sim.frame(k)
        yield RawFrame(k, int(round(f.t_s * 1e9)), f.i, f.q, FE, f.truth)


@pytest.mark.parametrize("y_m,x_m,vy", [(60.0, 1.75, 22.0), (120.0, -1.75, -25.0), (250.0, -5.25, -33.0)])
def test_single_car_range_speed_angle_within_tolerance(y_m, x_m, vy):
    p = LanePipeline(FE, LaneConfig(mounting_height_m=7.0, tracking=False))
    timer = StageTimer()
    errs = []
    for fr in _single_car_frames(y_m, x_m, vy):
        det, _ = p.detect(fr, timer)
        assert len(det) == 1, f"expected exactly one detection, got {len(det)}"
        tr = fr.truth
        # the point scatterer sits 0.5 m above the road: compare with its slant range and azimuth
        errs.append((det.range_m[0] - tr.range_m[0], det.radial_speed_mps[0] - tr.radial_speed_mps[0],
                     math.degrees(det.az_rad[0] - tr.az_rad[0]), det.x_m[0] - tr.position_m[0, 0],
                     det.y_m[0] - tr.position_m[0, 1]))
    e = np.abs(np.array(errs))
    # 0.75 m bins: a twentieth of a bin in range; 1.2 m/s Doppler resolution: a tenth in speed
    assert e[:, 0].max() < 0.06
    assert e[:, 1].max() < 0.1
    assert e[:, 2].max() < (0.3 if y_m < 200 else 0.6)  # Bartlett over 4 elements, SNR falls with range
    assert e[:, 4].max() < 0.1  # ground range along the road


def test_hot_path_is_single_precision():
    p = LanePipeline(FE, LaneConfig(mounting_height_m=7.0, tracking=False))
    fr = next(_single_car_frames())
    det, inter = p.detect(fr, StageTimer())
    assert p.spectra._iq.dtype == np.complex64
    assert p.spectra.window.dtype == np.float32
    for k in ("power", "threshold", "noise", "angle_spectrum"):
        assert inter[k].dtype == np.float32, k
    for a in (det.range_m, det.radial_speed_mps, det.az_rad, det.snr_db, det.x_m, det.y_m):
        assert a.dtype == np.float32


def test_static_clutter_and_noise_give_no_confirmed_track():
    """Guard-rail posts only: detections, but the tracker confirms nothing (static) in 60 frames. The clutter
    map is off: it removes the posts after its 16-frame initialisation, and the tracker must reject them anyway."""
    sc = Scene(RadarPose(height_m=7.0, tilt_deg=1.5), seed=9)
    from hw_sim.scene import Clutter

    ys = np.arange(10.0, 150.0, 8.0)
    sc.clutter = Clutter(np.stack([np.full(ys.size, -7.6), ys, np.full(ys.size, 0.75)], axis=1), np.full(ys.size, 0.5))
    sim = FrameSimulator(SIMO_BOARD, sc, 9)
    p = build_pipeline("lane", FE, load_config(env={}, overrides={"pipeline.lane.clutter_map_time_s": "0"}))
    n_det = 0
    for k in range(60):
        f = sim.frame(k)
        res = p.process(RawFrame(k, int(round(f.t_s * 1e9)), f.i, f.q, FE, f.truth), StageTimer())
        n_det += len(res.detections)
        assert not [t for t in res.tracks if t.confirmed]
    assert n_det > 60  # the posts are seen


def test_config_section_and_profile_are_registered():
    cfg = load_config(env={}, overrides={"pipeline.lane.cfar_pfa": "1e-5", "track.pdaf.confirm_m": "2"})
    assert cfg.section("pipeline.lane").cfar_pfa == 1e-5
    p = build_pipeline("lane", FE, cfg)
    assert isinstance(p, LanePipeline) and p.tracker.config.confirm_m == 2
    with pytest.raises(Exception, match="calibration"):
        LanePipeline(FE, LaneConfig(calibration_gain=(1.0, 1.0)))


def test_clutter_map_removes_static_posts_and_keeps_the_car():
    """A strong static post at the car's future position: after the map has learned (time constant
    shortened to 1 s for the test) the post gives no detection, the moving car still does."""
    from hw_sim.scene import Clutter

    sc = Scene(RadarPose(height_m=7.0, tilt_deg=1.5), seed=3)
    sc.clutter = Clutter([[-1.75, 80.0, 0.75], [6.0, 40.0, 1.0]], [30.0, 30.0])
    sc.add_target(Target(1, "car", LinearTrajectory((-1.75, 150.0, 0.5), (0.0, -20.0, 0.0)), np.zeros((1, 3)),
                         np.array([10.0]), swerling=0))
    sim = FrameSimulator(SIMO_BOARD, sc, 3)
    with_map = LanePipeline(FE, LaneConfig(tracking=False, clutter_map_time_s=1.0))
    without = LanePipeline(FE, LaneConfig(tracking=False, clutter_map_time_s=0.0))
    timer = StageTimer()
    for k in range(150):
        f = sim.frame(k)
        fr = RawFrame(k, 0, f.i, f.q, FE, f.truth)
        d_map, _ = with_map.detect(fr, timer)
        d_raw, _ = without.detect(fr, timer)
    static = lambda d: int(np.sum(np.abs(d.radial_speed_mps) < 0.3))  # noqa: E731
    assert static(d_raw) == 2 and static(d_map) == 0
    assert np.sum(np.abs(d_map.radial_speed_mps + 20.0) < 0.5) == 1


def test_sparse_cfar_gives_the_same_detections_as_the_full_threshold():
    sparse = LanePipeline(FE, LaneConfig(tracking=False))
    full = LanePipeline(FE, LaneConfig(tracking=False, cfar_full_threshold=True))
    timer = StageTimer()
    for fr in _single_car_frames(180.0, 5.25, 30.0, n=4):
        a, ia = sparse.detect(fr, timer)
        b, ib = full.detect(fr, timer)
        np.testing.assert_array_equal(a.range_m, b.range_m)
        np.testing.assert_array_equal(a.az_rad, b.az_rad)
        assert np.isfinite(ib["threshold"]).all()
        at = np.isfinite(ia["threshold"])
        assert 0 < at.sum() < at.size
        np.testing.assert_allclose(ia["threshold"][at], ib["threshold"][at], rtol=1e-6)


def test_track_aided_pairing_recovers_a_smeared_near_vehicle():
    """A confirmed track at 35 m whose four peaks are each off by up to two bins (a near vehicle's body
    smears its echo): the four-segment pairing finds nothing, the track's own prediction does; with
    peaks in only two segments it does not."""
    from edge.dsp.pairing import pair_beats

    p = build_pipeline("lane", FE, load_config(env={}))
    tr = p.tracker
    x, y, vy = -1.75, 35.0, -25.0
    tr.tracks.append(np.array([[x, y, 0.0, vy]]), np.eye(4)[None] * 0.01, 1.0)
    tr.tracks.confirmed[:] = True
    tr.last_t_ns = 0
    t_ns = 33_000_000
    r, v, f = _predicted_beats(p, x, y, vy, t_ns)
    off = np.array([2.0, 2.0, -1.5, 1.5]) * p.peaks.bin_hz
    freqs = tuple(np.array([f[k] + off[k], f[k] + 40 * p.peaks.bin_hz[k]]) for k in range(4))
    bins = tuple(np.round(fk / p.peaks.bin_hz[k]).astype(np.int64) % p.n_bins for k, fk in enumerate(freqs))
    cfg = p.config
    pairs = pair_beats(freqs, p.pairs.model, min_range_m=cfg.min_range_m, max_range_m=cfg.max_range_m,
                       max_speed_mps=cfg.max_speed_kmh / 3.6, tolerance_hz=p.pairs.tol)
    assert not (np.abs(pairs.range_m - r) < 3).any()
    b, rng, vel, _ = p.pairs.track_aided(freqs, bins, pairs, t_ns, p.feedback())
    assert rng.size == 1 and abs(rng[0] - r) < 1.0 and abs(vel[0] - v) < 1.5  # 2-bin offsets: 1.2 m/s
    assert (b[0] == [bk[0] for bk in bins]).all()
    two = tuple(fk if k < 2 else fk + 50 * p.peaks.bin_hz[k] for k, fk in enumerate(freqs))
    assert p.pairs.track_aided(two, bins, pairs, t_ns, p.feedback())[1].size == 0


def _predicted_beats(p, x: float, y: float, vy: float, t_ns: int):
    """Slant range, radial speed and the four segments' beat frequencies of a track at (x, y) moving at ``vy``
    along the boresight, ``t_ns`` after its last update (the prediction the track-aided pairing makes)."""
    yy = y + vy * t_ns * 1e-9
    dz = p.config.mounting_height_m - p.config.target_height_m
    r = math.sqrt(x * x + yy * yy + dz * dz)
    v = (yy * vy) / r
    return r, v, p.pairs.model.predict(np.array(r), np.array(v))


def _aided_for_tentative(config, y=260.0, vy=-30.0, hits=2, moved=True):
    """A tentative track (``hits`` hits) at ``y`` moving at ``vy`` along the boresight, and peaks exactly at its
    predicted beats in all four segments: the track-aided pairings found for it."""
    from edge.dsp.pairing import pair_beats

    p = build_pipeline("lane", FE, config)
    tr = p.tracker
    x = -5.25
    tr.tracks.append(np.array([[x, y, 0.0, vy]]), np.eye(4)[None] * 0.01, 1.0)
    tr.tracks.hits[:] = hits
    tr.tracks.moved[:] = moved
    tr.last_t_ns = 0
    t_ns = 33_000_000
    r, v, f = _predicted_beats(p, x, y, vy, t_ns)
    freqs = tuple(np.array([f[k] + 0.3 * p.peaks.bin_hz[k]]) for k in range(4))
    bins = tuple(np.round(fk / p.peaks.bin_hz[k]).astype(np.int64) % p.n_bins for k, fk in enumerate(freqs))
    cfg = p.config
    # the four-segment pairing would find it too; the aided search is asked directly (no pairing given)
    pairs = pair_beats(tuple(np.zeros(0) for _ in range(4)), p.pairs.model, min_range_m=cfg.min_range_m,
                       max_range_m=cfg.max_range_m, max_speed_mps=cfg.max_speed_kmh / 3.6, tolerance_hz=p.pairs.tol)
    _, rng, vel, _ = p.pairs.track_aided(freqs, bins, pairs, t_ns, p.feedback())
    return rng, vel, r, v


def test_far_approaching_tentative_tracks_search_for_their_peaks():
    """aided_tentative_min_range_m: a tentative track approaching from 260 m with two hits takes its peaks as a
    confirmed track does; not with one hit, not when it recedes, not at 150 m, not before the tracker found it
    moving, not with the option off."""
    cfg = load_config(env={})
    rng, vel, r, v = _aided_for_tentative(cfg)
    assert rng.size == 1 and abs(rng[0] - r) < 0.5 and abs(vel[0] - v) < 0.5
    assert _aided_for_tentative(cfg, hits=1)[0].size == 0
    assert _aided_for_tentative(cfg, vy=30.0)[0].size == 0
    assert _aided_for_tentative(cfg, y=150.0)[0].size == 0
    assert _aided_for_tentative(cfg, moved=False)[0].size == 0
    off = load_config(env={}, overrides={"pipeline.lane.aided_tentative_min_range_m": "0"})
    assert _aided_for_tentative(off)[0].size == 0
    either = load_config(env={}, overrides={"pipeline.lane.aided_tentative_approaching": "false",
                                            "pipeline.lane.aided_tentative_min_hits": "1"})
    assert _aided_for_tentative(either, vy=30.0, hits=1)[0].size == 1


#: the radar on an overpass above four lanes, two each way (highway4's road)
_FOUR_LANES = """
[radar]
height_m = 7.0
tilt_deg = 1.5
occluded_behind = true
[[lane]]
center_x_m = -5.25
[[lane]]
center_x_m = -1.75
[[lane]]
center_x_m = 1.75
direction = "away"
[[lane]]
center_x_m = 5.25
direction = "away"
"""


def _scenario_frames(tmp_path, text, overrides, seed, n, patch=None):
    """(frame, result) of the lane pipeline, built as radar-edge evaluate builds it, on the first n frames of the
    scenario ``text`` (TOML, written to tmp_path)."""
    from edge.evaluation.lane import _installer_config
    from hw_sim.scenario import load_scenario

    path = tmp_path / "scenario.toml"
    path.write_text(text)
    sc = load_scenario(str(path), patch)
    lc, tc, fc = _installer_config(load_config(env={}, overrides=overrides), sc)
    p = LanePipeline(FE, lc, tc, fc)
    sim = FrameSimulator(SIMO_BOARD, sc.build_scene(seed), seed)
    timer = StageTimer()
    for k in range(n):
        f = sim.frame(k)
        yield f, p.process(RawFrame(k, int(round(f.t_s * 1e9)), f.i, f.q, FE, f.truth), timer)


_TRUCK_LANE1 = """
[scenario]
name = "truck-lane1"
board = "simo"
description = "an approaching truck in lane 1, 100 m out"
duration_s = 6.0
seed = 3
""" + _FOUR_LANES + """[[vehicle]]
id = 1
kind = "truck"
lane = 1
y_m = 100.0
speed_kmh = 70.0
"""


def _against_lane_track_frames(tmp_path, overrides, seed=3, n=180):
    """Frames x confirmed tracks moving towards the radar in the receding lanes (x > 0.3 m), and the detections
    there, while the truck of _TRUCK_LANE1 comes from 100 m to 30 m."""
    n_tracks = n_dets = 0
    # the yaw as installed (not estimated: one truck would not estimate it in 6 s)
    # figures measured on the v1 instrument; the corpus reports the physical defaults
    for _, res in _scenario_frames(tmp_path, _TRUCK_LANE1, {"traffic.estimate_yaw": "false", **overrides}, seed, n,
                                   patch={"physics": {"preset": "v1"}}):
        d = res.detections
        n_dets += int(((d.x_m > 0.3) & (d.radial_speed_mps < -3.0)).sum())
        n_tracks += sum(1 for t in res.tracks if t.confirmed and t.x_m > 0.3 and t.vy_mps < -3.0)
    return n_tracks, n_dets


def test_a_trucks_angle_glint_in_the_other_carriageway_is_dropped(tmp_path):
    """Two scatterers of a truck's body in one range cell in antiphase pull the 4-element Bartlett peak up to a
    beamwidth aside: at 45-60 m the approaching truck can show up 5-6 m beside itself, in a receding lane, at its
    own speed. No track may drive against that lane (a wrong-way alarm). Lim's OS-CFAR (decision 0049) leaves the
    truck's weak body peaks undetected: a few such detections and no track (decision 0050)."""
    on_tracks, on_dets = _against_lane_track_frames(tmp_path, {})
    assert on_tracks == 0 and on_dets <= 10, (on_tracks, on_dets)


_STOPPING_CAR = """
[scenario]
name = "stopping-car"
board = "simo"
description = "a car of lane 1 brakes to a standstill about 90 m out and stands"
duration_s = 20.0
seed = 2
""" + _FOUR_LANES + """[[vehicle]]
id = 1
kind = "car"
lane = 1
y_m = 150.0
speed_kmh = 60.0
stop_at_s = 1.0
decel_mps2 = 3.0
stop_s = 60.0
"""


def _standing_tracked_fraction(tmp_path, overrides, n=600):
    """Fraction of the frames from 10 s on (the car of _STOPPING_CAR has stood since 6.6 s) with a confirmed track
    within 3 m of it; the clutter map's time constant is 2 s, so an unheld map learns the standing car in seconds."""
    held = total = 0
    for f, res in _scenario_frames(tmp_path, _STOPPING_CAR, {"pipeline.lane.clutter_map_time_s": "2", **overrides},
                                   2, n):
        if f.t_s < 10.0:
            continue
        car = f.truth.position_m[0]
        total += 1
        held += any(t.confirmed and math.hypot(t.x_m - car[0], t.y_m - car[1]) < 3.0 for t in res.tracks)
    return held / total


def test_the_clutter_map_hold_keeps_a_stopped_vehicle(tmp_path):
    """A vehicle standing still (engine off: fixed scattering phases) is a static echo: the clutter map learns it
    and its track is lost. pipeline.lane.clutter_map_hold_speed_mps stops the map's update in the range bins of a
    confirmed track that moved and now stands, and the car stays tracked."""
    off = _standing_tracked_fraction(tmp_path, {"pipeline.lane.clutter_map_hold_speed_mps": "0"})
    on = _standing_tracked_fraction(tmp_path, {})  # the default: 1 m/s
    assert off < 0.5 and on > 0.95
