"""FFT-only bound, peer pipeline and classifier latency of the ``surveillance`` profile.

``fft_bound``: the transforms the profile cannot avoid -- the first channel's int16 I/Q into
complex64 and the zero-padded range-Doppler FFT as configured in ``pipeline.surveillance``
(``N_R`` = 512 along fast time, of which the positive half is kept, then ``N_D`` = 256 along slow
time), single precision, ``scipy.fft`` with one worker. No canceller, window, magnitude or
threshold.

``peer``: what a user would otherwise glue together, written plainly:

* float64 numpy: ``i + 1j q`` as complex128, the IIR canceller with ``scipy.signal.lfilter`` along
  the chirps (step-initialised state, first chirp dropped, DESIGN §5), Kaiser windows, one
  ``numpy.fft.fft2`` zero-padded to ``(N_D, N_R)``, positive range half, ``fftshift``, magnitude;
* threshold ``th_RD``; the points placed on the cylinder of Tavanti eq. 6 (``[v', v'', r]``) and
  clustered by scikit-learn's ``DBSCAN(eps, min_samples=M)`` (Euclidean);
* the feature step and the tracking: the product's :class:`edge.track.surveillance.SurveillanceTracker`
  (cluster signatures, alpha-beta tracker, event segmentation, per-track features -- no library
  provides Tavanti's signatures or the cylinder-constrained Benedict-Bordner tracker), but with a
  scikit-learn ``KNeighborsClassifier(n_neighbors=k, weights='distance')`` behind a
  ``StandardScaler``, fitted on the packaged reference set, as the classifier; the provisional class
  of every live track is queried from it every frame, as the product does.

Without scikit-learn, :func:`peer` returns ``None`` (the bench report says why).

``extras`` adds the per-query latency of the deployed classifier (onnxruntime) and of the numpy
k-NN on the same reference set (:func:`edge.classify.classifier.classifier_latency`) to the report.
"""

from __future__ import annotations

import logging
from typing import Any, Callable

import numpy as np
import scipy.fft
import scipy.signal

log = logging.getLogger(__name__)

#: one line for the report
PEER_DESCRIPTION = ("float64 numpy range-Doppler map, scikit-learn DBSCAN, product features/alpha-beta, "
                    "scikit-learn KNeighborsClassifier(weights='distance')")

#: why the peer could not be built (``None`` when it could); read by the bench report
PEER_UNAVAILABLE: str | None = None


def fft_bound(frontend: Any, config: Any = None) -> Callable[[Any], np.ndarray]:
    """Channel 0 to complex64, range FFT zero-padded to N_R (positive half kept), Doppler FFT to N_D."""
    n_r, n_d = _fft_sizes(config)
    buf = np.empty(frontend.frame_shape[1:], dtype=np.complex64)
    half = n_r // 2

    def run(frame: Any) -> np.ndarray:
        buf.real = frame.i[0]
        buf.imag = frame.q[0]
        rng = scipy.fft.fft(buf, n=n_r, axis=1, workers=1)[:, :half]
        return scipy.fft.fft(rng, n=n_d, axis=0, workers=1)

    return run


def _fft_sizes(config: Any) -> tuple[int, int]:
    if config is None:
        from edge.pipelines.surveillance import SurveillanceConfig

        sc = SurveillanceConfig()
    else:
        sc = config.section("pipeline.surveillance")
    return int(sc.n_range_fft), int(sc.n_doppler_fft)


class SklearnKnn:
    """scikit-learn ``KNeighborsClassifier(weights='distance')`` behind a ``StandardScaler`` with the
    interface the surveillance tracker calls (``classes``, ``predict_proba``, ``predict`` -> indices)."""

    def __init__(self, ref: Any, k: int) -> None:
        from sklearn.neighbors import KNeighborsClassifier
        from sklearn.pipeline import make_pipeline
        from sklearn.preprocessing import StandardScaler

        self.classes = tuple(ref.classes)
        self.model = make_pipeline(StandardScaler(), KNeighborsClassifier(n_neighbors=k, weights="distance"))
        self.model.fit(np.asarray(ref.features, dtype=np.float64), np.asarray(ref.labels))
        self._cols = np.asarray(self.model.classes_, dtype=np.intp)

    def predict_proba(self, x: np.ndarray) -> np.ndarray:
        p = self.model.predict_proba(np.atleast_2d(x))
        out = np.zeros((p.shape[0], len(self.classes)))
        out[:, self._cols] = p
        return out

    def predict(self, x: np.ndarray) -> np.ndarray:
        return np.argmax(self.predict_proba(x), axis=1)


