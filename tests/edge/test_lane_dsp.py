"""Known-answer tests of the lane profile's DSP: OS-CFAR, peak interpolation, pairing, Bartlett, geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge.dsp.angle import bartlett, steering_matrix
from edge.dsp.cfar import os_cfar, os_cfar_pfa, os_cfar_scale, reference_index
from edge.dsp.geometry import polar_to_ground
from edge.dsp.pairing import PairingModel, body_extent, nearest_of_clusters, pair_beats
from edge.dsp.peaks import interpolate_peak, local_maxima
from edge.dsp.range_fft import make_window
from hal.waveform import simo_frontend

FE = simo_frontend()
LAM = FE.waveform.wavelength_m


# --- OS-CFAR -------------------------------------------------------------------------------------

@pytest.mark.parametrize("n_ref,rank,pfa", [(32, 24, 1e-6), (16, 12, 1e-3), (48, 36, 1e-4)])
def test_os_cfar_pfa_integral_matches_rohling_closed_form(n_ref, rank, pfa):
    a = os_cfar_scale(pfa, n_ref, rank, n_looks=1)  # closed form inverted
    assert os_cfar_pfa(a, n_ref, rank, n_looks=1) == pytest.approx(pfa, rel=1e-3)


def test_os_cfar_false_alarm_rate_on_noise_matches_design():
    """Non-coherent sum of 4 channels of complex Gaussian noise: measured Pfa within 15 % of the design."""
    rng = np.random.default_rng(11)
    pfa, n_train, guard, n = 1e-3, 16, 2, 1024
    rank = 24
    scale = os_cfar_scale(pfa, 2 * n_train, rank, n_looks=4)
    ref = reference_index(n, n_train, guard)
    trials = 300
    x = rng.standard_normal((trials, 4, n), dtype=np.float32) + 1j * rng.standard_normal((trials, 4, n), dtype=np.float32)
    power = (np.abs(x) ** 2).sum(axis=1).astype(np.float32)  # (trials, n)
    mask, thr, noise = os_cfar(power, ref, rank, scale)
    assert thr.dtype == np.float32 and noise.dtype == np.float32
    measured = mask.mean()
    expected_sd = math.sqrt(pfa / mask.size)
    assert abs(measured - pfa) < max(0.15 * pfa, 4 * expected_sd)
    # a single-look design would be wrong for this noise: it gives a visibly different scale
    assert os_cfar_scale(pfa, 2 * n_train, rank, n_looks=1) > 1.5 * scale


def test_os_cfar_detects_a_tone_and_returns_its_threshold():
    rng = np.random.default_rng(2)
    n = 1024
    p = rng.exponential(1.0, n).astype(np.float32)
    p[300] = 200.0
    ref = reference_index(n, 16, 2)
    mask, thr, _ = os_cfar(p, ref, 24, os_cfar_scale(1e-6, 32, 24))
    assert mask[300] and thr[300] < 200.0
    assert mask.sum() <= 2


def test_interpolate_peak_hann_within_two_hundredths_of_a_bin():
    n = 1024
    w = make_window("hann", n)
    for true_bin in (100.0, 100.25, 100.5, 233.8):
        x = (np.exp(2j * np.pi * true_bin * np.arange(n) / n) * w).astype(np.complex64)
        p = np.abs(np.fft.fft(x)) ** 2
        p = p.astype(np.float32)
        k = int(np.argmax(p))
        assert local_maxima(p, np.ones(n, bool))[k]
        d = interpolate_peak(p, np.array([k]))[0]
        assert abs(k + d - true_bin) < 0.02


# --- pairing ---------------------------------------------------------------------------------------

MODEL = PairingModel.from_waveform(FE.waveform)
KW = dict(min_range_m=5.0, max_range_m=330.0, max_speed_mps=70.0, tolerance_hz=(60.0, 60.0))


def test_pairing_model_matches_lim_equations_9_and_10_without_migration():
    """For a target that does not move between segments the model is Lim's eqs. 5/8/13/14 with our signs."""
    r, v = 123.4, -27.0
    f = MODEL.predict(np.array([r]), np.array([v]))[0]
    # Lim writes f1 = S tau - f_d, f2 = S tau + f_d with his approach-positive f_d; the complex FFT of the
    # down-chirp reads -f2. Range migration (v * t_mid) shifts the range term; remove it to compare.
    seg = FE.waveform.segments
    t_mid = [s.t_start_s + 0.5 * s.n_samples / s.sample_rate_hz for s in seg]
    f_static = f - np.array([2 * s.slope_hz_per_s * v * t / 299_792_458.0 for s, t in zip(seg, t_mid)])
    f1, f2 = f_static[0], -f_static[1]
    dT, dB, fc = 5e-3, 200e6, 24.1e9
    assert (f1 + f2) * 299_792_458.0 * dT / (4 * dB) == pytest.approx(r, abs=1e-6)
    v_lim = (f2 - f1) * 299_792_458.0 / (4 * fc)  # eq. 10 with the typo fixed: approach positive
    assert -v_lim == pytest.approx(v, abs=1e-6)
    f3, f4 = f_static[2], -f_static[3]
    assert (f3 + f4) * 299_792_458.0 * (2 * dT) / (4 * dB) == pytest.approx(r, abs=1e-6)


