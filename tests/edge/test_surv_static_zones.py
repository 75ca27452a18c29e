"""Static zones of the surveillance profile (``track.alphabeta.static_zone_*``): a slow cluster that keeps its range
(swaying foliage) becomes site clutter and feeds no track, a walker crossing the beam does not."""

from __future__ import annotations

import itertools
import math
from importlib import resources

import numpy as np
import pytest

from edge.config import load_config
from edge.pipeline import StageTimer, build_pipeline
from edge.track.static_zones import StaticZones
from hal import open_radar

PERIOD = 0.2


def _zones(**kw) -> StaticZones:
    args = dict(cell_m=0.75, max_range_m=24.0, frame_period_s=PERIOD, time_s=60.0, speed_kmh=2.0, occupancy=0.1)
    args.update(kw)
    return StaticZones(**args)


def test_a_slow_cluster_that_stays_becomes_a_zone_after_its_share_reaches_the_occupancy():
    z = _zones()
    first = None
    for n in range(600):
        seen = n % 2 == 0  # a bush found in every other frame at 8.1 m
        out = z.update([8.1] if seen else [], [0.4] if seen else [])
        if out == [0] and first is None:
            first = n
    # share after n frames: 0.5 (1 - (1 - w)^n); it reaches 0.1 at n = ln(0.8) / ln(1 - w)
    w = 1.0 - math.exp(-PERIOD / 60.0)
    expected = math.log(0.8) / math.log(1.0 - w)
    assert first is not None and abs(first - expected) <= 2
    assert z.zones_m() == [(pytest.approx(7.5), pytest.approx(8.25))]
    # fast clusters in the zone are not site clutter; slow ones elsewhere neither
    assert z.update([8.1, 8.1, 15.0], [3.0, -4.9, 0.0]) == []
    assert z.update([15.0, 8.1], [0.0, -1.9]) == [1]


def test_a_bush_whose_centroid_wanders_across_a_cell_boundary_counts_in_every_cell_it_spans():
    # the bush's cells span 7.3-8.4 m in every frame it is found; its centroid falls on either side of 7.5 m
    def first_zone(spans: bool) -> int | None:
        z = _zones()
        for n in range(600):
            seen = n % 2 == 0
            r = 7.4 if n % 4 == 0 else 7.9
            args = ([r], [0.4], [7.3], [8.4]) if spans else ([r], [0.4])
            out = z.update(*args) if seen else z.update([], [])
            if out == [0]:
                return n
        return None

    w = 1.0 - math.exp(-PERIOD / 60.0)
    with_spans, centroid_only = first_zone(True), first_zone(False)
    # spanned: every cell sees the bush in half the frames, as a bush that keeps its cell (0.5 (1 - (1 - w)^n) = 0.1)
    assert with_spans is not None and abs(with_spans - math.log(0.8) / math.log(1.0 - w)) <= 4
    # by the centroid alone each cell sees it in a quarter of the frames (0.25 (1 - (1 - w)^n) = 0.1): more than twice
    # as long
    assert centroid_only is not None and abs(centroid_only - math.log(0.6) / math.log(1.0 - w)) <= 4


def test_a_walker_crossing_the_beam_makes_no_zone():
    z = _zones()
    # a walker crossing at 6 m: slow (radial speed near zero) at one range for 6 s, a new cell when its range moves;
    # its cells span half a metre around its centroid
    for n in range(30):
        r = 6.0 + 0.01 * n
        assert z.update([r], [0.3], [r - 0.25], [r + 0.25]) == []
    assert z.zones_m() == []
    # a vehicle crossing a range cell with its wrapped Doppler near zero (an alias) for a frame or two neither
    for n in range(300):
        r = 20.0 - 2.2 * PERIOD * (n % 40)
        z.update([r], [-0.5])
    assert z.zones_m() == []


def test_shares_follow_the_exponential_average():
    z = _zones(time_s=5.0)
    rng = np.random.default_rng(3)
    ref = np.zeros_like(z.share)
    for _ in range(200):
        n = int(rng.integers(0, 4))
        r, v = rng.uniform(0.0, 30.0, n), rng.uniform(-5.3, 5.3, n)
        cells = np.clip((r / 0.75).astype(int), 0, ref.size - 1)
        slow = np.abs(v) <= 2.0
        expect = [int(k) for k in np.flatnonzero(slow & (ref[cells] >= 0.1))]
        assert z.update(r.tolist(), v.tolist()) == expect
        seen = np.zeros_like(ref)
        seen[cells[slow]] = 1.0
        ref += z.weight * (seen - ref)
        assert np.array_equal(z.share, ref)  # bit for bit: share += w (seen - share)


def test_zones_merge_adjacent_cells():
    z = _zones(time_s=1.0)
    for _ in range(20):
        z.update([7.6, 8.3, 12.0], [0.0, 0.1, -0.2])
    assert z.zones_m() == [(pytest.approx(7.5), pytest.approx(9.0)), (pytest.approx(12.0), pytest.approx(12.75))]


def _published_late(seed: int, frames: int, **sets) -> int:
    src = open_radar(f"sim://d2g?scenario=empty-d2g&realtime=0&seed={seed}&frames={frames}")
    src.open()
    try:
        cfg = load_config(None, overrides={f"track.alphabeta.{k}": v for k, v in sets.items()})
        pipe = build_pipeline("surveillance", src.frontend, cfg)
        timer = StageTimer(window=16)
        late = 0
        for k, fr in enumerate(itertools.islice(iter(src), frames)):
            res = pipe.process(fr, timer)
            late += len(res.tracks) if k >= frames - 50 else 0
        return late
    finally:
        src.close()


@pytest.mark.parametrize("seed", [2, 3])
def test_swaying_foliage_of_the_empty_site_is_not_tracked_once_its_zone_is_learned(seed):
    # the simulated urban site (hw_sim.events: a bush beside the radar at 8 m, trees) without a target, 60 s: without
    # zones its foliage is tracked to the end; with them nothing is published in the last 10 s
    assert _published_late(seed, 300, static_zone_time_s=0.0) > 0
    assert _published_late(seed, 300) == 0


def test_a_walker_crossing_after_the_zones_are_learned_is_tracked_and_classified(tmp_path):
    from edge.evaluation.surveillance import evaluate
    from hw_sim.scenario import load_scenario

    text = resources.files("hw_sim").joinpath("scenarios", "empty-d2g.toml").read_text(encoding="utf-8")
    text = text.replace("duration_s = 10.0", "duration_s = 64.0")
    # a walker crossing the road 5 m ahead, 45 s in (the bush's zone at 8 m is learned by then)
    text += ('\n[[d2g_target]]\nid = 100\nclass = "pedestrian"\nx_m = -3.0\ny_m = 5.0\nvx_mps = 1.3\nvy_mps = 0.0\n'
             'start_s = 45.0\nend_s = 53.0\n')
    path = tmp_path / "crossing.toml"
    path.write_text(text, encoding="utf-8")
    sc = load_scenario(str(path))
    report = evaluate(sc, seed=2, frames=None, events=None, config=load_config(None))
    (row,) = report["targets"]
    assert row["predicted_class"] == "pedestrian"
    assert row["tracked_fraction"] > 0.5
