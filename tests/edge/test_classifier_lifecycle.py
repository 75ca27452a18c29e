"""Lifecycle on the simulated Distance2Go: recordings -> features -> train -> default model -> pipeline."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from edge.classify.knn import KnnConfig, WeightedKNN
from edge.classify.onnx_runtime import OnnxKnnClassifier, default_model_path
from edge.classify.reference import DEFAULT_CLASSES, default_reference_path, load_reference_set
from edge.cli import main
from edge.config import load_config

onnx = pytest.importorskip("onnx")


def write_event_recordings(root: Path, n_events: int, seed: int) -> list[str]:
    """One recording per single-random event (the frames of its target's passage, as an event
    trigger records them: :func:`hw_sim.events.frame_view` all round), with truth; returns the classes in
    event order."""
    from hal.frame import RawFrame
    from hal.recording import RecordingWriter
    from hw_sim.boards import board_for
    from edge.classify.refgen import PASSAGE_HALF_SECTOR_DEG
    from hw_sim.events import SLOT_S, frame_view, single_random
    from hw_sim.simulator import FrameSimulator

    scenario = single_random(events=n_events)
    board = board_for(scenario.board)
    fe = board.frontend
    scene = scenario.build_scene(seed)
    sim = FrameSimulator(board, scene, seed)
    period = fe.waveform.frame_period_s
    per_slot = int(round(SLOT_S / period))
    classes = []
    for e in range(n_events):
        w = RecordingWriter(fe, meta={"event": e, "seed": seed})
        for n in range(e * per_slot, (e + 1) * per_slot):
            if len(frame_view(scene, n * period, PASSAGE_HALF_SECTOR_DEG)) == 0:
                continue
            f = sim.frame(n)
            w.add(RawFrame(seq=n, t_ns=int(round(f.t_s * 1e9)), i=f.i, q=f.q, frontend=fe, truth=f.truth))
        classes.append(w._frames[0].truth.cls[0] if len(w) else None)
        if len(w):
            w.save(root / f"event_{e:03d}.npz")
    return classes


def test_recordings_give_the_synthetic_builders_features(tmp_path):
    """A site's recordings of single-target events and the synthetic builder take the same path:
    the same events give the same feature vectors."""
    from edge.classify.datasets import recordings_reference_set
    from edge.classify.refgen import build_reference_set

    cfg = load_config(env={})
    write_event_recordings(tmp_path, 8, seed=77)
    ref_rec = recordings_reference_set([tmp_path], cfg)  # labels from the recordings' ground truth
    # the recordings are of the evaluation generator's keep-right road
    ref_syn = build_reference_set(events_per_class=2, seed=77, config=cfg, vehicle_lanes="keep_right")
    np.testing.assert_array_equal(ref_rec.labels, ref_syn.labels)
    np.testing.assert_allclose(ref_rec.features, ref_syn.features, rtol=1e-6)
    forced = recordings_reference_set([sorted(tmp_path.glob("*.npz"))[0]], cfg, label="truck")
    assert forced.labels.tolist() == [DEFAULT_CLASSES.index("truck")]
    with pytest.raises(ValueError, match="unknown class"):
        recordings_reference_set([tmp_path], cfg, label="tram")
    # the command on a directory of recordings (2 events per class: 2-fold CV)
    out = tmp_path / "site-model"
    assert main(["train", "--recordings", str(tmp_path), "--folds", "2", "--ks", "1-3", "--no-plot", "--no-progress",
                 "--out", str(out)]) == 0
    saved = load_reference_set(out / "reference_set.npz")
    np.testing.assert_array_equal(saved.features, ref_rec.features)
    assert saved.meta["generator"] == "recordings" and len(saved.meta["files"]) == len(ref_rec)
    OnnxKnnClassifier(out / "model.onnx", expected_classes=DEFAULT_CLASSES)


def test_train_command_on_synthetic_events_is_seeded(tmp_path, capsys):
    args = ["train", "--synthetic", "16", "--seed", "5", "--ks", "1-10", "--no-plot", "--no-progress"]
    assert main(args + ["--out", str(tmp_path / "a")]) == 0
    assert main(args + ["--out", str(tmp_path / "b")]) == 0
    a = json.loads((tmp_path / "a" / "report.json").read_text())
    b = json.loads((tmp_path / "b" / "report.json").read_text())
    assert a["reference_sha256"] == b["reference_sha256"] and (a["k"], a["metric"]) == (b["k"], b["metric"])
    assert a["cv_table"] == b["cv_table"]
    assert sum(a["class_counts"].values()) >= 12
    ref = load_reference_set(tmp_path / "a" / "reference_set.npz")
    assert ref.meta["seed"] == 5
    m = OnnxKnnClassifier(tmp_path / "a" / "model.onnx", expected_classes=DEFAULT_CLASSES)
    assert m.metadata["build"]["seed"] == 5 and m.k == a["k"]


def test_shipped_default_model_is_the_documented_command_output(tmp_path, capsys):
    """`radar-edge export-onnx --out edge/data/knn_default.onnx` rebuilds the packaged model: same
    reference-set hash, same parameters, same bytes (when built by the same version)."""
    shipped = default_model_path()
    assert shipped.is_file(), "edge/data/knn_default.onnx is missing: run radar-edge export-onnx --out it"
    rebuilt = tmp_path / "knn_default.onnx"
    assert main(["export-onnx", "--out", str(rebuilt), "--check", "1000"]) == 0
    a, b = OnnxKnnClassifier(shipped, expected_classes=DEFAULT_CLASSES), OnnxKnnClassifier(rebuilt)
    assert a.reference_sha256 == b.reference_sha256
    assert a.metadata["build"] == b.metadata["build"]
    kc = KnnConfig()
    assert (a.k, a.metric, a.metadata["weighting"]) == (kc.k, kc.metric, kc.weighting)
    assert a.feature_names == kc.features
    if a.metadata["version"] == b.metadata["version"]:
        assert shipped.read_bytes() == rebuilt.read_bytes()
    assert shipped.stat().st_size < 64 * 1024
    # and it is the packaged reference set's classifier
    ref = load_reference_set(default_reference_path()).select(kc.features)
    knn = WeightedKNN.from_reference_set(ref, k=kc.k, metric=kc.metric, weighting=kc.weighting)
    q = ref.features.astype(np.float32)
    np.testing.assert_array_equal(a.predict(q), knn.predict(q))
    np.testing.assert_allclose(a.predict_proba(q), knn.predict_proba(q), atol=1e-6)


def test_default_configuration_loads_the_shipped_model():
    from edge.classify.classifier import build_classifier

    clf = build_classifier(load_config(env={}))
    assert isinstance(clf.classifier, OnnxKnnClassifier) and clf.path == default_model_path()
    assert clf.feature_names == KnnConfig().features


def _classifications(backend: str, frames: list, fe) -> list:
    from edge.pipeline import StageTimer, build_pipeline

    cfg = load_config(env={}, overrides={"classify.onnx.backend": backend})
    pipe = build_pipeline("surveillance", fe, cfg)
    timer = StageTimer(window=64)
    out = []
    for fr in frames:
        out.extend(pipe.process(fr, timer).classifications)
    out.extend(pipe.flush())
    return out


@pytest.mark.parametrize("scenario,events", [("tavanti-test1", None), ("tavanti-test2", None), ("tavanti-test3", None),
                                             ("multi-random", 3)])
def test_surveillance_pipeline_identical_with_onnx_and_numpy(scenario, events):
    from hal.frame import RawFrame
    from hw_sim.scenario import load_scenario_for_eval
    from hw_sim.simulator import FrameSimulator

    # figure measured on the v1 instrument; the corpus reports the physical defaults
    sc = load_scenario_for_eval(scenario, events=events, patch={"physics": {"preset": "v1"}})
    board = sc.sim_board()
    fe = board.frontend
    period = fe.waveform.frame_period_s
    sim = FrameSimulator(board, sc.build_scene(sc.seed), sc.seed)
    frames = []
    for n in range(int(round(sc.duration_s / period))):
        f = sim.frame(n)
        frames.append(RawFrame(seq=n, t_ns=int(round(n * period * 1e9)), i=f.i, q=f.q, frontend=fe))
    a = _classifications("onnx", frames, fe)
    b = _classifications("numpy", frames, fe)
    assert len(a) >= 2 and len(a) == len(b)
    for ea, eb in zip(a, b):
        assert (ea.track_id, ea.cls, ea.start_ns, ea.end_ns, ea.direction) == (eb.track_id, eb.cls, eb.start_ns,
                                                                               eb.end_ns, eb.direction)
        assert ea.features == eb.features and ea.mean_radial_speed_kmh == eb.mean_radial_speed_kmh
        assert ea.probabilities.keys() == eb.probabilities.keys()
        for k in ea.probabilities:
            assert ea.probabilities[k] == pytest.approx(eb.probabilities[k], abs=1e-12)


def test_classifier_latency_for_bench():
    from edge.classify.classifier import classifier_latency

    rep = classifier_latency(load_config(env={}), queries=50)
    assert rep["k"] == 13 and rep["reference_size"] == len(load_reference_set())
    assert rep["onnxruntime"]["p50_us"] > 0 and rep["numpy"] is not None and rep["numpy"]["p50_us"] > 0