def test_pairing_rejects_ghosts_of_two_targets_at_swapped_range_and_speed():
    truth = np.array([[100.0, -25.0], [140.0, 12.0]])
    # the two wrong fast pairings are real (R, v) solutions inside the limits: ghosts to reject
    f = MODEL.predict(truth[:, 0], truth[:, 1])  # (2, 4)
    freqs = tuple(f[::-1, k] if k % 2 else f[:, k] for k in range(4))  # shuffle peak order per segment
    out = pair_beats(freqs, MODEL, **KW)
    assert out.n_candidates == 4
    assert out.n_ghosts == 2
    got = np.stack([out.range_m, out.radial_speed_mps], axis=1)
    got = got[np.argsort(got[:, 0])]
    np.testing.assert_allclose(got, truth, atol=1e-3)
    # the swapped world (A's range with B's speed and vice versa) is told apart from the first one
    swapped = np.array([[100.0, 12.0], [140.0, -25.0]])
    fs = MODEL.predict(swapped[:, 0], swapped[:, 1])
    out2 = pair_beats(tuple(fs[:, k] for k in range(4)), MODEL, **KW)
    got2 = np.stack([out2.range_m, out2.radial_speed_mps], axis=1)
    got2 = got2[np.argsort(got2[:, 0])]
    np.testing.assert_allclose(got2, swapped, atol=1e-3)


def test_pairing_needs_both_slow_segments():
    f = MODEL.predict(np.array([80.0]), np.array([-20.0]))[0]
    ok = pair_beats((f[[0]], f[[1]], f[[2]], f[[3]]), MODEL, **KW)
    assert ok.range_m.size == 1
    off = pair_beats((f[[0]], f[[1]], f[[2]] + 500.0, f[[3]]), MODEL, **KW)
    assert off.range_m.size == 0 and off.n_ghosts == 1
    empty = pair_beats((f[[0]], f[[1]], np.zeros(0), f[[3]]), MODEL, **KW)
    assert empty.range_m.size == 0


def test_pairing_refines_range_and_speed_with_noisy_frequencies():
    rng = np.random.default_rng(5)
    r, v = 210.0, 30.0
    f = MODEL.predict(np.array([r]), np.array([v]))[0] + rng.normal(0, 5.0, 4)  # 5 Hz of noise
    out = pair_beats(tuple(np.array([x]) for x in f), MODEL, **KW)
    assert abs(out.range_m[0] - r) < 0.1 and abs(out.radial_speed_mps[0] - v) < 0.1


def test_nearest_of_clusters_keeps_the_near_face():
    r = np.array([100.0, 102.0, 105.0, 100.5, 140.0])
    v = np.array([-20.0, -20.1, -20.0, -20.0, -20.0])
    x = np.array([-1.7, -1.6, -1.8, 1.8, -1.7])  # the 4th is in the next lane, the 5th far behind
    keep = nearest_of_clusters(r, v, x, length_m=7.0, speed_mps=0.6, lateral_m=1.5)
    assert keep.tolist() == [True, False, False, True, True]


