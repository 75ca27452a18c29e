"""Training (grid search + CV report), the train/export-onnx commands and the classifier factory."""

from __future__ import annotations

import json

import numpy as np
import pytest

from edge.classify.knn import WeightedKNN
from edge.classify.reference import ReferenceSet, save_reference_set
from edge.classify.train import stratified_folds
from edge.classify.training import confusion_matrix, drop_classes, format_report, reference_pca, train
from edge.cli import main
from edge.config import load_config

pytest.importorskip("onnx")

CLASSES = ("pedestrian", "car", "motorcycle", "truck")
UNITS = np.array([0.1, 0.02, 3e3, 1e7, 15.0, 2.0])
OFFSET = np.array([0.4, 0.03, 5e3, 2e7, 25.0, 5.0])
#: class centres in standard units: trucks sit next to cars (Tavanti Fig. 7: they overlap)
CENTRES = np.array([[-3.0, 2.0, -2.0, -2.0, -3.0, -2.0], [1.0, -1.0, 1.0, 1.0, 1.0, 0.5],
                    [0.0, 2.0, 0.0, 0.0, 2.0, -0.5], [1.8, -1.6, 2.2, 2.2, 0.6, 1.2]])
F = CENTRES.shape[1]


def make_set(seed: int, counts=(31, 88, 56, 7), spread: float = 0.6) -> ReferenceSet:
    rng = np.random.default_rng(seed)
    x = np.concatenate([CENTRES[c] + spread * rng.normal(size=(n, F)) for c, n in enumerate(counts)])
    y = np.concatenate([np.full(n, c) for c, n in enumerate(counts)])
    return ReferenceSet(x * UNITS + OFFSET, y, CLASSES, meta={"generator": "test blobs", "seed": seed})


def test_train_is_seeded_and_its_out_of_fold_predictions_equal_sklearn():
    ref = make_set(1)
    knn, rep = train(ref, ks=range(1, 21), weighting="uniform", score="accuracy", cv_seed=3)
    knn2, rep2 = train(ref, ks=range(1, 21), weighting="uniform", score="accuracy", cv_seed=3)
    assert (rep.k, rep.metric, rep.cv_table) == (rep2.k, rep2.metric, rep2.cv_table)
    assert rep.cv_score == max(max(v) for v in rep.cv_table.values())
    assert set(rep.cv_table) == {"euclidean", "manhattan", "chebyshev"} and len(rep.ks) == 20
    cm = np.asarray(rep.cv_confusion)
    np.testing.assert_array_equal(cm.sum(axis=1), np.bincount(ref.labels, minlength=4))
    assert 0.5 < rep.cv_accuracy <= 1.0
    # scikit-learn on the same folds: uniform weights make eq. 20 a StandardScaler up to one common
    # factor and eq. 21 a plain majority vote
    skm = pytest.importorskip("sklearn.model_selection")
    from sklearn.neighbors import KNeighborsClassifier
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    folds = stratified_folds(ref.labels, 3, 3)
    fold_of = np.empty(len(ref), dtype=int)
    for f, idx in enumerate(folds):
        fold_of[idx] = f
    sk = make_pipeline(StandardScaler(), KNeighborsClassifier(rep.k, metric=rep.metric, algorithm="brute"))
    pred = skm.cross_val_predict(sk, ref.features, ref.labels, cv=skm.PredefinedSplit(fold_of))
    np.testing.assert_array_equal(confusion_matrix(ref.labels, pred, 4), cm)
    # the fitted model is the one of the whole set
    np.testing.assert_array_equal(knn.z_.shape, (len(ref), F))


def test_without_trucks_the_trucks_are_labelled_as_the_nearest_class():
    """Tavanti Table V: trucks left out of the reference set are classified as cars."""
    ref = drop_classes(make_set(2), ["truck"])
    assert ref.class_counts()["truck"] == 0 and ref.classes == CLASSES
    test = make_set(3, counts=(5, 5, 5, 5))
    knn, rep = train(ref, test=test)
    cm = np.asarray(rep.test_confusion)
    assert cm[3].tolist() == [0, 5, 0, 0]  # every truck -> car
    assert cm[:, 3].sum() == 0  # nothing predicted as truck
    assert np.trace(cm[:3, :3]) >= 14
    assert "test set confusion matrix" in format_report(rep)


