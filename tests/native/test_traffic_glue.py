"""The traffic layer's per-frame glue in its kernel (edge/native/_traffic.pyx, decision 0035) against the numpy /
Python forms it replaces, bit for bit: the confirmed tracks' table with its gathers (``track_kin``), the yaw sums from
that table (``yaw_add_kin``), the start-up estimate in one call (``yaw_startup``) and the published copies of the
tracks (``monitor_pass``), on random inputs and on the lane pipeline's own frames."""

from __future__ import annotations

import dataclasses
import math
import struct
from types import SimpleNamespace

import numpy as np
import pytest

from edge.traffic import TrafficConfig, TrafficMonitor
from edge.traffic.lanes import YawEstimator
from edge.traffic.monitor import _with
from edge.types import TrackState, track_state
from tests.native.conftest import require_kernel
from tests.native.test_traffic import _random_frames, _random_scene, _traffic_inputs


def _bits(v):
    """A value with its floats as their bits (NaN, -0.0), recursively through lists and tuples."""
    if isinstance(v, float):
        return ("f", struct.pack("<d", v))
    if isinstance(v, (list, tuple)):
        return (type(v).__name__, tuple(_bits(x) for x in v))
    return (type(v).__name__, v)


def _track_items(t):
    """A published track as its type and instance dict items in order, floats by their bits."""
    return type(t), [(k, _bits(v)) for k, v in vars(t).items()]


def _random_tracks(rng, m: int):
    """``m`` tracks of mixed make: the tracker's fast constructor, the dataclass's own, a subclass; confirmed or not,
    id 0 and recycled ids."""

    class Sub(TrackState):
        pass

    out = []
    for _ in range(m):
        args = (int(rng.integers(0, 40)), rng.normal(0, 6), rng.uniform(5, 250), rng.normal(0, 1), rng.normal(0, 25),
                rng.uniform(5, 250), rng.normal(0, 25), rng.normal(0, 0.1), int(rng.integers(1, 500)),
                int(rng.integers(1, 500)), bool(rng.random() < 0.7))
        kind = rng.integers(0, 3)
        if kind == 0:
            out.append(track_state(*args, None))
        elif kind == 1:
            out.append(TrackState(*args))
        else:
            out.append(Sub(*args))
    return tuple(out)


@pytest.mark.parametrize("seed", range(6))
def test_track_table_and_its_gathers_equal_the_numpy_form(seed):
    k = require_kernel("_traffic")
    rng = np.random.default_rng(seed)
    for trial in range(60):
        m = int(rng.integers(0, 30))
        tracks = _random_tracks(rng, m)
        yaw_x = rng.normal(0, 5, m)
        ext = np.where(rng.random(m) < 0.3, np.nan, rng.uniform(0, 20, m))
        conf, sel, kin, ids, id_list, yx, ex = k.track_kin(tracks, yaw_x, ext, TrackState)
        want_sel = [j for j, t in enumerate(tracks) if t.confirmed and t.track_id > 0]
        want_conf = [tracks[j] for j in want_sel]
        want_kin = np.array([(t.track_id, t.age_frames, t.x_m, t.y_m, t.vx_mps, t.vy_mps) for t in want_conf],
                            dtype=np.float64).reshape(-1, 6)
        assert conf == want_conf and all(a is b for a, b in zip(conf, want_conf))
        assert sel.dtype == np.int64 and sel.tolist() == want_sel
        assert kin.dtype == np.float64 and kin.flags.c_contiguous
        assert kin.tobytes() == want_kin.tobytes()
        assert ids.dtype == np.int64 and ids.tolist() == id_list == [t.track_id for t in want_conf]
        for got, src in ((yx, yaw_x), (ex, ext)):
            want = np.asarray(src, dtype=np.float64)[np.asarray(want_sel, dtype=np.int64)]
            assert got.dtype == np.float64 and got.flags.c_contiguous and got.tobytes() == want.tobytes()
        # inputs the kernel does not gather: left to the caller's numpy form
        assert k.track_kin(tracks, yaw_x.astype(np.float32), list(ext), TrackState)[5:] == (None, None)
        assert k.track_kin(tracks, yaw_x[:-1] if m else np.zeros(1), None, TrackState)[5:] == (None, None)
        rev = k.track_kin(tracks, yaw_x[::-1], ext.reshape(-1, 1), TrackState)  # (strided: gathered; 2-D: not)
        assert rev[5].tobytes() == yaw_x[::-1][np.asarray(want_sel, dtype=np.int64)].tobytes() and rev[6] is None
        # without the class (or for other classes) the fields are read through getattr: the same table
        assert k.track_kin(tracks, None, None, None)[2].tobytes() == want_kin.tobytes()