def test_body_extent_is_the_farthest_detection_of_the_same_body():
    r = np.array([100.0, 102.0, 105.0, 100.5, 140.0, 103.0])
    v = np.array([-20.0, -20.1, -20.0, -20.0, -20.0, -25.0])  # the 6th: a ghost of another speed
    x = np.array([-1.7, -1.6, -1.8, 1.8, -1.7, -1.7])
    keep = nearest_of_clusters(r, v, x, length_m=7.0, speed_mps=0.6, lateral_m=1.5)
    ext = body_extent(r, v, x, keep, length_m=7.0, speed_mps=0.6, lateral_m=1.5)
    assert ext[[0, 3, 4]].tolist() == [5.0, 0.0, 0.0]  # near face 100 m to 105 m; alone; alone
    assert np.isnan(ext[[1, 2]]).all()


def test_nearest_of_clusters_gives_the_reference_body_extent():
    rng = np.random.default_rng(11)
    for n in (0, 1, 2, 15, 40):
        r = rng.uniform(20.0, 120.0, n).astype(np.float32)
        v = rng.choice([-25.0, -20.0, 22.0], n).astype(np.float32) + rng.normal(0, 0.3, n).astype(np.float32)
        x = rng.choice([-5.25, -1.75, 1.75], n).astype(np.float32) + rng.normal(0, 0.4, n).astype(np.float32)
        kw = dict(length_m=17.0, speed_mps=0.6, lateral_m=1.5)
        keep, ext = nearest_of_clusters(r, v, x, **kw, with_extent=True)
        np.testing.assert_array_equal(keep, nearest_of_clusters(r, v, x, **kw))
        ref = body_extent(r, v, x, keep, **kw)
        np.testing.assert_array_equal(ext[keep], ref[keep])
        assert ext.shape == (n,) and (n < 15 or (ext[keep] > 0).any())


# --- angle and geometry ------------------------------------------------------------------------

def _snapshots(az_deg, n_snap, snr_db, rng, gains=None):
    d = FE.rx_spacing_m
    m = np.arange(4)
    a = np.exp(-2j * np.pi * m * d * math.sin(math.radians(az_deg)) / LAM)
    s = np.exp(2j * np.pi * rng.random(n_snap))[:, None] * a[None, :]
    if gains is not None:
        s = s * gains
    sigma = 10 ** (-snr_db / 20) / math.sqrt(2)
    s = s + sigma * (rng.standard_normal(s.shape) + 1j * rng.standard_normal(s.shape))
    return s.astype(np.complex64)[None]


@pytest.mark.parametrize("az_deg", [-15.0, -4.2, 0.0, 0.8, 12.5])
def test_bartlett_angle_within_a_tenth_of_a_degree(az_deg):
    rng = np.random.default_rng(int(az_deg * 10) + 1000)
    grid = np.radians(np.arange(-19.0, 19.0 + 1e-9, 0.25)).astype(np.float32)
    steer = steering_matrix(4, FE.rx_spacing_m, LAM, grid)
    az, spec = bartlett(_snapshots(az_deg, 4, 30.0, rng), steer, grid)
    assert spec.dtype == np.float32 and az.dtype == np.float32
    assert abs(math.degrees(az[0]) - az_deg) < 0.1


def test_bartlett_needs_the_calibration_vector():
    rng = np.random.default_rng(3)
    gains = np.array([1.0, 0.9 * np.exp(0.5j), 1.1 * np.exp(-0.7j), np.exp(1.2j)])
    grid = np.radians(np.arange(-19.0, 19.0 + 1e-9, 0.25)).astype(np.float32)
    steer = steering_matrix(4, FE.rx_spacing_m, LAM, grid)
    snaps = _snapshots(5.0, 4, 30.0, rng, gains)
    raw, _ = bartlett(snaps, steer, grid)
    cal, _ = bartlett((snaps / gains).astype(np.complex64), steer, grid)
    assert abs(math.degrees(cal[0]) - 5.0) < 0.1
    assert abs(math.degrees(raw[0]) - 5.0) > 0.5


