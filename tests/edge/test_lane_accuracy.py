"""Lane profile accuracy fixes (issue 3): each test failed before its fix."""

from __future__ import annotations

import numpy as np

from edge.pipeline import StageTimer
from edge.pipelines.lane import LaneConfig, LanePipeline
from hal.frame import RawFrame
from hw_sim import SIMO_BOARD, FrameSimulator, RadarPose, Scene
from hw_sim.physics import parse_physics

FE = SIMO_BOARD.frontend
#: the v1 instrument (white glint, near-face bodies), for tests whose figures were measured on it
V1 = parse_physics({"preset": "v1"})


def _frames(scene: Scene, seed: int, n: int):
    sim = FrameSimulator(SIMO_BOARD, scene, seed)
    for k in range(n):
        f = sim.frame(k)
        yield RawFrame(k, int(round(f.t_s * 1e9)), f.i, f.q, FE, f.truth)


def test_clutter_map_removes_the_tx_leakage_within_a_second():
    """The TX->RX leakage sits at DC some 80 dB over the noise. The running-mean map alone leaves
    (warm-up - 1)/(n + warm-up) of it for minutes, masking the beats of vehicles 10-35 m away (their beat
    crosses zero in one segment); the median of the first frames removes it exactly."""
    scene = Scene(RadarPose(height_m=7.0, tilt_deg=1.5), seed=5)  # nothing but leakage and noise
    p = LanePipeline(FE, LaneConfig(mounting_height_m=7.0, tracking=False))
    timer = StageTimer()
    for fr in _frames(scene, 5, 30):
        _, inter = p.detect(fr, timer)
    power = inter["power"]  # (segment, bin)
    floor = np.median(power, axis=1)
    near_dc = np.concatenate([power[:, -20:], power[:, :21]], axis=1)  # +-20 bins around DC
    excess_db = 10.0 * np.log10(near_dc.max(axis=1) / floor)
    assert (excess_db < 15.0).all(), excess_db  # noise peaks only (before: 60-80 dB of leakage)
    off = LanePipeline(FE, LaneConfig(mounting_height_m=7.0, tracking=False, clutter_map_init_frames=0))
    for fr in _frames(scene, 5, 30):
        _, inter = off.detect(fr, timer)
    assert 10.0 * np.log10(inter["power"][:, :3].max() / np.median(inter["power"])) > 40.0  # the leakage is there


def _approaching_car_track_fraction(seed: int, config=None) -> float:
    """Fraction of frames in which an approaching car (extended body, glint) between 300 and 270 m has a
    confirmed track within 3 m + its length of its near face."""
    from edge.config import load_config
    from hw_sim.vehicles import RoadTrajectory, make_vehicle

    cfg = config or load_config(env={})
    # figure measured on the v1 instrument; the corpus reports the physical defaults
    scene = Scene(RadarPose(height_m=7.0, tilt_deg=1.5), seed=seed, physics=V1)
    v = 30.0
    traj = RoadTrajectory(-1.75, 372.0, -1, (0.0,), (v,))
    car = make_vehicle(1, "car", traj, lane=1, rng=np.random.default_rng(seed), length_m=4.5, physics=V1)
    scene.add_target(car)
    p = LanePipeline(FE, cfg.section("pipeline.lane"), cfg.section("track.pdaf"), cfg.section("traffic"))
    timer = StageTimer()
    hit = n = 0
    for fr in _frames(scene, seed, int(102.0 / v / FE.waveform.frame_period_s)):
        res = p.process(fr, timer)
        ref = car.near_face_point(fr.t_ns * 1e-9)
        if not 270.0 <= ref[1] <= 300.0:
            continue
        n += 1
        hit += any(t.confirmed and np.hypot(t.x_m - ref[0], t.y_m - ref[1]) <= 3.0 + car.length_m for t in p.tracker.published())
    return hit / n


def test_an_approaching_car_is_tracked_when_it_reaches_300_m():
    """A car at 300 m is detected in only about half the frames (Swerling-like glint, 12 dB mean SNR).
    Its track must be confirmed before it gets there: tracks (and detections) live beyond the design range,
    and a tentative track may take 5 hits in 10 frames. Before: tracks beyond 320 m were deleted and 5 of 7
    were needed, so the car was often still unconfirmed well inside 300 m."""
    fractions = [_approaching_car_track_fraction(seed) for seed in (1, 2, 3)]
    assert min(fractions) >= 0.95, fractions


