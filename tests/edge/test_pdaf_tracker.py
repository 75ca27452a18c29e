"""The PDAF/JPDA tracker on seeded synthetic detections: accuracy, ids, crossing, recycling, clutter."""

from __future__ import annotations

import numpy as np
import pytest

from edge.config import load_config
from edge.track import IdPool, PdafConfig, PdafTracker
from edge.types import Detections
from tests.edge.trackscene import FRAME_NS, Vehicle, frames, scene_config


def _run(vehicles, n_frames, cfg=None, **kw):
    """Track a scene; return per-vehicle lists of (track_id or -1, position error, speed error) and all ids."""
    tr = PdafTracker(cfg or scene_config())
    hist: dict[int, list[tuple[int, float, float]]] = {}
    ids = set()
    for t_ns, det, truth in frames(vehicles, n_frames, **kw):
        out = tr.step(det, t_ns)
        ids |= {o.track_id for o in out}
        for i, x, y, vx, vy in truth:
            d = [np.hypot(o.x_m - x, o.y_m - y) for o in out]
            if d and min(d) < 3.0:
                o = out[int(np.argmin(d))]
                hist.setdefault(i, []).append((o.track_id, min(d), abs(o.speed_mps - np.hypot(vx, vy))))
            else:
                hist.setdefault(i, []).append((-1, np.nan, np.nan))
    return hist, ids, tr


HIGHWAY = [
    Vehicle(-5.25, 220.0, 0.0, -27.0),
    Vehicle(-1.75, 160.0, 0.0, -22.0),
    Vehicle(1.75, 20.0, 0.0, 30.0),
    Vehicle(5.25, 40.0, 0.0, 25.0),
]


def test_config_section_registered_and_validated():
    cfg = load_config(env={})
    assert cfg["track.pdaf"] == PdafConfig()
    cfg = load_config(env={}, overrides={"track.pdaf.association": "pdaf", "track.pdaf.prob_gate": "0.95"})
    assert cfg["track.pdaf"].association == "pdaf" and cfg["track.pdaf"].prob_gate == 0.95
    with pytest.raises(ValueError):
        load_config(env={}, overrides={"track.pdaf.association": "nearest"})


@pytest.mark.parametrize("association", ["pdaf", "jpda"])
def test_four_lanes_with_clutter_one_id_per_vehicle_and_accurate(association):
    hist, ids, _ = _run(HIGHWAY, 300, scene_config(association=association), seed=11, p_detect=0.9,
                        clutter_per_frame=2.0)
    assert len(ids) == 4, f"expected one confirmed track per vehicle, got ids {sorted(ids)}"
    for i, h in hist.items():
        tid = np.array([a for a, _, _ in h])
        assert np.all(tid[10:] == tid[10]) and tid[10] > 0, f"vehicle {i}: ids {set(tid.tolist())}"
        err = np.array([b for _, b, _ in h[10:]])
        verr = np.array([c for _, _, c in h[10:]])
        # position noise: 0.15 m in range, 0.5 deg in azimuth (1.7 m across at 200 m) -> filtered well below
        assert np.sqrt(np.mean(err**2)) < 0.6, f"vehicle {i}: position rmse {np.sqrt(np.mean(err ** 2)):.2f} m"
        assert np.mean(verr) * 3.6 < 1.0, f"vehicle {i}: speed mae {np.mean(verr) * 3.6:.2f} km/h"


def test_position_only_measurement_also_tracks():
    hist, ids, _ = _run(HIGHWAY[:2], 200, scene_config(use_radial_speed=False), seed=2, p_detect=0.95)
    assert len(ids) == 2
    for h in hist.values():
        assert sum(a > 0 for a, _, _ in h) > 180


def _crossing(dv_mps: float):
    """B overtakes A while both change lanes across each other: their paths cross at the same range."""
    a = Vehicle(-1.75, 60.0, 0.0, 20.0, lane_change=(2.0, 2.0, 3.5))
    b = Vehicle(1.75, 60.0 - dv_mps * 3.0, 0.0, 20.0 + dv_mps, lane_change=(2.0, 2.0, -3.5))
    return [a, b]