def test_polar_to_ground_reduces_to_eq16_and_handles_height():
    x, y = polar_to_ground(np.array([100.0]), np.array([math.radians(3.0)]), 0.5, 0.5)
    assert x[0] == pytest.approx(100 * math.sin(math.radians(3.0)), abs=1e-4)
    assert y[0] == pytest.approx(100 * math.cos(math.radians(3.0)), abs=1e-3)
    # radar 7 m above a target 0.5 m high, 40 m ahead on the ground, 2 m to the right
    r = math.sqrt(40**2 + 2**2 + 6.5**2)
    x, y = polar_to_ground(np.array([r]), np.array([math.asin(2 / r)]), 7.0, 0.5)
    assert x[0] == pytest.approx(2.0, abs=1e-4) and y[0] == pytest.approx(40.0, abs=1e-3)


def test_bartlett_consensus_drops_a_contaminated_segment():
    """One of four segments also holds a 10 dB stronger vehicle at another angle: the plain Bartlett sum
    follows the intruder, the consensus estimate keeps the target's angle."""
    from edge.dsp.angle import bartlett_consensus

    rng = np.random.default_rng(8)
    grid = np.radians(np.arange(-19.0, 19.0 + 1e-9, 0.25)).astype(np.float32)
    steer = steering_matrix(4, FE.rx_spacing_m, LAM, grid)
    snaps = _snapshots(-2.4, 4, 25.0, rng)
    intruder = 3.0 * _snapshots(6.0, 1, 40.0, rng)[0, 0]
    snaps[0, 2] += intruder
    plain, _ = bartlett(snaps, steer, grid)
    az, _, kept, used = bartlett_consensus(snaps, steer, grid, math.radians(2.0))
    assert abs(math.degrees(plain[0]) + 2.4) > 1.0
    assert abs(math.degrees(az[0]) + 2.4) < 0.15
    assert kept[0].tolist() == [True, True, False, True]


def test_bartlett_consensus_leaves_out_a_look_shared_with_another_vehicle():
    """A car at -5.5 deg whose fourth look also holds a faster vehicle at -2.7 deg (their beats coincide in that
    segment; highway4-traffic seed 7012, car 120 beside car 266): the visitor pulls that look's maximum less than
    the 2 deg outlier limit, so the consensus keeps it and the angle is biased towards the visitor. Told each
    detection's peak bins, the look that both detections use is left out of both and the angles are unbiased; a
    detection of the same speed (another scatterer of the car) or one that is not accepted does not count."""
    from edge.dsp.angle import bartlett_consensus

    grid = np.radians(np.arange(-19.0, 19.0 + 1e-9, 0.25)).astype(np.float32)
    steer = steering_matrix(4, FE.rx_spacing_m, LAM, grid)
    bins = np.array([[100, 220, 140, 300], [130, 260, 170, 301]])  # look 3: one bin apart
    err_plain, err_shared = [], []
    for seed in range(8):
        rng = np.random.default_rng(seed)
        car = _snapshots(-5.5, 4, 25.0, rng)[0]
        other = _snapshots(-2.7, 4, 25.0, rng)[0]
        car[3] += 0.8 * other[3]
        snaps = np.stack([car, other])
        az, _, kept, used = bartlett_consensus(snaps, steer, grid, math.radians(2.0))
        assert kept.all() and (used == kept).all()  # the visitor passes the outlier test
        err_plain.append(abs(math.degrees(az[0]) + 5.5))
        az, _, kept, used = bartlett_consensus(snaps, steer, grid, math.radians(2.0), bins, 1, 3,
                                               speeds=np.array([-18.7, -28.7]), min_speed_diff=1.0)
        assert kept.all()  # still counted as agreeing (the pairing is accepted as before)
        assert used.tolist() == [[True, True, True, False]] * 2
        err_shared.append(abs(math.degrees(az[0]) + 5.5))
        assert abs(math.degrees(az[1]) + 2.7) < 0.2
        # one speed: another scatterer of the same vehicle, no visitor
        _, _, _, used = bartlett_consensus(snaps, steer, grid, math.radians(2.0), bins, 1, 3,
                                           speeds=np.array([-18.7, -18.9]), min_speed_diff=1.0)
        assert used.all()
        # bins two apart: not shared
        far = bins.copy()
        far[1, 3] = 302
        _, _, _, used = bartlett_consensus(snaps, steer, grid, math.radians(2.0), far, 1, 3)
        assert used.all()
    assert np.mean(err_plain) > 0.25
    assert np.mean(err_shared) < 0.1


