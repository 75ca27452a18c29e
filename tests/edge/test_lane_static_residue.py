"""Guard-rail ghosts: the images a vehicle leaves of the posts it shadows (the clutter map's echo minus nothing)
pair across posts into moving targets at multiples of 23.9 km/h; ``pipeline.lane.pair_static_residue_db`` drops a
pairing whose four peaks are no stronger than the clutter map's echo in their bins, and keeps vehicles."""

from __future__ import annotations

import dataclasses

import numpy as np

from edge.lane.clutter import ClutterMap
from edge.lane.pairs import PairStage
from edge.lane.records import Feedback, Peaks, Spectra
from edge.pipelines.lane import LaneConfig
from hw_sim.boards import SIMO_BOARD

FE = SIMO_BOARD.frontend
WF = FE.waveform
N = WF.n_samples
BIN_HZ = np.array([s.sample_rate_hz / N for s in WF.segments])
POST_POWER = 1e-3  # channel power of a post's echo in its bin (the map's echo, and the image it leaves)
FLOOR = np.full(4, 1e-7, np.float32)  # the segments' noise floor


def _stage(db: float) -> PairStage:
    cfg = dataclasses.replace(LaneConfig(), pair_static_residue_db=db)
    st = PairStage(FE, cfg, BIN_HZ)
    st.clutter = ClutterMap(cfg, tuple(FE.frame_shape), WF.frame_period_s, (st.model.a / BIN_HZ).tolist())
    return st


def _posts() -> np.ndarray:
    """Slant ranges (m) of guard-rail posts 7.6 m beside the road every 4 m from 40 to 200 m, radar 7 m up."""
    y = np.arange(40.0, 200.0, 4.0)
    return np.sqrt(y * y + 7.6 ** 2 + 7.0 ** 2)


def _scene(st: PairStage, seed: int, vehicles: list[tuple[float, float, float]]):
    """Peaks and spectra of one frame: the map holds every post; a random half of the posts is shadowed in each
    segment (their images are peaks as strong as the map's echo); ``vehicles`` (range m, speed m/s, channel power)
    add peaks. Returns (peaks, spectra)."""
    rng = np.random.default_rng(seed)
    r = _posts()
    f_posts = st.model.predict(r, np.zeros_like(r))  # (posts, 4)
    bg = st.clutter.background
    power = np.zeros((4, N), np.float32)
    freqs, bins = [], []
    for k in range(4):
        b_post = np.rint(f_posts[:, k] / BIN_HZ[k]).astype(np.int64) % N
        bg[:, k, b_post] = np.sqrt(POST_POWER / bg.shape[0])  # the map's echo of every post
        shadowed = rng.random(r.size) < 0.5
        power[k, b_post[shadowed]] = POST_POWER  # the image: the echo that is missing
        fk, bk = list(f_posts[shadowed, k]), list(b_post[shadowed])
        for rv, vv, pv in vehicles:
            f = float(st.model.predict(np.array([rv]), np.array([vv]))[0, k])
            b = int(np.rint(f / BIN_HZ[k])) % N
            power[k, b] += pv
            fk.append(f)
            bk.append(b)
        order = np.argsort(fk)
        freqs.append(np.asarray(fk, np.float64)[order])
        bins.append(np.asarray(bk, np.int64)[order])
    peaks = Peaks(tuple(freqs), tuple(bins), np.zeros((4, N), np.float32), np.zeros((4, N), np.float32), FLOOR)
    return peaks, Spectra(np.zeros(tuple(FE.frame_shape), np.complex64), power, 0)


def _moving_kmh(pairs) -> np.ndarray:
    v = np.abs(pairs.radial_speed_mps.astype(np.float64)) * 3.6
    return v[v > 1.0]


def test_images_of_shadowed_posts_pair_into_ghosts_at_multiples_of_the_post_spacing_speed():
    # an up-chirp image of one post and a down-chirp image of another Delta R away pair at k Delta R lambda / 2c:
    # posts 8 m apart give 23.9 km/h in all four segments
    ghosts = []
    for seed in range(5):
        peaks, spectra = _scene(_stage(0.0), seed, [])
        ghosts.extend(_moving_kmh(_stage(0.0)(peaks, 0, Feedback.none(), spectra)).tolist())
    assert len(ghosts) >= 10
    step = 23.9
    assert np.all(np.abs(np.asarray(ghosts) / step - np.round(np.asarray(ghosts) / step)) * step < 0.8)


def test_static_residue_pairings_are_dropped_and_vehicles_kept():
    car_far = (151.3, -27.0, 50 * POST_POWER)  # a car in bins the map holds no echo in
    n_ghosts = 0
    for seed in range(5):
        st = _stage(3.0)
        peaks, spectra = _scene(st, seed, [car_far])
        kept = st(peaks, 0, Feedback.none(), spectra)
        off = _stage(0.0)
        off.clutter = st.clutter
        all_pairs = off(peaks, 0, Feedback.none(), spectra)
        n_ghosts += _moving_kmh(all_pairs).size - 1
        # only the car is left, at its range and speed
        assert kept.range_m.size == 1
        assert abs(float(kept.range_m[0]) - car_far[0]) < 0.5
        assert abs(float(kept.radial_speed_mps[0]) - car_far[1]) < 0.2
    assert n_ghosts >= 10


def test_a_vehicle_over_the_posts_in_every_segment_is_kept_when_stronger_than_their_echo():
    st = _stage(3.0)
    # put a static reflector's echo in the map at a car's four bins, then the car, 10 dB stronger, on top
    car = (120.0, -25.0)
    fc = st.model.predict(np.array([car[0]]), np.array([car[1]]))[0]
    bins = np.rint(fc / BIN_HZ).astype(np.int64) % N
    bg = st.clutter.background
    power = np.zeros((4, N), np.float32)
    for k in range(4):
        bg[:, k, bins[k]] = np.sqrt(POST_POWER / bg.shape[0])
    spectra = Spectra(np.zeros(tuple(FE.frame_shape), np.complex64), power, 0)
    peaks = Peaks(tuple(np.array([fc[k]]) for k in range(4)), tuple(np.array([bins[k]]) for k in range(4)),
                  np.zeros((4, N), np.float32), np.zeros((4, N), np.float32), FLOOR)
    power[np.arange(4), bins] = 10 * POST_POWER
    assert st(peaks, 0, Feedback.none(), spectra).range_m.size == 1
    # as weak as the echo it sits on in every segment: taken for the echo's residue
    power[np.arange(4), bins] = POST_POWER
    assert st(peaks, 0, Feedback.none(), spectra).range_m.size == 0
    # ... unless one segment is clearly stronger
    power[2, bins[2]] = 10 * POST_POWER
    assert st(peaks, 0, Feedback.none(), spectra).range_m.size == 1
    # and where the map holds nothing above the noise floor nothing is residue
    power[np.arange(4), bins] = POST_POWER
    bg[...] = 0
    assert st(peaks, 0, Feedback.none(), spectra).range_m.size == 1