def _truck_run(seed: int, direction: int, y0_m: float, y_lo: float, y_hi: float, config=None):
    """A 16 m truck (traffic body: near face, sides, far face; glint) in lane 1 (approaching, direction -1) or
    lane 2 (receding, +1). Returns (frames with the near face in [y_lo, y_hi], frames whose nearest confirmed
    track lies within 2.5 m of the near face, frames with more than one confirmed track on the truck)."""
    from edge.config import load_config
    from hw_sim.vehicles import RoadTrajectory, make_vehicle

    cfg = config or load_config(env={})
    scene = Scene(RadarPose(height_m=7.0, tilt_deg=1.5), seed=seed)
    v = 25.0
    x = -1.75 if direction < 0 else 1.75
    truck = make_vehicle(1, "truck", RoadTrajectory(x, y0_m, direction, (0.0,), (v,)), lane=1,
                         rng=np.random.default_rng(seed), length_m=16.0)
    scene.add_target(truck)
    p = LanePipeline(FE, cfg.section("pipeline.lane"), cfg.section("track.pdaf"), cfg.section("traffic"))
    timer = StageTimer()
    n = on_face = doubled = 0
    ref0 = truck.near_face_point(0.0)[1]
    n_frames = int((y_hi - ref0 if direction > 0 else ref0 - y_lo) / v / FE.waveform.frame_period_s) + 1
    for fr in _frames(scene, seed, n_frames):
        p.process(fr, timer)
        ref = truck.near_face_point(fr.t_ns * 1e-9)
        if not y_lo <= ref[1] <= y_hi:
            continue
        n += 1
        tracks = [t for t in p.tracker.published() if t.confirmed]
        d = np.array([np.hypot(t.x_m - ref[0], t.y_m - ref[1]) for t in tracks])
        on_face += bool(d.size and d.min() <= 2.5)
        # "on the truck": half a lane across, from just before the near face to the far end of the body (which
        # lies farther from the radar whichever way the truck drives)
        on_truck = [t for t in tracks if abs(t.x_m - ref[0]) < 1.75 and -3.0 <= t.y_m - ref[1] <= 19.0]
        doubled += len(on_truck) > 1
    return n, on_face, doubled


def test_an_approaching_truck_is_one_track_on_its_near_face():
    """Before: detections of the rear half of a 16 m truck (more than 7 m behind the near face) survived the
    clustering and seeded a second track on the truck's body."""
    for seed in (1, 2, 3):
        n, on_face, doubled = _truck_run(seed, -1, 180.0, 40.0, 150.0)
        assert on_face >= 0.95 * n, (seed, n, on_face)
        assert doubled <= 0.02 * n, (seed, n, doubled)


def test_a_receding_truck_from_under_the_overpass_is_tracked_on_its_near_face():
    """A truck coming out from under the overpass shows its front first: the track is born on the front, 16 m
    ahead of the near face (its rear, the reference point), and the near face could not seed a track of its
    own in that track's same-vehicle box. Before (7 m / 0.6 m/s clustering, 5 of 7): on seed 1 the track stayed
    16 m ahead of the near face. (A second track on the body ghosts still appears in some frames: not asserted.)"""
    for seed in (1, 2, 3):
        n, on_face, _ = _truck_run(seed, 1, -40.0, 20.0, 70.0)
        assert on_face >= 0.8 * n, (seed, n, on_face)


def _mirrored_detections(config, seed: int) -> tuple[int, int]:
    """A car receding in the outer lane (x = 5.25 m) from under the overpass to 30 m: (detections of it on the
    correct side, detections mirrored into the approaching lanes) while its ground range is 8-30 m."""
    from hw_sim.vehicles import RoadTrajectory, make_vehicle

    scene = Scene(RadarPose(height_m=7.0, tilt_deg=1.5, occluded_behind=True), seed=seed)
    car = make_vehicle(1, "car", RoadTrajectory(5.25, -2.0, 1, (0.0,), (25.0,)), lane=3,
                       rng=np.random.default_rng(seed), length_m=4.5)
    scene.add_target(car)
    p = LanePipeline(FE, config.section("pipeline.lane"), config.section("track.pdaf"), config.section("traffic"))
    timer = StageTimer()
    right = mirrored = 0
    for fr in _frames(scene, seed, 50):
        res = p.process(fr, timer)
        ref = car.near_face_point(fr.t_ns * 1e-9)
        if not 8.0 <= ref[1] <= 30.0:
            continue
        d = res.detections
        moving = d.radial_speed_mps > 1.0
        right += int(np.sum(moving & (np.abs(d.x_m - ref[0]) < 1.75) & (np.abs(d.y_m - ref[1]) < 6.0)))
        mirrored += int(np.sum(moving & (d.x_m < 0.0)))
    return right, mirrored


def test_grating_lobe_images_of_near_outer_lane_vehicles_are_put_back_in_their_lane():
    """At 12 m the car is 25 deg off boresight, beyond the +-19.5 deg an array with d = 1.5 lambda can tell
    apart: without the lane check its detections appear at sin(az) - 2/3, across the road in an approaching
    lane, receding (false tracks driving the wrong way next to the radar)."""
    from edge.config import load_config

    on = load_config(env={})
    off = load_config(env={}, overrides={"pipeline.lane.unalias_by_lane": "false"})
    for seed in (1, 3):
        right_off, mirrored_off = _mirrored_detections(off, seed)
        right_on, mirrored_on = _mirrored_detections(on, seed)
        assert mirrored_off >= 4, (seed, mirrored_off)  # the images exist
        assert mirrored_on == 0, (seed, mirrored_on)
        assert right_on > right_off, (seed, right_on, right_off)  # ... and are put where the car is