def test_track_table_reads_duck_typed_tracks_through_getattr():
    k = require_kernel("_traffic")
    t = SimpleNamespace(track_id=3, confirmed=True, age_frames=7, x_m=1.5, y_m=20.0, vx_mps=0.25, vy_mps=-9.0)
    conf, sel, kin, ids, id_list, yx, ex = k.track_kin((t,), None, None, TrackState)
    assert conf == [t] and kin.tolist() == [[3.0, 7.0, 1.5, 20.0, 0.25, -9.0]] and id_list == [3]


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_yaw_sums_from_the_table_equal_the_array_form_and_the_reference(seed):
    """``add_table`` (``yaw_add_kin``) against ``add`` with the kernel (``yaw_add``) and the Python reference: the same
    sums, running flags, order and votes, frame for frame, with the table's x column and with another x."""
    require_kernel("_traffic")
    cfg = TrafficConfig(yaw_min_tracks=8, yaw_window_tracks=12, yaw_live_min_length_m=5.0)
    tab, arr, ref = YawEstimator(cfg), YawEstimator(cfg), YawEstimator(cfg, kernels=False)
    rng = np.random.default_rng(seed)
    n_votes = 0
    for f, (ids, age, x, y) in enumerate(_random_frames(seed, 400)):
        kin = np.column_stack([ids.astype(np.float64), age.astype(np.float64), x, y, np.zeros_like(x),
                               np.zeros_like(x)]).reshape(-1, 6)
        xo = x + rng.normal(0, 0.2, x.size) if f % 2 else None
        tab.add_table(kin, xo)
        arr.add(ids, age, x if xo is None else xo, y)
        ref.add(ids, age, x if xo is None else xo, y)
        assert tab._acc.tobytes() == arr._acc.tobytes() and tab._live.tobytes() == arr._live.tobytes()
        assert tab._seq.tobytes() == arr._seq.tobytes() and tab._next_seq == arr._next_seq
        assert tab._n_live == arr._n_live
        assert _bits(list(tab._votes)) == _bits(list(arr._votes)) == _bits(list(ref._votes))
        n_votes = tab._n_voted
    assert n_votes > 10


def _startup_reference(est: YawEstimator):
    """The start-up estimate of the kernel path before ``yaw_startup``: live_votes_weighted, then weighted_median or
    the numpy form."""
    votes_l = list(est._votes)
    live, w = est.live_votes_weighted()
    if len(votes_l) + live.size < est.cfg.yaw_min_tracks:
        return None, None
    return est._estimate_startup(votes_l, live, w), est._stderr


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_start_up_estimate_in_one_call_equals_its_parts_and_the_reference(seed):
    """``yaw_startup`` against ``live_votes_weighted`` + ``weighted_median`` (or the numpy form beyond 64 votes) of the
    same estimator and against the Python reference: the estimate and its standard error bit for bit, ``None``
    before there are enough votes."""
    k = require_kernel("_traffic")
    big = seed == 4  # more than 64 votes: the numpy path
    cfg = TrafficConfig(yaw_min_tracks=66 if big else 8, yaw_window_tracks=80 if big else 12,
                        yaw_live_min_length_m=5.0, yaw_min_track_length_m=5.0 if big else 40.0,
                        yaw_max_lateral_sd_m=5.0 if big else 0.8)
    fast, ref = YawEstimator(cfg), YawEstimator(cfg, kernels=False)
    codes = {0: 0, 1: 0, 2: 0}
    for ids, age, x, y in _random_frames(seed, 500):
        fast.add(ids, age, x, y)
        ref.add(ids, age, x, y)
        if len(fast._votes) >= cfg.yaw_min_tracks:
            continue
        code, a, b = k.yaw_startup(fast._acc, fast._live, fast._seq, fast._n_live, fast._votes,
                                   cfg.yaw_live_min_length_m, cfg.yaw_max_lateral_sd_m, cfg.yaw_min_tracks, np.arctan2)
        codes[code] += 1
        want = _startup_reference(fast)
        if code == 0:
            assert want == (None, None)
        elif code == 1:
            assert _bits((a, b)) == _bits(want)
        else:
            live, w = fast.live_votes_weighted()
            assert a.tobytes() == live.tobytes() and b.tobytes() == w.tobytes()
        got = fast.estimate_rad()
        assert _bits((got, fast.stderr_rad)) == _bits((ref.estimate_rad(), ref.stderr_rad))
    assert codes[0] > 0 and (codes[2] > 0 if big else codes[1] > 20), codes


