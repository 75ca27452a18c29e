"""The seed-exclusion gate's scatterer-height term: near an overpass radar a vehicle's higher scatterers appear nearer
and faster than its low ones, and must not start a second track."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge.track import PdafConfig, PdafTracker
from edge.track.roles.measure import height_cov
from edge.types import Detections

FRAME_NS = 33_000_000
H_RADAR, H_ASSUMED = 7.0, 0.5  # the overpass mounting and the pipeline's target_height_m
DZ = H_RADAR - H_ASSUMED


def _detection(x: float, y: float, vy: float, z: float, snr_db: float):
    """What the lane pipeline reports for a scatterer at height ``z`` above the ground point (x, y) of a vehicle
    moving at ``vy`` along the road: the slant range and radial speed, projected to the ground with the assumed
    height (``polar_to_ground``), as (range, radial speed, az, snr, x, y)."""
    rho = math.hypot(x, y)
    slant = math.hypot(rho, H_RADAR - z)
    vr = vy * y / rho * rho / slant  # the horizontal radial speed times the cosine of the elevation
    rho_g = math.sqrt(max(slant * slant - DZ * DZ, 0.0))
    return slant, vr, math.atan2(x, y), snr_db, x * rho_g / rho, y * rho_g / rho


def _frame(rows) -> Detections:
    r, vr, az, snr, x, y = (np.array(c, dtype=np.float32) for c in zip(*rows))
    return Detections(r, vr, az, snr, x, y)


def test_a_higher_scatterer_appears_nearer_and_faster_along_the_terms_direction():
    """The roof edge (3.5 m) of a truck 10 m out and its bumper (0.5 m): the roof's reported ground range is
    shorter and its ground radial speed higher, by amounts the rank-one term's direction reproduces to first order."""
    x, y, vy = 1.75, 10.0, 28.0
    lo, hi = _detection(x, y, vy, H_ASSUMED, 30.0), _detection(x, y, vy, 3.5, 30.0)
    rho = math.hypot(x, y)
    d_rho = math.hypot(hi[4], hi[5]) - math.hypot(lo[4], lo[5])
    d_v = hi[1] * hi[0] / math.hypot(hi[4], hi[5]) - lo[1] * lo[0] / math.hypot(lo[4], lo[5])
    assert d_rho < -1.0 and d_v > 2.0  # metres nearer, metres per second faster
    r = np.zeros((1, 3, 3))
    height_cov(r, np.array([[x, y]]), np.array([vy * y / rho]), DZ, 1.0)
    g = np.sqrt(np.diag(r[0]))  # |g| per component for a 1 m height
    assert np.allclose(r[0], np.outer(r[0][:, 0], r[0][:, 0]) / r[0][0, 0])  # rank one
    assert r[0][1, 2] < 0  # nearer goes with faster (y falls as the radial speed rises)
    assert d_rho / 3.0 == pytest.approx(-math.hypot(g[0], g[1]), rel=0.35)
    assert d_v / 3.0 == pytest.approx(g[2], rel=0.35)
    far = np.zeros((1, 3, 3))
    height_cov(far, np.array([[x, 150.0]]), np.array([vy]), DZ, 1.0)
    assert far[0][1, 1] < 0.01 * r[0][1, 1] and far[0][2, 2] < 0.01 * r[0][2, 2]  # far out it hardly matters


def _recede(cfg: PdafConfig, n_frames: int = 40) -> tuple[set[int], int]:
    """A tall vehicle leaving the overpass in the lane at x = 1.75 m, 28 m/s from 5 m out: its bumper (0.5 m) gives a
    detection every frame, the top edge of its rear doors (3.5 m) every frame from the fourth. Returns the confirmed
    track ids and the largest number of confirmed tracks in a frame."""
    tr = PdafTracker(cfg, height_above_target_m=DZ)
    ids, most = set(), 0
    for k in range(n_frames):
        y = 5.0 + 28.0 * k * FRAME_NS * 1e-9
        rows = [_detection(1.75, y, 28.0, H_ASSUMED, 32.0)]
        if k >= 3:
            rows.append(_detection(1.75, y, 28.0, 3.5, 26.0))
        out = [t for t in tr.step(_frame(rows), k * FRAME_NS) if t.confirmed]
        ids |= {t.track_id for t in out}
        most = max(most, len(out))
    return ids, most


def test_a_tall_vehicles_top_edge_starts_no_second_track_near_the_radar():
    ids, most = _recede(PdafConfig())
    assert len(ids) == 1 and most == 1
    # without the term the top edge's detections, nearer and faster, start a second confirmed track
    ids0, most0 = _recede(PdafConfig(scatterer_height_sigma_m=0.0))
    assert len(ids0) == 2 and most0 == 2


def test_the_term_needs_the_mounting_height():
    """A tracker that is not told how high the radar is above the scatterers has no height term."""
    tr = PdafTracker(PdafConfig())
    assert tr.measurement_model.height_above_target_m == 0.0
    xp = np.array([[1.75, 10.0, 0.0, 25.0]])
    s = np.eye(3)[None]
    assert np.array_equal(tr.measurement_model.with_sensor(xp, s, 1.0), tr.measurement_model.with_sensor(xp, s, 0.0))


def _far_end_confirms(height_above_target_m: float, near_y: float) -> bool:
    """A confirmed track on a truck's rear, ``near_y`` out at 30.5 m/s (it follows a high scatterer, so it reads
    fast), and a tentative track on its front end 15 m farther at 27.5 m/s, ready to confirm: whether the confirmer
    confirms it (the kernel and the numpy reference agree)."""
    from types import SimpleNamespace

    tr = PdafTracker(PdafConfig(), height_above_target_m=height_above_target_m)
    conf = tr.confirmer
    tracks = SimpleNamespace(x=np.array([[1.75, near_y, 0.0, 30.5], [1.75, near_y + 15.0, 0.0, 27.5]]),
                             history=np.array([0b1111111111, 0b11111], np.uint32), confirmed=np.array([True, False]),
                             moved=np.array([True, True]), score=np.zeros(2))
    rows = conf.confirming(tracks)
    assert list(rows) == conf.confirming_numpy(tracks).tolist()
    return 1 in list(rows)


def test_the_confirm_blocks_speed_test_allows_for_scatterer_height_near_the_radar():
    """14 m from an overpass radar two scatterers of one truck, 2 m apart in height, read radial speeds 2 m/s apart:
    a 3 m/s difference there is the same truck, while 150 m out (where height hardly matters) or with no mounting
    height it is a second vehicle, and the tentative track confirms."""
    assert not _far_end_confirms(DZ, 14.0)
    assert _far_end_confirms(DZ, 150.0)
    assert _far_end_confirms(0.0, 14.0)
