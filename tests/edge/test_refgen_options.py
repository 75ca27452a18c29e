"""Reference-set generator options: board gain augmentation and the widened vehicle population."""

from __future__ import annotations

import numpy as np
import pytest

from edge.classify.refgen import DEFAULT_SEED, build_reference_set, event_gain_offsets
from hw_sim.events import (
    CAR_LENGTH_M,
    TRUCK_LENGTH_M,
    VAN_LENGTH_M,
    single_random,
)

SEED = DEFAULT_SEED + 17  # not a corpus seed, not the packaged set's


def _body_lengths(scenario, seed: int) -> dict[str, list[float]]:
    scene = scenario.build_scene(seed)
    out: dict[str, list[float]] = {}
    for tg in scene.targets:
        if tg.cls in ("car", "truck"):
            y = np.asarray(tg.offsets_m)[:, 1]
            out.setdefault(tg.cls, []).append(float(y.max() - y.min()))
    return out


def test_event_gain_offsets_are_seeded_and_uniform_in_the_range():
    g = event_gain_offsets(SEED, 400, (-6.0, 6.0))
    assert g.shape == (400,) and g.min() >= -6.0 and g.max() <= 6.0
    assert g.min() < -5.0 and g.max() > 5.0 and abs(g.mean()) < 1.0
    np.testing.assert_array_equal(g, event_gain_offsets(SEED, 400, (-6.0, 6.0)))
    assert not np.allclose(g, event_gain_offsets(SEED + 1, 400, (-6.0, 6.0)))


def test_gain_offsets_reach_the_simulated_board(monkeypatch):
    import hw_sim.simulator as simulator

    boards = []
    real = simulator.FrameSimulator

    class Recording(real):
        def __init__(self, board, scene, seed):
            boards.append(board.radio.gain_offset_db)
            super().__init__(board, scene, seed)

    monkeypatch.setattr(simulator, "FrameSimulator", Recording)
    ref = build_reference_set(events_per_class=1, seed=SEED, gain_offsets_db=(-6.0, 6.0))
    base = boards[0]  # the instrument's board, made before the events
    want = event_gain_offsets(SEED, 4, (-6.0, 6.0))
    np.testing.assert_allclose(np.array(boards[1:]) - base, want)
    assert ref.meta["gain_offsets_db"] == [-6.0, 6.0] and ref.meta["population"] == "site"
    # the events themselves are those of the build without offsets; a weaker board reads a weaker RCS
    boards.clear()
    plain = build_reference_set(events_per_class=1, seed=SEED)
    assert len(boards) == 1 and plain.meta["gain_offsets_db"] is None
    assert plain.labels.tolist() == ref.labels.tolist()
    rcs = list(plain.feature_names).index("rcs_mean")
    for k in range(len(ref)):
        if abs(want[k]) > 2.0:
            assert np.sign(ref.features[k, rcs] - plain.features[k, rcs]) == np.sign(want[k])
    with pytest.raises(ValueError):
        build_reference_set(events_per_class=1, seed=SEED, gain_offsets_db=(6.0, -6.0))


def test_wide_population_draws_longer_trucks_vans_and_the_wider_car_range():
    wide = _body_lengths(single_random(events=48, population="wide"), SEED)
    trucks, cars = np.array(wide["truck"]), np.array(wide["car"])
    assert trucks.size == 12 and cars.size == 12
    assert np.all((trucks >= TRUCK_LENGTH_M["wide"][0]) & (trucks <= TRUCK_LENGTH_M["wide"][1]))
    assert trucks.max() > 12.5 and trucks.min() < 9.0  # beyond the site's 7-12 m
    in_car = (cars >= CAR_LENGTH_M["wide"][0]) & (cars <= CAR_LENGTH_M["wide"][1])
    in_van = (cars >= VAN_LENGTH_M[0]) & (cars <= VAN_LENGTH_M[1])
    assert np.all(in_car | in_van)
    assert np.any(cars > CAR_LENGTH_M["wide"][1])  # a van


def test_site_population_is_the_evaluation_corpus_unchanged():
    site = _body_lengths(single_random(events=16), SEED)
    assert np.all((np.array(site["truck"]) >= 7.0) & (np.array(site["truck"]) <= 12.0))
    assert np.all((np.array(site["car"]) >= 3.8) & (np.array(site["car"]) <= 5.0))
    a = single_random(events=8).build_scene(SEED)
    b = single_random(events=8, population="site").build_scene(SEED)
    for ta, tb in zip(a.targets, b.targets):
        np.testing.assert_array_equal(ta.offsets_m, tb.offsets_m)
    with pytest.raises(ValueError):
        single_random(events=4, population="huge")


def test_tracked_signatures_are_the_targets_tracks_not_the_site_clutter():
    """On the urban site the swaying bush holds a track through every event: a tracked reference event is the
    track that follows the target (it moves), never the bush's (about 1 km/h)."""
    ref = build_reference_set(events_per_class=2, seed=SEED, signatures="tracked", population="wide")
    speed = list(ref.feature_names).index("abs_radial_speed_mean_kmh")
    assert len(ref) >= 6
    assert np.all(ref.features[:, speed] > 2.0), ref.features[:, speed]
