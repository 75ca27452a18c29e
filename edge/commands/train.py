"""``radar-edge train``: build a reference set, tune and export the surveillance classifier."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from edge.commands.common import add_config_arguments, config_from_args

NAME = "train"
HELP = "train the surveillance classifier (grid search + 3-fold CV) and export it to ONNX"
DESCRIPTION = """\
Tavanti §III-C on your data: turns labelled single-target events into the feature vectors of
eq. 19 plus the range extent (a site's own recordings, for recalibration at a new site, or a synthetic set from the
simulated Distance2Go), searches k in [1, 50] x {Euclidean, Manhattan, Chebyshev} with stratified
3-fold cross-validation and class-balancing weights, fits the weighted k-NN (eqs. 20-21) on the
whole set with the best pair, and writes to --out:

  reference_set.npz   the feature vectors (edge.classify.reference format)
  model.onnx          the classifier for the device (use: --set classify.onnx.model=OUT/model.onnx)
  report.json/.txt    chosen k and metric, CV score table, out-of-fold (and test) confusion matrices
  reference_pca.png   the reference set on its first three principal components (Tavanti Fig. 7)

Data sources (one of):
  --synthetic N --seed S    N simulated single-target events, classes balanced
  --recordings PATH ...     .npz recordings of single-target events; the class is the directory
                            name (PATH/<class>/*.npz), --label CLASS, or the recording's ground truth
  --reference FILE.npz      an existing reference set

A test set (--test-synthetic N / --test-reference FILE) is classified by the trained model and
reported as a confusion matrix (Tavanti Table IV); with --drop-class truck the trucks are left out
of the reference set but not the test set, so they show up as the nearest remaining class
(Table V). Confusion matrices: rows = true class, columns = predicted."""
EPILOG = """\
examples:
  radar-edge train --synthetic 200 --seed 1 --out out/train
  radar-edge train --recordings site/ --out site-model            # site/car/*.npz, site/pedestrian/*.npz ...
  radar-edge train --reference edge/data/reference_set.npz --drop-class truck \\
                   --test-synthetic 20 --test-seed 7 --out out/no-trucks      # Tavanti Table V
  radar-edge train --reference ref.npz --ks 1-30 --metrics euclidean --out out/quick --no-plot
"""


def _ks(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        try:
            a, b = int(lo), int(hi or lo)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected k values like 1-50 or 1,3,5; got {text!r}") from None
        if a < 1 or b < a:
            raise argparse.ArgumentTypeError(f"bad k range {part!r}")
        out.extend(range(a, b + 1))
    return sorted(set(out))


def add_arguments(p: argparse.ArgumentParser) -> None:
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--synthetic", type=int, metavar="N",
                     help="simulate N single-target events (rounded up to a multiple of 4: classes balanced)")
    src.add_argument("--recordings", nargs="+", metavar="PATH", help="recordings (.npz) or directories of them")
    src.add_argument("--reference", metavar="FILE.npz", help="an existing reference set")
    p.add_argument("--seed", type=int, default=1, help="seed of the synthetic events (default 1)")
    p.add_argument("--label", metavar="CLASS", help="class of every recording given (else directory name or truth)")
    p.add_argument("--drop-class", action="append", default=[], metavar="CLASS",
                   help="leave this class out of the reference set (not out of the test set; repeatable)")
    test = p.add_mutually_exclusive_group()
    test.add_argument("--test-synthetic", type=int, metavar="N", help="also classify N simulated test events")
    test.add_argument("--test-reference", metavar="FILE.npz", help="also classify this labelled set")
    p.add_argument("--test-seed", type=int, default=1001, help="seed of the synthetic test events (default 1001)")
    p.add_argument("--ks", type=_ks, default=list(range(1, 51)), help="k grid, e.g. 1-50 or 1,3,5 (default 1-50)")
    p.add_argument("--metrics", nargs="+", choices=("euclidean", "manhattan", "chebyshev"),
                   default=["euclidean", "manhattan", "chebyshev"], help="metric grid (default all three)")
    p.add_argument("--folds", type=int, default=3, help="cross-validation folds (default 3, the paper's)")
    p.add_argument("--cv-seed", type=int, default=0, help="seed of the fold assignment (default 0)")
    p.add_argument("--weighting", choices=("balanced", "uniform"), default="balanced",
                   help="reference weights of eqs. 20-21 (default balanced: every class weighs the same)")
    p.add_argument("--score", choices=("balanced_accuracy", "accuracy"), default="balanced_accuracy",
                   help="CV score to maximise (default balanced_accuracy)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--model", metavar="FILE.onnx", help="model path (default OUT/model.onnx)")
    p.add_argument("--no-plot", action="store_true", help="skip the principal-component plot")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_config_arguments(p)


def run(args: argparse.Namespace) -> int:
    from edge.extras import available, install_hint, require

    require("onnx", "train")  # it exports the trained model
    from edge.classify.modelio import export_knn, parity_check
    from edge.classify.onnx_runtime import OnnxKnnClassifier
    from edge.classify.reference import load_reference_set, save_reference_set
    from edge.classify.training import drop_classes, format_report, plot_reference_pca, train

    cfg = config_from_args(args)
    progress = not args.no_progress and sys.stderr.isatty()
    if progress and not available("tqdm"):
        logging.getLogger(__name__).warning("no progress bar: tqdm is not installed (%s)", install_hint("tqdm"))
        progress = False
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.folds < 2:
        raise ValueError("--folds must be at least 2")

    if args.reference:
        ref = load_reference_set(args.reference)
    else:
        from edge.classify import datasets

        if args.synthetic is not None:
            if args.synthetic < 4 * args.folds:
                raise ValueError(f"--synthetic needs at least {4 * args.folds} events for {args.folds}-fold CV")
            ref = datasets.synthetic_reference_set(args.synthetic, args.seed, cfg, progress=progress)
        else:
            ref = datasets.recordings_reference_set(args.recordings, cfg, label=args.label, progress=progress)
        save_reference_set(ref, out / "reference_set.npz")
    full_ref = ref
    if args.drop_class:
        ref = drop_classes(ref, args.drop_class)

    test = None
    if args.test_reference:
        test = load_reference_set(args.test_reference)
    elif args.test_synthetic:
        from edge.classify import datasets

        test = datasets.synthetic_reference_set(args.test_synthetic, args.test_seed, cfg, progress=progress)
        save_reference_set(test, out / "test_set.npz")

    from edge.classify.onnx_export import reference_set_hash

    feats = cfg.section("classify.knn").features  # the features the k-NN compares
    ref = ref.select(feats)
    if test is not None:
        test = test.select(feats)
    h = reference_set_hash(ref.features, ref.labels, ref.classes, ref.feature_names)
    knn, rep = train(ref, ks=args.ks, metrics=tuple(args.metrics), n_folds=args.folds, cv_seed=args.cv_seed,
                     weighting=args.weighting, score=args.score, test=test, reference_sha256=h)
    model_path = Path(args.model) if args.model else out / "model.onnx"
    build = {"command": "radar-edge train", "source": ("synthetic" if args.synthetic is not None else
                                                       "recordings" if args.recordings else "reference"),
             "seed": args.seed if args.synthetic is not None else None, "n_events": len(full_ref),
             "dropped_classes": list(args.drop_class), "cv_score": round(rep.cv_score, 6),
             "score": rep.score_name, "folds": args.folds, "cv_seed": args.cv_seed, "features": list(feats)}
    res = export_knn(knn, ref, model_path, weighting=args.weighting, build=build)
    model = OnnxKnnClassifier(model_path, threads=cfg.section("classify.onnx").threads)
    chk = parity_check(knn, model, ref.features, n_random=2000, seed=0)
    rep.extra.update({"model": str(model_path), "model_bytes": res.path.stat().st_size, "parity": chk})
    if not args.no_plot:
        try:
            png = plot_reference_pca(knn, out / "reference_pca.png",
                                     title=f"reference set ({len(ref)} vectors) on its first principal components")
            rep.extra["plot"] = str(png)
        except ImportError:
            print("note: matplotlib is not installed (extra `plot`): no reference_pca.png", file=sys.stderr)
    text = format_report(rep)
    (out / "report.txt").write_text(text + "\n", encoding="utf-8")
    (out / "report.json").write_text(json.dumps(rep.as_dict(), indent=2) + "\n", encoding="utf-8")
    print(text)
    print(f"model {model_path} ({res.path.stat().st_size / 1024:.1f} KiB, parity with numpy on {chk['queries']} "
          f"queries), report and plot in {out}/")
    return 0