def test_training_refuses_too_small_or_single_class_sets():
    with pytest.raises(ValueError, match="at least 3 vectors per class"):
        train(make_set(4, counts=(10, 10, 2, 10)))
    with pytest.raises(ValueError, match="two classes"):
        train(make_set(4, counts=(0, 10, 0, 0)))


def test_pca_explains_the_variance_in_order():
    z = np.random.default_rng(0).normal(size=(200, F)) * [5, 3, 1, 0.5, 0.1, 0.2]
    proj, var = reference_pca(z, 3)
    assert proj.shape == (200, 3)
    assert var[0] > var[1] > var[2] and 0.9 < var.sum() <= 1.0
    np.testing.assert_allclose(np.var(proj, axis=0) / np.var(z - z.mean(0), axis=0).sum(), var, rtol=1e-9)


def test_train_command_end_to_end(tmp_path, capsys):
    ref = tmp_path / "ref.npz"
    save_reference_set(make_set(5), ref)
    testset = tmp_path / "test.npz"
    save_reference_set(make_set(6, counts=(5, 5, 5, 5)), testset)
    out = tmp_path / "out"
    assert main(["train", "--reference", str(ref), "--test-reference", str(testset), "--ks", "1-15",
                 "--out", str(out), "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "chosen: k = " in text and "out-of-fold confusion matrix" in text
    rep = json.loads((out / "report.json").read_text())
    from edge.classify.onnx_runtime import OnnxKnnClassifier

    model = OnnxKnnClassifier(out / "model.onnx")
    assert (model.k, model.metric) == (rep["k"], rep["metric"])
    assert model.reference_sha256 == rep["reference_sha256"]
    assert model.metadata["build"]["command"] == "radar-edge train"
    assert rep["extra"]["parity"]["queries"] > 2000
    assert (out / "reference_pca.png").stat().st_size > 10_000
    assert sum(map(sum, rep["test_confusion"])) == 20


def test_export_onnx_command_uses_config_defaults(tmp_path, capsys):
    ref = tmp_path / "ref.npz"
    save_reference_set(make_set(7), ref)
    p = tmp_path / "m.onnx"
    assert main(["export-onnx", "--reference", str(ref), "--out", str(p), "--check", "300", "--set",
                 "classify.knn.metric=chebyshev"]) == 0
    out = capsys.readouterr().out
    assert "parity with numpy: 482 queries" in out
    from edge.classify.onnx_runtime import OnnxKnnClassifier

    m = OnnxKnnClassifier(p)
    assert (m.k, m.metric, m.metadata["weighting"]) == (13, "chebyshev", "balanced")
    assert main(["export-onnx", "--reference", str(ref), "--out", str(p), "--check", "0", "--drop-class", "truck",
                 "--k", "4"]) == 0
    m = OnnxKnnClassifier(p, expected_classes=CLASSES)
    assert m.k == 4 and m.metadata["reference_size"] == str(31 + 88 + 56)
    assert main(["export-onnx", "--reference", str(tmp_path / "missing.npz"), "--out", str(p)]) == 2


def test_classifier_factory_picks_the_backend(tmp_path, caplog):
    from edge.classify.classifier import build_classifier
    from edge.classify.onnx_runtime import ModelError, OnnxKnnClassifier

    ref = tmp_path / "ref.npz"
    save_reference_set(make_set(8), ref)
    p = tmp_path / "m.onnx"
    assert main(["export-onnx", "--reference", str(ref), "--out", str(p), "--check", "0"]) == 0
    cfg = load_config(env={}, overrides={"classify.onnx.model": str(p), "classify.knn.k": "7"})
    clf = build_classifier(cfg)
    assert isinstance(clf.classifier, OnnxKnnClassifier) and clf.k == 13
    assert "classify.knn.k = 7 is ignored" in caplog.text
    cfg = load_config(env={}, overrides={"classify.onnx.backend": "numpy", "classify.knn.reference_set": str(ref)})
    assert isinstance(build_classifier(cfg).classifier, WeightedKNN)
    with pytest.raises(ModelError, match="not found"):
        build_classifier(load_config(env={}, overrides={"classify.onnx.model": str(tmp_path / "none.onnx")}))