def test_start_up_estimate_declines_a_nan_vote():
    k = require_kernel("_traffic")
    est = YawEstimator(TrafficConfig(yaw_min_tracks=2, yaw_live_min_length_m=1.0))
    for f in range(20):
        est.add(np.array([1, 2]), np.array([f + 1, f + 1]), np.array([0.1 * f, 3.0 + 0.05 * f]),
                np.array([10.0 + 2 * f, 50.0 - 2 * f]))
    est._votes.append(float("nan"))
    code, live, w = k.yaw_startup(est._acc, est._live, est._seq, est._n_live, est._votes, 1.0, 1.0, 2, np.arctan2)
    assert code == 2 and live.size == w.size == 2  # the numpy form takes it


def _monitors(cfg):
    fast = TrafficMonitor(cfg)
    ref = TrafficMonitor(cfg)
    ref._kernel = None  # the monitor's Python reference, its yaw estimator on the kernel (as fast's)
    assert fast._kernel is not None
    return fast, ref


def test_published_copies_equal_the_reference_copy_item_for_item():
    """On the lane pipeline's own frames (highway4-traffic): the kernel's published tracks are TrackStates whose
    instance dicts hold what ``monitor._with``'s do, key for key in the same order, floats bit for bit; a track
    that needs no copy is the tracker's own object; the motion model's x and the extents given as lists, float32 or
    a different length take the numpy gathers and publish the same."""
    require_kernel("_traffic")
    rec, cfg = _traffic_inputs(160)
    runs = [_monitors(cfg) for _ in range(3)]
    n_copied = n_same = 0
    for f, (tracks, t_ns, mx, ext) in enumerate(rec):
        variants = [(mx, ext),
                    (None if mx is None else mx.tolist(), None if ext is None else ext.astype(np.float32)),
                    (mx if f % 2 else None, None if ext is None else ext[:-1] if f % 3 else ext.tolist())]
        first = None
        for (fast, ref), (vx, ve) in zip(runs, variants):
            a, b = fast.update(tracks, t_ns, vx, ve), ref.update(tracks, t_ns, vx, ve)
            assert [_track_items(t) for t in a.tracks] == [_track_items(t) for t in b.tracks], t_ns
            assert a.presence == b.presence and a.events == b.events and repr(a.lane_stats) == repr(b.lane_stats)
            assert _bits((fast.yaw_rad, fast.yaw_sigma_rad)) == _bits((ref.yaw_rad, ref.yaw_sigma_rad))
            first = a if first is None else first
        for t0, t1 in zip(tracks, first.tracks):
            if t1 is t0:
                n_same += 1
            else:
                n_copied += 1
                assert vars(t1) == {**vars(t0), "lane": t1.lane, "cls": t1.cls, "length_m": t1.length_m}
    assert n_copied > 500


@pytest.mark.parametrize("seed", [4, 5])
def test_monitor_on_random_scenes_publishes_the_reference_copies(seed):
    """Random scenes (coasting, unconfirmed tracks with a length, classes, stops, wrong-way): the kernel path's
    published tracks against the Python reference's, dict item for dict item."""
    require_kernel("_traffic")
    cfg = TrafficConfig(estimate_yaw=True, interval_s=5.0, wrong_way_min_frames=5, stopped_min_s=3.0,
                        length_min_frames=3, yaw_min_tracks=4)
    fast, ref = _monitors(cfg)
    n_len = 0
    for tracks, t_ns, ext in _random_scene(seed, 600):
        a, b = fast.update(tracks, t_ns, extent_m=ext), ref.update(tracks, t_ns, extent_m=ext)
        assert [_track_items(t) for t in a.tracks] == [_track_items(t) for t in b.tracks], t_ns
        assert a.events == b.events and fast.yaw_rad == ref.yaw_rad
        n_len += sum(t.length_m is not None for t in a.tracks)
    assert n_len > 100