@pytest.mark.parametrize("association,dv_mps", [("jpda", 1.5), ("jpda", 5.0), ("pdaf", 5.0)])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_crossing_vehicles_keep_their_ids(association, dv_mps, seed):
    hist, ids, _ = _run(_crossing(dv_mps), 200, scene_config(association=association), seed=seed, p_detect=0.9,
                        clutter_per_frame=1.0, clutter_box=(-10.0, 10.0, 20.0, 150.0))
    before = [{a for a, _, _ in h[30:60]} for h in hist.values()]
    after = [{a for a, _, _ in h[-40:]} for h in hist.values()]
    assert all(len(b) == 1 and -1 not in b for b in before)
    assert before == after, f"ids before {before}, after {after}"
    assert before[0] != before[1]


def test_id_pool_recycles_oldest_released_first():
    pool = IdPool(3)
    assert [pool.acquire() for _ in range(3)] == [1, 2, 3]
    assert pool.acquire() is None
    pool.release(2)
    pool.release(1)
    assert pool.acquire() == 2 and pool.acquire() == 1
    pool.release(7)  # unknown ids are ignored
    assert pool.in_use == 3


def test_ids_are_recycled_and_stay_small():
    # twelve vehicles one after another, at most two in view at a time; ids 1..3 only
    vehicles = [Vehicle(1.75, 20.0, 0.0, 30.0, t_start_s=k * 1.5, t_end_s=k * 1.5 + 2.5) for k in range(12)]
    for k, v in enumerate(vehicles):
        v.y0_m = 20.0 - 30.0 * k * 1.5  # enters at y = 20 m when it starts
    cfg = scene_config(max_track_id=3, delete_after_misses=3)
    tr = PdafTracker(cfg)
    seen = []
    for t_ns, det, _ in frames(vehicles, int(19.0 / 0.033), seed=4, p_detect=0.95):
        out = tr.step(det, t_ns)
        seen.extend(o.track_id for o in out)
        assert len({o.track_id for o in out}) == len(out)
    assert set(seen) == {1, 2, 3}
    # every vehicle got a track: id changes along the sequence count the vehicles
    changes = 1 + sum(1 for a, b in zip(seen, seen[1:]) if a != b)
    assert changes >= 12


def test_static_clutter_never_confirms_but_a_vehicle_that_stops_stays():
    # a guard-rail post and a vehicle that decelerates to a standstill at 5 s
    class Stopping(Vehicle):
        def position(self, t_s):
            tt = min(t_s, 5.0)
            return self.x0_m, self.y0_m + self.vy_mps * tt - 0.5 * (self.vy_mps / 5.0) * tt * tt

    post = Vehicle(8.0, 80.0, 0.0, 0.0)
    car = Stopping(1.75, 30.0, 0.0, 15.0)
    hist, ids, tr = _run([post, car], 300, seed=5, p_detect=0.95)
    assert len(ids) == 1
    assert all(a == -1 for a, _, _ in hist[0])
    tail = {a for a, _, _ in hist[1][-50:]}
    assert len(tail) == 1 and -1 not in tail
    assert len(tr.tracks) == 1  # a detection without radial speed never seeds a track


def test_static_clutter_without_radial_speed_is_held_in_a_tentative_track():
    post = Vehicle(8.0, 80.0, 0.0, 0.0)
    tr = PdafTracker(scene_config(use_radial_speed=False))
    for t_ns, det, _ in frames([post], 100, seed=6, p_detect=0.95):
        out = tr.step(det, t_ns)
    assert out == ()
    assert len(tr.tracks) == 1 and not tr.tracks.confirmed[0]  # absorbs the post's detections, unpublished