def peer_map(frontend: Any, sc: Any) -> Callable[[Any], np.ndarray]:
    """The peer's float64 range-Doppler magnitude map ``(N_R/2, N_D)`` (``sc``: the
    ``pipeline.surveillance`` section): ``lfilter`` canceller, Kaiser windows, ``numpy.fft.fft2``."""
    seg = frontend.waveform.segments[0]
    n_c, n_s = seg.n_chirps, seg.n_samples
    n_r, n_d = int(sc.n_range_fft), int(sc.n_doppler_fft)
    half = n_r // 2
    w_r = scipy.signal.windows.kaiser(n_s, sc.k_sf)
    w_d = scipy.signal.windows.kaiser(n_c - 1, sc.k_sf)
    win = np.outer(w_d, w_r)
    scale = 1.0 / (w_r.sum() * w_d.sum())
    k_c = float(sc.k_c)

    def run(frame: Any) -> np.ndarray:
        q = frame.i[0].astype(np.float64) + 1j * frame.q[0].astype(np.float64)  # (N_c, N_s)
        w_init = q[0] / (1.0 - k_c)  # step initialisation: u[0] = 0
        w = scipy.signal.lfilter([1.0], [1.0, -k_c], q, axis=0, zi=(k_c * w_init)[None, :])[0]
        u = np.diff(w, axis=0)  # u[n] = w[n] - w[n-1], n >= 1 (u[0] = 0 dropped)
        rd = np.fft.fft2(u * win, s=(n_d, n_r))[:, :half]
        return np.fft.fftshift(np.abs(rd) * scale, axes=0).T  # (range, Doppler)

    return run


def peer(frontend: Any, config: Any) -> Callable[[Any], Any] | None:
    """The peer pipeline (module docstring) as ``f(frame) -> (tracks, classified events)``; ``None``
    when scikit-learn is not installed."""
    global PEER_UNAVAILABLE
    try:
        from sklearn.cluster import DBSCAN
    except ImportError as exc:
        PEER_UNAVAILABLE = f"scikit-learn is not installed ({exc}); pip install scikit-learn"
        log.warning("surveillance peer pipeline unavailable: %s", PEER_UNAVAILABLE)
        return None
    PEER_UNAVAILABLE = None

    from edge.classify.features import MapPoints
    from edge.classify.reference import load_reference_set
    from edge.track.surveillance import SurveillanceTracker
    from hal.waveform import SPEED_OF_LIGHT_MPS

    sc = config.section("pipeline.surveillance")
    kc = config.section("classify.knn")
    wf = frontend.waveform
    seg = wf.segments[0]
    n_r, n_d = int(sc.n_range_fft), int(sc.n_doppler_fft)
    half = n_r // 2
    rd_map = peer_map(frontend, sc)
    range_m = np.arange(half) * seg.sample_rate_hz / n_r * SPEED_OF_LIGHT_MPS / (2.0 * abs(seg.slope_hz_per_s))
    v_max_kmh = wf.wavelength_m / (4.0 * seg.pri_s) * 3.6
    speed_kmh = (np.arange(n_d) - n_d // 2) * wf.wavelength_m / (2.0 * n_d * seg.pri_s) * 3.6
    theta = 2.0 * np.pi * np.arange(n_d) / n_d
    radius = v_max_kmh / np.pi
    dbscan = DBSCAN(eps=sc.eps, min_samples=sc.min_points)
    clf = SklearnKnn(load_reference_set(kc.reference_set or None), kc.k)
    tracker = SurveillanceTracker(
        frontend, sc.th_rd, tracking=config.section("track.alphabeta"), events=config.section("track.events"),
        features=config.section("classify.features"), knn=clf)
    period_ns = int(round(wf.frame_period_s * 1e9))

    def run(frame: Any) -> tuple:
        amp = rd_map(frame)
        rb, db = np.nonzero(amp >= sc.th_rd)
        if rb.size:
            pts3 = np.column_stack([radius * np.cos(theta[db]), radius * np.sin(theta[db]), range_m[rb]])
            labels = dbscan.fit_predict(pts3).astype(np.int32)
        else:
            labels = np.zeros(0, np.int32)
        pts = MapPoints(range_m[rb].astype(np.float32), speed_kmh[db].astype(np.float32),
                        amp[rb, db].astype(np.float32), rb.astype(np.int32), db.astype(np.int32), labels)
        step = tracker.update(frame.seq * period_ns, pts, level=float(amp.max()))
        # provisional class of every live track, as the product publishes it
        feats = [a.features() for tid, a in tracker._acc.items() if a.n >= 2]
        feats = [f for f in feats if np.all(np.isfinite(f))]
        provisional = clf.predict_proba(np.asarray(feats)) if feats else None
        return step.tracks, step.classifications, provisional

    return run


def extras(frontend: Any, config: Any, *, queries: int = 2000) -> dict[str, Any]:
    """``classifier_latency``: per-query latency of the configured ONNX model and of the numpy k-NN."""
    from edge.classify.classifier import classifier_latency

    try:
        return {"classifier_latency": classifier_latency(config, queries=queries)}
    except (OSError, ValueError, RuntimeError) as exc:  # a missing/corrupt model is reported, not fatal here
        log.warning("classifier latency not measured: %s", exc)
        return {"classifier_latency": {"error": str(exc)}}
