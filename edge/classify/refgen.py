"""Synthetic reference set from single-target events of the simulated Distance2Go (Tavanti §III-C).

The paper trains its k-NN on 182 recorded single-target passages whose signatures are *thresholded*
with ``th_RD`` but neither clustered nor tracked, so that learning does not depend on the DBSCAN and
tracker parameters. :func:`build_reference_set` does the same on the simulator:

1. the ``single-random`` event generator of :mod:`hw_sim.events` (one randomised pedestrian, car,
   motorcycle or truck per 24 s slot at the simulated test site, classes balanced) with a seed;
2. every frame of the target's *passage* -- some of its scatterers within 24 m, at any azimuth
   (:data:`PASSAGE_HALF_SECTOR_DEG`; :func:`hw_sim.events.frame_view`), i.e. the whole recording an
   event trigger would make, including the frames where it passes beside the radar at short range
   and its Doppler spreads and the last ones just behind it, which the board's sidelobe floor still
   sees -- is synthesised and run through the profile's front end (IIR
   canceller, Kaiser windows, 512 x 256 map: :class:`edge.dsp.range_doppler.RangeDopplerProcessor`
   with the ``pipeline.surveillance`` settings);
3. all cells at or above ``th_RD`` form one signature (label 0) whose circular variance, eq. 17 RCS
   quantity and centroid range feed a :class:`~edge.classify.features.TrackFeatureAccumulator`;
   cells closer than ``min_range_m`` (default: one range resolution cell, c / 2B = 0.75 m) are left
   out: the residue of the TX->RX leakage that the canceller does not remove sits there, and a few
   such cells would drag the centroid of a target 20 m away to mid-range and fake a radial speed
   (clustering rejects them in operation: they never reach DBSCAN's ``M`` points);
4. an event seen in at least ``min_frames`` frames with points gives one labelled feature vector.

``frames="beam"`` keeps only the frames with the target inside the half-power beam (range <= 24 m,
|az| <= 21°, :func:`hw_sim.events.visible`); it was the default until the surveillance tracker was
measured against it: a track lives through the whole passage, so features from the beam frames
alone had half the circular variance of the same car's track (cars then read as motorcycles).
``passage_half_sector_deg`` was 45° until it was compared with what the tracker measures: the
surveillance tracker follows a target as long as it gives clusters, through its passage beside the
radar (motorcycles in the near lane had twice the circular variance in operation that the 45°
passage gave them, and read as cars).
Vehicles (``vehicle_lanes``): the evaluation generators keep right on the two-way road (approaching
in the near lane, 2-3.5 m beside the radar; receding in the far lane, 5-6.5 m), so a reference set
drawn from them never held a vehicle *departing* close to the radar and near boresight, seen
stronger (eq. 17) and longer in range than any departing car of the set; Tavanti's Test 1 car is one
(16.5 km/h, 3 m beside the radar: read as a truck on 3 of 5 dev seeds). The default ``"any"`` draws
each vehicle's direction independently of its lane (``hw_sim.events``, ``keep_right=False``).
Frames outside the passage are not synthesised (the scene is empty then), which keeps a build of
4 x 250 events to a few minutes.

``signatures="tracked"`` is the alternative the paper avoids: the events go through the whole
surveillance chain (DBSCAN, alpha-beta tracker, :class:`~edge.track.surveillance.SurveillanceTracker`
without classification) and, of the events whose track follows the target as the surveillance evaluation
matches them, the one with the most frames gives its feature vector, so the reference features are computed
exactly as in operation (with the clustering and tracking parameters baked in). The longest event of the
passage alone would be the urban site's swaying bush, tracked throughout.

``gain_offsets_db=(lo, hi)`` simulates each event on a board whose ``physics.gain_offset_db`` is drawn uniformly
in ``[lo, hi]`` (the corpus's gain-offset variants' knob), so one set covers boards of different gain;
``population="wide"`` draws the vehicles from :mod:`hw_sim.events`' widened population (cars 3.5-5.2 m, vans,
trucks and buses 6-18 m). Decision 0014 has the figures of a set built with both on tracked signatures.

The packaged default ``edge/data/reference_set.npz`` (the one the surveillance pipeline loads when
``classify.knn.reference_set`` is empty) is regenerated, from the repository root, with exactly::

    PYTHONPATH=. python -c "from edge.classify.refgen import write_default; write_default()"

which is ``build_reference_set(**PACKAGED_BUILD)``: 150 tracked events per class on the physical defaults, each on
a board between -6 and +6 dB of gain, vehicles from the wide population (568 references; about 15 to 20 minutes on the
development machine, 45 under load). It replaced a set of 250 thresholded passages per class built on the
simulator's ``v1`` instrument; docs/decisions/0016 has the dev figures that chose it. Afterwards rebuild the packaged
ONNX model: ``radar-edge export-onnx --out edge/data/knn_default.onnx``. The seeds used by evaluations and tests
must differ from :data:`DEFAULT_SEED`.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from typing import Any, Callable

import numpy as np

from edge.classify.features import (FEATURE_NAMES, FeatureConfig, MapPoints, SignatureExtractor, TrackFeatureAccumulator,
                                    feature_settings)
from edge.classify.reference import DEFAULT_CLASSES, ReferenceSet, default_reference_path, save_reference_set
from hal.waveform import characteristics

log = logging.getLogger(__name__)

__all__ = ["DEFAULT_EVENTS_PER_CLASS", "DEFAULT_SEED", "PACKAGED_BUILD", "PASSAGE_HALF_SECTOR_DEG", "build_reference_set",
           "event_gain_offsets", "event_signatures", "write_default"]

DEFAULT_SEED = 90210
DEFAULT_EVENTS_PER_CLASS = 250
#: azimuth half-sector of a passage's frames (180 = all round: within 24 m at any azimuth)
PASSAGE_HALF_SECTOR_DEG = 180.0
#: ``signatures="tracked"``: least fraction of the target's range rate a track of it has
MIN_RATE_FRACTION = 0.5
REGENERATE_COMMAND = 'PYTHONPATH=. python -c "from edge.classify.refgen import write_default; write_default()"'
#: how the packaged reference set is built (:func:`write_default`)
PACKAGED_BUILD: dict[str, Any] = {"events_per_class": 150, "seed": DEFAULT_SEED, "signatures": "tracked",
                                  "gain_offsets_db": (-6.0, 6.0), "population": "wide"}


def event_signatures(
    frames: Any, extractor: SignatureExtractor, min_range_m: float = 0.0
) -> TrackFeatureAccumulator:
    """Accumulate thresholded signatures: ``frames`` yields ``(t_s, MapPoints)`` (labels ignored,
    cells closer than ``min_range_m`` dropped)."""
    acc = TrackFeatureAccumulator(extractor.config.extent_percentile, vmax_kmh=extractor.speed_vmax_kmh)
    for t_s, pts in frames:
        k = np.asarray(pts.range_m) >= min_range_m
        if not k.any():
            continue
        one = MapPoints(pts.range_m[k], pts.doppler_kmh[k], pts.amplitude[k], pts.range_bin[k],
                        pts.doppler_bin[k], np.zeros(int(k.sum()), dtype=np.int32))
        sig = extractor(one, n_clusters=1)
        acc.add(t_s, sig.circular_variance[0], sig.rcs[0], sig.range_m[0], float(sig.extent_m[0]),
                float(sig.doppler_kmh[0]))
    return acc


def _matches_target(hist: list[tuple[int, float]], ids: set[int], view: Callable[[int], Any]) -> bool:
    """Whether a track's ``(frame, range)`` history follows one of the targets ``ids`` as the surveillance
    evaluation matches them (:mod:`edge.evaluation.surveillance`): the target in view (``view(n)``, a
    :class:`hw_sim.events.FrameView`) on at least half of the track's frames, the track's range on average within
    ``MATCH_RANGE_M`` of the target's scatterers, and its range rate at least :data:`MIN_RATE_FRACTION` of the
    target's weighted range's, same sign."""
    from edge.evaluation.surveillance import MATCH_RANGE_M, MIN_MATCH_OVERLAP

    if not hist:
        return False
    gaps, rows = [], []
    for n, r in hist:
        fv = view(n)
        k = [j for j, i in enumerate(fv.id.tolist()) if i in ids]
        if k:
            gaps.append(max(0.0, fv.range_min_m[k[0]] - r, r - fv.range_max_m[k[0]]))
            rows.append((n, r, fv.range_m[k[0]]))
    if len(gaps) < MIN_MATCH_OVERLAP * len(hist) or float(np.mean(gaps)) > MATCH_RANGE_M or len(rows) < 3:
        return False
    # a static object inside a long body's extent (the urban site's bush, merged with the body while it passes)
    # also passes the test above: the track's range must change at the rate of the target's weighted range
    n, r, rw = (np.array(c, dtype=float) for c in zip(*rows))
    rate, rate_true = np.polyfit(n, r, 1)[0], np.polyfit(n, rw, 1)[0]
    return bool(rate * rate_true > 0 and abs(rate) >= MIN_RATE_FRACTION * abs(rate_true))


def event_gain_offsets(seed: int, n_events: int, gain_offsets_db: tuple[float, float]) -> np.ndarray:
    """The board gain offsets (dB) of a build's ``n_events`` events, uniform in ``gain_offsets_db``, from ``seed``
    (a stream of its own: the events themselves are those of the build without offsets)."""
    lo, hi = (float(g) for g in gain_offsets_db)
    return np.random.default_rng([int(seed), 0x6A17]).uniform(lo, hi, int(n_events))


def build_reference_set(
    *,
    events_per_class: int = DEFAULT_EVENTS_PER_CLASS,
    seed: int = DEFAULT_SEED,
    config: Any = None,
    min_frames: int = 3,
    min_range_m: float | None = None,
    signatures: str = "thresholded",
    frames: str = "passage",
    passage_half_sector_deg: float = PASSAGE_HALF_SECTOR_DEG,
    vehicle_lanes: str = "any",
    progress: Callable[[int, int], None] | None = None,
    physics: Any = None,
    gain_offsets_db: tuple[float, float] | None = None,
    population: str = "site",
) -> ReferenceSet:
    """Build a reference set from ``4 * events_per_class`` simulated single-target events.

    ``config`` is a resolved :class:`edge.config.Config` (default: the defaults); its
    ``pipeline.surveillance`` section sets the front end and ``th_RD``, ``classify.features`` the
    signatures. ``min_range_m`` defaults to the range resolution ``c / 2B``. ``progress(done, total)``
    is called after every event. ``vehicle_lanes``: ``"any"`` (default) draws a vehicle's direction
    independently of its lane (``hw_sim.events``, ``keep_right=False``), ``"keep_right"`` is the
    evaluation generators' two-way road (approaching in the near lane, receding in the far one).
    ``physics`` (a :class:`hw_sim.physics.Physics`) is the simulator's instrument; default: the scenario's
    (the physical defaults); ``parse_physics({"preset": "v1"})`` is the instrument the shipped set was built on.
    ``gain_offsets_db`` ``(lo, hi)``: each event is simulated on a board whose ``physics.gain_offset_db`` is the
    instrument's plus an offset drawn uniformly in ``[lo, hi]`` (:func:`event_gain_offsets`); None: one board.
    ``population``: the vehicles' bodies (:data:`hw_sim.events.VEHICLE_POPULATIONS`; "wide" for wider lengths and vans).
    """
    from edge.config import load_config
    from edge.dsp.range_doppler import RangeDopplerProcessor
    from hw_sim.events import SLOT_S, frame_view, single_random, visible
    from hw_sim.simulator import FrameSimulator

    if events_per_class < 1:
        raise ValueError("events_per_class must be at least 1")
    if frames not in ("passage", "beam"):
        raise ValueError(f"frames must be 'passage' or 'beam', got {frames!r}")
    if vehicle_lanes not in ("any", "keep_right"):
        raise ValueError(f"vehicle_lanes must be 'any' or 'keep_right', got {vehicle_lanes!r}")
    if signatures not in ("thresholded", "tracked"):
        raise ValueError(f"signatures must be 'thresholded' or 'tracked', got {signatures!r}")
    if gain_offsets_db is not None and not gain_offsets_db[0] <= gain_offsets_db[1]:
        raise ValueError(f"gain_offsets_db must be (lo, hi) with lo <= hi, got {gain_offsets_db!r}")
    cfg = config if config is not None else load_config(env={})
    sc_cfg = cfg.section("pipeline.surveillance")
    feat_cfg: FeatureConfig = cfg.section("classify.features")
    n_events = 4 * events_per_class
    if population == "site":  # the scenario exactly as before the option (its raw table has no population key)
        scenario = single_random(events=n_events, keep_right=vehicle_lanes == "keep_right")
    else:
        scenario = single_random(events=n_events, keep_right=vehicle_lanes == "keep_right", population=population)
    if physics is not None:
        scenario = dataclasses.replace(scenario, physics=physics)
    board = scenario.sim_board()
    fe = board.frontend
    scene = scenario.build_scene(seed)
    sim = FrameSimulator(board, scene, seed)
    gains = None if gain_offsets_db is None else event_gain_offsets(seed, n_events, gain_offsets_db)
    rd = RangeDopplerProcessor(fe, k_c=sc_cfg.k_c, k_sf=sc_cfg.k_sf, n_range_fft=sc_cfg.n_range_fft,
                               n_doppler_fft=sc_cfg.n_doppler_fft)
    extractor = SignatureExtractor(feat_cfg, fe)
    if min_range_m is None:
        min_range_m = characteristics(fe).range_resolution_m
    period = fe.waveform.frame_period_s
    per_slot = int(round(SLOT_S / period))
    iq = np.empty(fe.frame_shape, dtype=np.complex64)
    feats: list[np.ndarray] = []
    labels: list[int] = []
    skipped: dict[str, int] = {c: 0 for c in DEFAULT_CLASSES}
    t0 = time.perf_counter()

    def frames_of(event: int, cls_out: list[str]):
        for n in range(event * per_slot, (event + 1) * per_slot):
            if frames == "passage":
                fv = frame_view(scene, n * period, passage_half_sector_deg, board)
                if len(fv) == 0:
                    continue
                if fv.in_beam.any():
                    cls_out.append(fv.cls[int(np.flatnonzero(fv.in_beam)[0])])
            else:
                truth = scene.truth(n * period)
                vis = visible(truth, scene.pose)
                if not vis.any():
                    continue
                cls_out.append(truth.cls[int(np.flatnonzero(vis)[0])])
            f = sim.frame(n)
            iq.real = f.i
            iq.imag = f.q
            m = rd.process(iq).amplitude
            yield f.t_s, MapPoints.from_map(m, sc_cfg.th_rd, rd.range_m, rd.radial_speed_kmh)

    def tracked_features(event: int) -> tuple[str | None, np.ndarray, int]:
        from edge.pipeline import StageTimer
        from edge.pipelines.surveillance import SurveillancePipeline
        from edge.track.surveillance import SurveillanceTracker
        from edge.types import RawFrame

        tgs = [tg for tg in scene.targets if tg.id // 100 - 1 == event]
        if not tgs:
            return None, np.full(len(FEATURE_NAMES), np.nan), 0
        tracker = SurveillanceTracker(
            fe, sc_cfg.th_rd, tracking=cfg.section("track.alphabeta"), events=cfg.section("track.events"),
            features=feat_cfg, classify=False,
        )
        pipe = SurveillancePipeline(fe, dataclasses.replace(sc_cfg, keep_map=False), full_config=cfg, tracker=tracker)
        timer = StageTimer(window=16)
        tail = cfg.section("track.alphabeta").max_missed_frames + cfg.section("track.events").release_frames + 2
        n0 = max(0, int(min(tg.t_start_s for tg in tgs) / period))
        n1 = min((event + 1) * per_slot, int(max(tg.t_end_s for tg in tgs) / period) + tail)
        open_hist: dict[int, list[tuple[int, float]]] = {}
        evs: list[tuple[Any, list[tuple[int, float]]]] = []
        for n in range(n0, n1):
            f = sim.frame(n)
            raw = RawFrame(seq=n, t_ns=int(round(n * period * 1e9)), i=f.i, q=f.q, frontend=fe, truth=f.truth)
            res = pipe.process(raw, timer)
            for tid in res.intermediates.get("tracks_ended_without_event", ()):
                open_hist.pop(tid, None)
            meas = res.intermediates.get("track_cluster_range_m", {})
            for ts in res.tracks:
                r = meas.get(ts.track_id)
                open_hist.setdefault(ts.track_id, []).append((n, float(ts.range_m if r is None else r)))
            evs.extend((ev, open_hist.pop(ev.track_id, [])) for ev in res.classifications)
        evs.extend((ev, open_hist.pop(ev.track_id, [])) for ev in pipe.flush())
        ids = {tg.id for tg in tgs}
        views: dict[int, Any] = {}

        def view(n: int):
            if n not in views:
                views[n] = frame_view(scene, n * period, board=board)
            return views[n]

        mine = [(ev, hist) for ev, hist in evs if _matches_target(hist, ids, view)]
        if not mine:
            return tgs[0].cls, np.full(len(FEATURE_NAMES), np.nan), 0
        best = max(mine, key=lambda eh: len(eh[1]))[0]
        x = np.array([best.features[k] for k in FEATURE_NAMES])
        return tgs[0].cls, x, int(best.features.get("frames", 0))

    for e in range(n_events):
        if gains is not None:
            phys_e = dataclasses.replace(scenario.physics,
                                         gain_offset_db=scenario.physics.gain_offset_db + float(gains[e]))
            sim = FrameSimulator(dataclasses.replace(scenario, physics=phys_e).sim_board(), scene, seed)
        if signatures == "thresholded":
            seen_cls: list[str] = []
            acc = event_signatures(frames_of(e, seen_cls), extractor, min_range_m)
            cls, x, n_fr = (seen_cls[0] if seen_cls else None), acc.features(), acc.n
        else:
            cls, x, n_fr = tracked_features(e)
        if cls is not None:
            if n_fr >= min_frames and np.all(np.isfinite(x)):
                feats.append(x)
                labels.append(DEFAULT_CLASSES.index(cls))
            else:
                skipped[cls] += 1
        if progress is not None:
            progress(e + 1, n_events)
    elapsed = time.perf_counter() - t0
    if not feats:
        raise ValueError("no event produced a signature: check th_RD and the front end")
    meta = {
        "generator": "edge.classify.refgen.build_reference_set",
        "scenario": "single-random",
        "signatures": signatures,
        "frames": frames,
        "passage_half_sector_deg": float(passage_half_sector_deg),
        "vehicle_lanes": vehicle_lanes,
        "population": population,
        "gain_offsets_db": None if gain_offsets_db is None else [float(g) for g in gain_offsets_db],
        "seed": int(seed),
        "events_per_class": int(events_per_class),
        "min_frames": int(min_frames),
        "min_range_m": float(min_range_m),
        "skipped_events": skipped,
        "pipeline.surveillance": {k: getattr(sc_cfg, k) for k in ("k_c", "k_sf", "th_rd", "n_range_fft",
                                                                  "n_doppler_fft")},
        "classify.features": feature_settings(feat_cfg),
        "build_seconds": round(elapsed, 1),
        "command": REGENERATE_COMMAND,
    }
    ref = ReferenceSet(np.array(feats), np.array(labels, dtype=np.intp), DEFAULT_CLASSES, meta=meta)
    log.info("reference set: %s from %d events in %.1f s (skipped %s)", ref.class_counts(), n_events, elapsed, skipped)
    return ref


def write_default(path: str | None = None, **kwargs: Any) -> ReferenceSet:
    """Build the packaged set (:data:`PACKAGED_BUILD`, ``kwargs`` override) and save it to the packaged location (or
    ``path``)."""
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    ref = build_reference_set(**{**PACKAGED_BUILD, **kwargs})
    out = save_reference_set(ref, path or default_reference_path())
    log.info("wrote %s", out)
    return ref