def test_sixty_four_simultaneous_tracks():
    rng = np.random.default_rng(9)
    vehicles = []
    for lane_x in (-8.75, -5.25, -1.75, 1.75, 5.25, 8.75, 12.25, -12.25):
        for k in range(8):
            vehicles.append(Vehicle(lane_x, 30.0 + 25.0 * k + rng.uniform(-3, 3), 0.0, rng.uniform(15, 30)))
    cfg = scene_config(range_sigma_m=0.1, azimuth_sigma_deg=0.2)  # the sensor model of this scene
    hist, ids, tr = _run(vehicles, 60, cfg, seed=9, p_detect=0.95, fov_deg=25.0, range_sigma_m=0.1, az_sigma_deg=0.2)
    last = tr.published()
    assert len(last) == 64 and len({o.track_id for o in last}) == 64


def test_empty_frames_and_missed_detections_coast_then_delete():
    cfg = scene_config(delete_after_misses=5)
    tr = PdafTracker(cfg)
    gen = frames([HIGHWAY[2]], 30, seed=1)
    t_ns = 0
    for t_ns, det, _ in gen:
        out = tr.step(det, t_ns)
    assert len(out) == 1
    for k in range(1, 5):
        assert len(tr.step(Detections.empty(), t_ns + k * FRAME_NS)) == 1  # coasting
    assert tr.step(Detections.empty(), t_ns + 5 * FRAME_NS) == ()
    assert tr.ids.in_use == 0


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_extended_vehicles_one_track_each_and_length_estimate(seed):
    """Cars, a van and a 12 m truck giving 1-3 detections spread over their length per frame."""
    vehicles = [
        Vehicle(-5.25, 220.0, 0.0, -27.0, length_m=4.5),
        Vehicle(-1.75, 160.0, 0.0, -22.0, length_m=12.0),
        Vehicle(1.75, 20.0, 0.0, 30.0, length_m=8.0),
        Vehicle(5.25, 40.0, 0.0, 25.0, length_m=4.5),
    ]
    tr = PdafTracker(scene_config())
    ids = set()
    per_vehicle: dict[int, list[int]] = {}
    lengths: dict[int, list[float]] = {}
    # the antenna's +-15 deg field of view (Lim Table 2); tracks are dropped beyond max_azimuth_deg = 20
    for t_ns, det, truth in frames(vehicles, 300, seed=seed, p_detect=0.9, clutter_per_frame=1.0, fov_deg=15.0):
        out = tr.step(det, t_ns)
        ids |= {o.track_id for o in out}
        for i, x, y, _, _ in truth:
            if y < 10.0:  # leaving the beam below the radar (the evaluation's minimum range too)
                continue
            near = [o for o in out if abs(o.x_m - x) < 1.75 and abs(o.y_m - y) < 8.0]  # half a lane
            per_vehicle.setdefault(i, []).append(near[0].track_id if len(near) == 1 else -len(near))
            if len(near) == 1 and near[0].length_m is not None:
                lengths.setdefault(i, []).append(near[0].length_m)
    assert len(ids) == 4, f"ids {sorted(ids)}"
    for i, seq in per_vehicle.items():
        tail = seq[10:]
        assert len(set(tail)) == 1 and tail[0] > 0, f"vehicle {i}: {set(tail)}"
    # the learned length orders the vehicles: truck > van > cars, within a factor of the truth
    med = {i: float(np.median(v[100:])) for i, v in lengths.items()}
    assert med[1] > med[2] > max(med[0], med[3])
    assert 6.0 < med[1] < 14.0 and 5.0 < med[2] < 10.0 and 2.0 < med[3] < 6.0


def test_slant_radial_speed_is_projected_to_the_ground_plane():
    from edge.track.tracker import Measurements

    # radar 6 m above the road, target on boresight 8 m away on the ground: slant range 10 m
    det = Detections(np.float32([10.0]), np.float32([-6.0]), np.float32([0.0]), np.float32([20.0]),
                     np.float32([0.0]), np.float32([8.0]))
    m = Measurements.from_detections(det, use_radial_speed=True)
    assert m.with_radial_speed
    np.testing.assert_allclose(m.z[0], [0.0, 8.0, -6.0 * 10.0 / 8.0], rtol=1e-6)
    nan = Detections(np.float32([10.0]), np.float32([np.nan]), np.float32([0.0]), np.float32([20.0]),
                     np.float32([0.0]), np.float32([8.0]))
    assert not Measurements.from_detections(nan, use_radial_speed=True).with_radial_speed