def test_bartlett_consensus_shares_only_with_accepted_detections_and_keeps_two_looks():
    """A pairing whose looks disagree (a ghost, not accepted) shares no look; a detection that would keep fewer
    than two agreeing looks without its shared ones keeps them all."""
    from edge.dsp.angle import bartlett_consensus

    grid = np.radians(np.arange(-19.0, 19.0 + 1e-9, 0.25)).astype(np.float32)
    steer = steering_matrix(4, FE.rx_spacing_m, LAM, grid)
    rng = np.random.default_rng(3)
    car = _snapshots(-5.5, 4, 25.0, rng)[0]
    ghost = np.stack([_snapshots(a, 1, 25.0, rng)[0, 0] for a in (-15.0, -5.0, 4.0, 12.0)])
    bins = np.array([[100, 220, 140, 300], [100, 221, 400, 500]])
    _, _, kept, used = bartlett_consensus(np.stack([car, ghost]), steer, grid, math.radians(2.0), bins, 1, 3)
    assert kept[0].all() and kept[1].sum() < 3
    assert used[0].all()
    other = _snapshots(-2.7, 4, 25.0, rng)[0]
    bins = np.array([[100, 220, 140, 300], [100, 220, 140, 350]])  # three looks shared
    _, _, kept, used = bartlett_consensus(np.stack([car, other]), steer, grid, math.radians(2.0), bins, 1, 3)
    assert kept.all() and (used == kept).all()


def test_pairing_drops_a_wrong_pairing_accepted_before_the_true_pairs():
    """Two scatterers of one long truck (A, B: 6 m apart, same speed) and slow peaks where the wrong
    fast pairing up(A) x down(B) predicts them (other scatterers of the truck lie there). The wrong
    pairing agrees best with its slow peaks and is accepted first; once A and B are in, it shares two
    peaks with them and is dropped."""
    ra, rb, v = 60.0, 66.0, 25.0
    fa = MODEL.predict(np.array(ra), np.array(v))
    fb = MODEL.predict(np.array(rb), np.array(v))
    det = MODEL.a[0] * MODEL.b[1] - MODEL.a[1] * MODEL.b[0]
    rg = (fa[0] * MODEL.b[1] - fb[1] * MODEL.b[0]) / det
    vg = (MODEL.a[0] * fb[1] - MODEL.a[1] * fa[0]) / det
    fg = MODEL.predict(np.array(rg), np.array(vg))
    slow_off = 0.3 * FE.waveform.segments[2].sample_rate_hz / FE.waveform.n_samples  # A, B: 0.3 bin off
    freqs = (np.array([fa[0], fb[0]]), np.array([fa[1], fb[1]]),
             np.array([fa[2] + slow_off, fb[2] + slow_off, fg[2]]), np.array([fa[3] + slow_off, fb[3] + slow_off, fg[3]]))
    out = pair_beats(freqs, MODEL, **KW)
    got = np.sort(out.range_m)
    assert got.size == 2
    np.testing.assert_allclose(got, [ra, rb], atol=0.2)
    np.testing.assert_allclose(out.radial_speed_mps, v, atol=0.2)


# --- resolving two vehicles in one cell ------------------------------------------------------------

def _two_source_frames(th_deg, powers, n_frames, range_m=100.0, v_mps=-25.0, snr_db=25.0, seed=0):
    """Snapshots (1 detection, 4 looks, 4 rx) of sources whose phases are random per frame (glint) but
    the same in the four looks of a frame (one range-speed cell: coherent within a frame)."""
    from edge.dsp.angle import steering_matrix as sm

    rng = np.random.default_rng(seed)
    a = sm(4, FE.rx_spacing_m, LAM, np.radians(np.asarray(th_deg))) * 2.0  # (k, rx), unit elements
    noise = 10 ** (-snr_db / 20)
    for _ in range(n_frames):
        amp = np.sqrt(powers) * np.exp(2j * np.pi * rng.random(len(powers)))
        x = (amp[:, None] * a).sum(axis=0)
        looks = x[None, :] * np.exp(2j * np.pi * rng.random(4))[:, None]  # common phase per look only
        looks = looks + noise * (rng.standard_normal((4, 4)) + 1j * rng.standard_normal((4, 4))) / math.sqrt(2)
        yield np.array([range_m]), np.array([v_mps]), looks[None].astype(np.complex64)