def test_body_glint_beside_a_truck_does_not_confirm():
    """The two sides of a truck at one range glint its body's echo up to a lane width beside it, a few metres
    behind its near face and at exactly its speed (seen on highway4-traffic seed 2: a second, false track in the
    next lane). A detection stream glued to a confirmed vehicle like that stays tentative, near the radar and far
    out (at 150 m as well); a car side by side at the same range, or behind at another speed, still confirms."""
    from edge.track import PdafTracker
    from tests.edge.trackscene import Vehicle, frames, scene_config

    def ids_for(second: Vehicle, seed: int, y0: float = 95.0) -> int:
        tr = PdafTracker(scene_config())
        ids = set()
        for t_ns, det, _ in frames([Vehicle(-5.25, y0, 0.0, -25.0), second], 80, seed=seed, p_detect=0.9,
                                   az_sigma_deg=0.3):
            ids |= {o.track_id for o in tr.step(det, t_ns) if o.confirmed}
        return len(ids)

    for seed in (1, 2, 3):  # the glint appears once the truck is near (its track exists)
        assert ids_for(Vehicle(-2.25, 99.5, 0.0, -25.0, t_start_s=1.0), seed) == 1, seed  # 3 m across, 4.5 m behind
        # farther out (the truck from 150 to 84 m): 2.5 m across, 4.5 m behind
        assert ids_for(Vehicle(-2.75, 154.5, 0.0, -25.0, t_start_s=1.0), seed, 150.0) == 1, seed
        assert ids_for(Vehicle(-1.75, 95.0, 0.0, -25.0, t_start_s=1.0), seed) == 2, seed  # side by side
        assert ids_for(Vehicle(-1.75, 105.0, 0.0, -23.0, t_start_s=1.0), seed) == 2, seed  # next lane, 2 m/s slower


def _adjacent_pair_track_fractions(seed: int, config=None) -> tuple[float, float]:
    """Two cars approaching in adjacent lanes, the outer one 6 m behind and 3.2 m/s faster (it catches up with
    its neighbour between 300 and 240 m, as on highway4-traffic seed 5, cars 50 and 222). Returns per car the
    fraction of frames with its near face between 240 and 300 m in which a confirmed track of its own (one to
    one, as the evaluator: within 3 m + its length) follows it."""
    from scipy.optimize import linear_sum_assignment

    from edge.config import load_config
    from hw_sim.vehicles import RoadTrajectory, make_vehicle

    cfg = config or load_config(env={})
    # figure measured on the v1 instrument; the corpus reports the physical defaults
    scene = Scene(RadarPose(height_m=7.0, tilt_deg=1.5), seed=seed, physics=V1)
    rng = np.random.default_rng(seed)
    v = 27.0
    cars = [make_vehicle(1, "car", RoadTrajectory(-1.75, 372.0, -1, (0.0,), (v,)), lane=1, rng=rng, length_m=4.5,
                         physics=V1),
            make_vehicle(2, "car", RoadTrajectory(-5.25, 378.0, -1, (0.0,), (v + 3.2,)), lane=0, rng=rng,
                         length_m=4.5, physics=V1)]
    for car in cars:
        scene.add_target(car)
    p = LanePipeline(FE, cfg.section("pipeline.lane"), cfg.section("track.pdaf"), cfg.section("traffic"))
    timer = StageTimer()
    hit, n = np.zeros(2), np.zeros(2)
    for fr in _frames(scene, seed, int(150.0 / v / FE.waveform.frame_period_s)):
        p.process(fr, timer)
        refs = np.array([car.near_face_point(fr.t_ns * 1e-9)[:2] for car in cars])
        inside = (refs[:, 1] >= 240.0) & (refs[:, 1] <= 300.0)
        n += inside
        tracks = np.array([[t.x_m, t.y_m] for t in p.tracker.published() if t.confirmed]).reshape(-1, 2)
        if not inside.any() or not len(tracks):
            continue
        dist = np.linalg.norm(refs[:, None, :] - tracks[None, :, :], axis=2)
        cost = np.where(dist <= 3.0 + 4.5, dist, 1e6)
        r, c = linear_sum_assignment(cost)
        for k in r[cost[r, c] < 1e6]:
            hit[k] += inside[k]
    return float(hit[0] / n[0]), float(hit[1] / n[1])


def test_a_far_car_beside_its_neighbour_gets_a_track_of_its_own():
    """Far away the outer car crosses the detection threshold in all four segments in a third to a half of its
    frames (glint, the outer lane's weaker echo; where its slow-segment beat falls within two bins of its
    neighbour's, the neighbour's stronger peak takes it), so its tentative tracks missed 5 of 10 and expired
    while the neighbour's confirmed track was the only one. Far approaching tentative tracks now search for
    their own peaks as confirmed ones do (``aided_tentative_min_range_m``). Seeds 1, 2, 3 before (neighbour,
    outer car): 0.13/0.88, 1.0/0.47, 1.0/0.57 of their frames; now 1.0 each."""
    fractions = [_adjacent_pair_track_fractions(seed) for seed in (1, 2, 3)]
    assert min(min(f) for f in fractions) >= 0.9, fractions