def test_frames_without_radial_speed_fall_back_to_position_only():
    tr = PdafTracker(scene_config())
    for t_ns, det, _ in frames([HIGHWAY[2]], 60, seed=3):
        det = Detections(det.range_m, np.full_like(det.radial_speed_mps, np.nan), det.az_rad, det.snr_db,
                         det.x_m, det.y_m)
        out = tr.step(det, t_ns)
    assert len(out) == 1 and out[0].vy_mps == pytest.approx(30.0, abs=1.0)


@pytest.mark.parametrize("y0_m,v_mps,length_m", [(60.0, -25.0, 0.0), (60.0, -25.0, 4.5), (25.0, 25.0, 4.5)])
def test_side_by_side_vehicles_get_two_tracks(y0_m, v_mps, length_m):
    """Two vehicles at equal range and speed in adjacent lanes (3.5 m apart), near enough that the
    azimuth noise (0.5 deg) separates them: each keeps its own track."""
    vehicles = [Vehicle(-1.75, y0_m, 0.0, v_mps, length_m=length_m), Vehicle(1.75, y0_m, 0.0, v_mps, length_m=length_m)]
    hist, ids, _ = _run(vehicles, 60, seed=3, p_detect=0.9, clutter_per_frame=1.0)
    assert len(ids) == 2
    own = [{a for a, _, _ in h[12:]} for h in hist.values()]
    assert all(len(o) == 1 and -1 not in o for o in own) and own[0] != own[1], own


def _snr_scene_errors(cfg, seed):
    """Per vehicle (position RMSE, ids) on a scene whose noise follows the SNR law (trackscene noise="snr")."""
    tr = PdafTracker(cfg)
    err: dict[int, list[float]] = {}
    ids: dict[int, set[int]] = {}
    vehicles = [Vehicle(-1.75, 280.0, 0.0, -27.0), Vehicle(5.25, 40.0, 0.0, 25.0)]
    for t_ns, det, truth in frames(vehicles, 300, seed=seed, p_detect=0.8, clutter_per_frame=1.0, noise="snr",
                                   extent_sigma_m=0.47):
        out = tr.step(det, t_ns)
        for i, x, y, _, _ in truth:
            d = [np.hypot(o.x_m - x, o.y_m - y) for o in out]
            if d and min(d) < 3.0:
                err.setdefault(i, []).append(min(d))
                ids.setdefault(i, set()).add(out[int(np.argmin(d))].track_id)
    return {i: (float(np.sqrt(np.mean(np.square(e)))), len(e), ids[i]) for i, e in err.items()}


def test_snr_noise_model_beats_the_constant_one_when_the_noise_follows_the_snr():
    """A car approaching from 280 m and one receding from 40 m, detections whose noise follows the SNR
    (radar equation, Swerling 1; the law of measurement_noise = "snr"): told the law, the tracker's position RMSE
    is lower than with the constant noise model (measured on seeds 1-6: mean 0.164 m vs 0.171 m), one id per
    vehicle, both tracked almost throughout.

    This compares the motion filter, whose state every other stage reads (gates, association, ids), so the
    published lateral position is the motion model's here (``lateral_smoother`` off in both). With the straight-line
    filter on (the default) both publish better lateral positions and the law no longer helps them: seeds 1-6, mean
    0.152 m (snr) vs 0.149 m (constant). The scene's detections scatter symmetrically about the vehicle's point, so
    the extent is symmetric here too (``extent_near_side_factor`` 1; the default 0 assumes a near face with the body
    behind it, as the simulator's vehicles and real ones have it: with 0 on this scene, mean 0.193 m)."""
    snr, const = [], []
    for seed in range(1, 7):
        a = _snr_scene_errors(PdafConfig(lateral_smoother=False, extent_near_side_factor=1.0), seed)
        b = _snr_scene_errors(scene_config(lateral_smoother=False, extent_near_side_factor=1.0), seed)
        for res in (a, b):
            assert sorted(res) == [0, 1]
            for rmse, n, ids in res.values():
                assert n > 280 and len(ids) == 1 and rmse < 0.3
        snr += [a[i][0] for i in a]
        const += [b[i][0] for i in b]
    assert np.mean(snr) < 0.98 * np.mean(const), (np.mean(snr), np.mean(const))