def _resolver():
    from edge.lane.resolve import CellResolver, ResolverConfig
    from edge.dsp.angle import steering_matrix as sm

    grid = np.arange(-math.radians(19.0), math.radians(19.0) + 1e-9, math.radians(0.25)).astype(np.float32)
    return CellResolver(ResolverConfig(), sm(4, FE.rx_spacing_m, LAM, grid), grid, FE.waveform.frame_period_s,
                        FE.rx_spacing_m / LAM)


def test_resolver_splits_two_cars_side_by_side_and_finds_both_angles():
    """Lanes -5.25 and -1.75 m at 70 m: 2.9 deg apart, a third of the Bartlett beamwidth."""
    th = np.degrees(np.arctan2([-5.25, -1.75], 70.0))
    res = _resolver()
    outs = [res.step(*f) for f in _two_source_frames(th, np.array([1.0, 0.8]), 20, range_m=70.0)]
    split = np.array([s[0][0] for s in outs])
    assert not split[:5].any()  # needs resolve min_frames of history
    assert split[10:].all()
    ang = np.degrees(np.array([a[0] for s, a in outs[10:]]))
    np.testing.assert_allclose(ang.mean(axis=0), np.sort(th), atol=0.5)


def test_resolver_leaves_one_car_alone():
    th = np.array([-2.0, -1.6])  # one car's near face, scatterers 0.5 m apart at 70 m
    res = _resolver()
    split = [res.step(*f)[0][0] for f in _two_source_frames(th, np.array([1.0, 1.0]), 30, range_m=70.0)]
    assert not any(split)


def test_resolver_ignores_static_cells_and_empty_looks():
    th = np.degrees(np.arctan2([-5.25, -1.75], 70.0))
    res = _resolver()
    static = [res.step(r, v * 0.0, x)[0][0] for r, v, x in _two_source_frames(th, np.array([1.0, 1.0]), 20, range_m=70.0)]
    assert not any(static)
    res = _resolver()
    # only the first look holds the second vehicle (its beat coincides in one segment): with that look
    # blanked out (as the angle consensus does) the cell is one vehicle
    for r, v, x in _two_source_frames([-2.0], np.array([1.0]), 20, range_m=70.0, seed=3):
        x = x.copy()
        x[:, 0] = 0.0
        assert not res.step(r, v, x)[0][0]


def test_resolver_marks_a_pair_too_close_to_split_and_not_one_car():
    """A cell with two sources whose second eigenvalue stays under min_eig_ratio is not split but marked
    ``two_sources`` (the tracker's lateral filter then draws no straight line through its angle, which lies between
    the lanes). On the simulated board two cars side by side at 100-120 m give 0.026-0.05, under the 0.05 that
    splits; these synthetic pairs decorrelate faster, so the split test is raised out of reach here instead. One
    car's near face (scatterers 0.5 m apart) is not marked."""
    from edge.lane.resolve import CellResolver, ResolverConfig
    from edge.dsp.angle import steering_matrix as sm

    grid = np.arange(-math.radians(19.0), math.radians(19.0) + 1e-9, math.radians(0.25)).astype(np.float32)

    def resolver():
        return CellResolver(ResolverConfig(min_eig_ratio=0.9), sm(4, FE.rx_spacing_m, LAM, grid), grid,
                            FE.waveform.frame_period_s, FE.rx_spacing_m / LAM)

    def run(res, th, n=30):
        out = []
        for f in _two_source_frames(th, np.array([1.0, 0.8]), n, range_m=115.0):
            split, _ = res.step(*f)
            out.append((bool(split[0]), bool(res.two_sources[0])))
        return np.array(out)

    pair = run(resolver(), np.degrees(np.arctan2([-5.25, -1.75], 115.0)))
    assert not pair[:, 0].any()
    assert not pair[:5, 1].any()  # not before min_frames of history
    assert pair[10:, 1].all()
    one = run(resolver(), np.degrees(np.arctan2([-2.25, -1.75], 115.0)))
    assert not one.any()