def test_copy_matches_with_on_a_track_of_the_dataclass_constructor():
    """``_with`` and the kernel's copy of a TrackState built by its own ``__init__`` (inline attribute values, no
    materialised dict) and of one built by ``track_state``."""
    require_kernel("_traffic")
    cfg = TrafficConfig(estimate_yaw=False)
    fast, ref = _monitors(cfg)
    for make in (lambda *a: TrackState(*a), lambda *a: track_state(*a, None)):
        tracks = (make(5, -1.75, 60.0, 0.0, -20.0, 60.0, -20.0, -0.03, 10, 9, True),
                  make(6, 1.75, 80.0, 0.0, 20.0, 80.0, 20.0, 0.02, 12, 12, False))
        a, b = fast.update(tracks, 1_000_000_000), ref.update(tracks, 1_000_000_000)
        assert [_track_items(t) for t in a.tracks] == [_track_items(t) for t in b.tracks]
        assert a.tracks[0] is not tracks[0] and a.tracks[0].lane == 1 and a.tracks[1] is tracks[1]
        assert dataclasses.replace(a.tracks[0]) == a.tracks[0]
        assert _track_items(_with(tracks[0], 1, None, None)) == _track_items(a.tracks[0])
        with pytest.raises(dataclasses.FrozenInstanceError):
            a.tracks[0].lane = 2


@pytest.mark.parametrize("seed", range(4))
def test_road_frame_and_lanes_equal_the_numpy_form(seed):
    """``road_lanes`` (whose per-track core ``monitor_pass`` runs) against ``TrafficMonitor.update``'s numpy form:
    along-road position and speed, speed, lane (nearest centre, first on ties, NaN), margin and the wrong-way gate,
    bit for bit except a NaN's sign; no lanes; the gate off."""
    from edge.traffic.lanes import Lane, assign_lanes_with_margin

    k = require_kernel("_traffic")
    rng = np.random.default_rng(seed)
    for trial in range(80):
        n = int(rng.integers(0, 25))
        kin = np.column_stack([np.arange(n, dtype=np.float64), np.ones(n), rng.normal(0, 8, n), rng.uniform(0, 300, n),
                               rng.normal(0, 2, n), rng.normal(0, 25, n)]).reshape(-1, 6)
        if n and trial % 5 == 0:
            kin[0, 2] = np.nan
        if n > 1 and trial % 7 == 0:
            kin[1, 2:4] = (0.0, 50.0)  # midway between two centres at yaw 0
        lanes = () if trial % 9 == 0 else tuple(
            Lane(c, w, d) for c, w, d in zip((-5.25, -1.75, 1.75, 5.25), rng.uniform(3.0, 4.0, 4), (-1, -1, 1, 1)))
        yaw = 0.0 if trial % 7 == 0 else rng.normal(0, 0.05)
        cy, sy = math.cos(yaw), math.sin(yaw)
        sure_k = -1.0 if trial % 4 == 0 else rng.uniform(0.001, 0.02)
        centres = np.array([ln.center_m for ln in lanes], dtype=np.float64)
        half_w = 0.5 * np.array([ln.width_m for ln in lanes], dtype=np.float64)
        got = k.road_lanes(kin, cy, sy, centres, half_w, sure_k)
        x, y, vx, vy = kin[:, 2], kin[:, 3], kin[:, 4], kin[:, 5]
        u, s_arr = x * cy + y * sy, -x * sy + y * cy
        lane_idx, margin = assign_lanes_with_margin(u, lanes)
        sure = lane_idx >= 0
        if sure_k > 0.0:
            sure &= margin >= sure_k * np.hypot(x, y)
        want = (s_arr.tolist(), (-vx * sy + vy * cy).tolist(), np.hypot(vx, vy).tolist(), lane_idx.tolist(),
                margin.tolist(), sure.tolist())
        nan = ("f", b"nan")  # (a NaN position: the kernel's NaN may carry the other sign bit, as at 4a8a1cf)
        same_nan = lambda v: [nan if isinstance(a, float) and a != a else _bits(a) for a in v]  # noqa: E731
        assert [same_nan(g) for g in got] == [same_nan(w) for w in want], trial