def _first_confirmed(hist: list) -> int:
    """Index of the first in-view frame in which the vehicle had a confirmed track (len(hist): never)."""
    return next((k for k, (tid, _, _) in enumerate(hist) if tid > 0), len(hist))


def test_far_tentative_tracks_kept_while_hit_confirm_weak_approaching_cars_sooner():
    """An approaching car at 370 m detected in 3 frames of 10 (the edge of the coverage): dropping its
    tentative track whenever 5 of 10 can no longer be reached re-seeds it with an empty history, so it
    confirmed after 55 frames on average over 16 seeds (2 never within 120 frames); kept while it holds 2 hits
    of 10 beyond tentative_keep_from_m, after 37 (never later on any seed). Far clutter still never confirms."""
    car = [Vehicle(-3.5, 370.0, 0.0, -28.0)]
    kw = dict(p_detect=0.3, clutter_per_frame=3.0, clutter_box=(-15, 15, 200, 380), noise="snr", snr_100m_db=35.0)
    off, on = [], []
    for seed in range(16):
        for keep, out in ((0.0, off), (250.0, on)):
            hist, ids, _ = _run(car, 120, scene_config(tentative_keep_from_m=keep), seed=seed, **kw)
            out.append(_first_confirmed(hist[0]))
            assert len(ids) <= 1, f"seed {seed}, keep {keep}: a false track confirmed ({sorted(ids)})"
    assert all(a <= b for a, b in zip(on, off)), (on, off)
    assert max(on) < 120 and np.mean(on) < 0.8 * np.mean(off), (on, off)
    _, ids, _ = _run([], 300, scene_config(tentative_keep_from_m=250.0), seed=1, clutter_per_frame=3.0,
                     clutter_box=(-15, 15, 200, 380), noise="snr")
    assert ids == set()


def test_receding_car_from_under_the_overpass_confirms_before_it_enters_the_field_of_view():
    """A car in the outer lane (5.25 m) leaving the overpass is 25-45 deg off boresight in its first metres,
    where the radar still sees it (grating-lobe images put back in their lane, edge.pipelines.lane). Tracks
    deleted beyond 20 deg had it confirmed before it reached the +-15 deg field of view in 3 of 8 seeds;
    beyond 40 deg in 6 of 8."""
    car = [Vehicle(5.25, 5.0, 0.0, 30.0)]
    k15 = int(np.ceil((5.25 / np.tan(np.radians(15.0)) - 5.0) / (30.0 * FRAME_NS * 1e-9)))  # frame at 15 deg
    early = {}
    for az in (20.0, 40.0):
        early[az] = sum(_first_confirmed(_run(car, 60, scene_config(max_azimuth_deg=az), seed=s, p_detect=0.5,
                                              fov_deg=45.0)[0][0]) < k15 for s in range(8))
    assert early[40.0] >= 5 and early[40.0] >= early[20.0] + 2, early


def _receding_from_under_the_deck(cfg: PdafConfig, seed: int) -> float:
    """Mean along-range error (track - rear face) of a 4.5 m car receding at 25 m/s from 8 m, over frames 30-74:
    for 8 frames only its front part is seen (the rear still under the overpass), then its rear face (80 % of
    frames, 25 dB) and now and then a scatterer along its body (40 %, 14 dB)."""
    rng = np.random.default_rng(seed)
    tr = PdafTracker(cfg)
    errs = []
    for k in range(75):
        t = k * 0.033
        x, y = 1.75, 8.0 + 25.0 * t
        pts = []
        if k < 8:
            pts.append((y + rng.uniform(2.0, 4.5), 12.0))
        else:
            if rng.random() < 0.8:
                pts.append((y, 25.0))
            if rng.random() < 0.4:
                pts.append((y + rng.uniform(0.0, 4.5), 14.0))
        r = [np.hypot(x, py) + rng.normal(0, 0.1) for py, _ in pts]
        az = [np.arctan2(x, py) + rng.normal(0, np.radians(0.3)) for py, _ in pts]
        vr = [25.0 * py / np.hypot(x, py) + rng.normal(0, 0.2) for py, _ in pts]
        out = [o for o in tr.step(Detections.from_polar(r, vr, az, [s for _, s in pts]), int(round(t * 1e9)))
               if o.confirmed]
        if k >= 30:
            assert len(out) == 1
            errs.append(out[0].y_m - y)
    return float(np.mean(errs))


def test_a_track_follows_the_near_face_not_the_body_behind_it():
    """``extent_near_side_factor`` (default 0): a detection nearer than the track's prediction is its near face.
    Seeds 1-5: mean along-range error 0.05-0.17 m; with the symmetric extent (1) the track that started on the
    car's front converges on its rear face as 1/n and is still 1.06-1.83 m behind it 1-2.5 s later."""
    for seed in range(1, 6):
        assert abs(_receding_from_under_the_deck(PdafConfig(), seed)) < 0.3
        assert _receding_from_under_the_deck(PdafConfig(extent_near_side_factor=1.0), seed) > 0.8


@pytest.mark.parametrize("v_mps,receding_only,jumps", [
    (-28.0, True, False),  # approaching: the detection 16 m nearer at its speed is the vehicle ahead's ghost
    (-28.0, False, True),  # (re-anchoring for every track)
    (28.0, True, True),    # receding: its track sat on the body, the near face behind it came into view
])
def test_only_receding_tracks_reanchor(v_mps, receding_only, jumps):
    """highway4-traffic seed 7018: car 105's confirmed track missed a frame at 84 m and re-anchored 16.5 m nearer
    onto a pairing ghost at its speed in front of car 104, crossed the line with it and kept car 105's next track
    tentative (``reanchor_receding_only``)."""
    cfg = scene_config(reanchor_receding_only=receding_only)
    tr = PdafTracker(cfg)
    x, y0 = -5.25, 84.0 if v_mps < 0 else 40.0
    dt = FRAME_NS * 1e-9

    def det(y: float) -> Detections:
        r = float(np.hypot(x, y))
        return Detections.from_polar([r], [v_mps * y / r], [np.arctan2(x, y)], [25.0])

    for k in range(20):  # confirmed on clean detections
        out = tr.step(det(y0 + v_mps * k * dt), k * FRAME_NS)
    (before,) = [o for o in out if o.confirmed]
    y_pred = y0 + v_mps * 20 * dt
    out = tr.step(det(y_pred - 16.0), 20 * FRAME_NS)  # its own detection missed; one 16 m nearer, at its speed
    (after,) = [o for o in out if o.track_id == before.track_id]
    assert abs(after.y_m - (y_pred - 16.0)) < 1.0 if jumps else abs(after.y_m - y_pred) < 1.0




@pytest.mark.parametrize("height_above_m,rear_y_m,dv_mps,jumps", [
    (5.0, 6.7, 2.5, True),    # the rear's higher scatterer reads faster: the widened test passes it
    (0.0, 6.7, 2.5, False),   # without the height term it does not
    (5.0, 1.2, 2.5, False),   # under the mounting, short of the range where tracks live
    (5.0, 6.7, -4.0, False),  # 4 m/s slower: a scatterer would have to lie below the road
])
def test_a_receding_track_reanchors_under_the_mounting_despite_the_height_speed_error(height_above_m, rear_y_m,
                                                                                        dv_mps, jumps):
    """A truck leaves from under the mounting front first: its track sits on the front, and the rear that comes
    into view nearer reads a ground radial speed metres per second faster, as a scatterer above the assumed height
    0.5 m over the road does there. With the radar 5 m above that height the re-anchoring's speed test widens by
    that error (as the confirm block's does) and the track moves to the rear; without the height term it does not,
    nor to a detection under the mounting (``min_range_m``), nor to one slower than a scatterer on the road reads."""
    tr = PdafTracker(scene_config(), height_above_target_m=height_above_m, target_height_m=0.5)
    x, v = 0.6, 28.0
    dt = FRAME_NS * 1e-9
    n = 20 if rear_y_m > 5.0 else 12
    y0 = rear_y_m + 15.0 - v * n * dt

    def det(y: float, dv: float = 0.0) -> Detections:
        r = float(np.hypot(x, y))
        return Detections.from_polar([r], [v * y / r + dv], [np.arctan2(x, y)], [25.0])

    for k in range(n):
        out = tr.step(det(y0 + v * k * dt), k * FRAME_NS)
    (before,) = [o for o in out if o.confirmed]
    y_pred = y0 + v * n * dt
    out = tr.step(det(rear_y_m, dv_mps), n * FRAME_NS)
    (after,) = [o for o in out if o.track_id == before.track_id]
    assert abs(after.y_m - rear_y_m) < 1.0 if jumps else abs(after.y_m - y_pred) < 1.0


def _rear_doors(y_m: float, v_mps: float, mount_above_m: float, doors_above_m: float) -> Detections:
    """One detection of a receding truck's rear doors ``doors_above_m`` above the assumed scatterer height, at ground
    distance ``y_m`` in the 1.75 m lane, as the lane pipeline gives it: projected to the ground with the assumed
    height (``mount_above_m`` below the radar), so it lies nearer and its ground radial speed reads faster."""
    x = 1.75
    slant = float(np.sqrt(x * x + y_m * y_m + (mount_above_m - doors_above_m) ** 2))
    rho = float(np.sqrt(slant * slant - mount_above_m**2))
    az = float(np.arctan2(x, y_m))
    return Detections.from_polar([rho], [v_mps * y_m / rho], [az], [25.0])


@pytest.mark.parametrize("y_m,v_mps,seeds", [
    (3.6, 30.0, False),  # 30 m/s 3.6 m out: a scatterer 1 m up reads 10 m/s faster, the seed's sd is 2 m/s
    (8.0, 30.0, True),   # 8 m out: 2.6 m/s, within two sds
    (3.6, 3.0, True),    # a slow vehicle: 1.0 m/s
])
def test_a_detection_seeds_only_where_the_scatterer_height_leaves_its_speed_known(y_m, v_mps, seeds):
    """With the radar 6 m above the assumed scatterer height, a detection near the radar seeds a track only where a
    scatterer one sd higher would read at most two sds of a seed's speed faster; without the height term it always
    seeds."""
    for height, want in ((6.0, seeds), (0.0, True)):
        tr = PdafTracker(scene_config(), height_above_target_m=height, target_height_m=0.5)
        x = 1.75
        r = float(np.hypot(x, y_m))
        tr.step(Detections.from_polar([r], [v_mps * y_m / r], [np.arctan2(x, y_m)], [25.0]), 0)
        assert (len(tr.tracks) == 1) == want, (height, len(tr.tracks))


def test_a_truck_rear_from_under_the_mounting_confirms_at_its_speed():
    """A truck recedes at 30 m/s from under a radar 6.5 m up; its rear doors, 1.7 m above the assumed height, are its
    only echo. Near the radar they read metres per second faster: seeded 4 m out, the track confirms 2.6 m/s fast.
    Seeding only where the height leaves the speed known, it confirms 1.9 m/s fast, two frames later."""
    def first_confirmed_speed(known: bool) -> float:
        tr = PdafTracker(scene_config(), height_above_target_m=6.0, target_height_m=0.5)
        if not known:
            tr.initiator._speed_known = lambda zc: None
        dt = FRAME_NS * 1e-9
        for k in range(60):
            y = 4.0 + 30.0 * k * dt
            for o in tr.step(_rear_doors(y, 30.0, 6.0, 1.7), k * FRAME_NS):
                if o.confirmed:
                    return o.speed_mps
        raise AssertionError("never confirmed")

    known, unknown = first_confirmed_speed(True) - 30.0, first_confirmed_speed(False) - 30.0
    assert abs(known) < 2.0 and unknown - known > 0.5, (known, unknown)
