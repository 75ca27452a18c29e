"""``radar-edge export-onnx``: write a reference set's weighted k-NN as an ONNX model."""

from __future__ import annotations

import argparse
import json

from edge.commands.common import add_config_arguments, config_from_args

NAME = "export-onnx"
HELP = "export a reference set's weighted k-NN (eqs. 20-21) to the ONNX model the device runs"
DESCRIPTION = """\
Fits the weighted k-NN of Tavanti eqs. 20-21 on a reference set (.npz, edge.classify.reference
format; default: classify.knn.reference_set, i.e. the packaged synthetic set) with the given k,
metric and weighting (defaults: classify.knn, the paper's k = 13, Euclidean, class-balancing
weights) and writes one ONNX graph: float32 features [N, 5] in, label [N] and probabilities [N, C]
out, the standardisation of eq. 20 folded in, k nearest by TopK (ties to the lower reference
index), the weighted vote of eq. 21. Metadata: classes, feature names and units, k, metric, the
SHA-256 of the reference set and the project version.

After writing, the model is loaded with onnxruntime and checked against the numpy k-NN on every
reference vector and --check random vectors (labels equal, probabilities within 1e-6); a mismatch
is an error. Building needs the `onnx` package (extra `train`); running it only onnxruntime.

The packaged default model edge/data/knn_default.onnx is built by exactly:
  radar-edge export-onnx --out edge/data/knn_default.onnx
from the packaged synthetic reference set edge/data/reference_set.npz (tracked single-target events on
simulated boards of -6..+6 dB gain, 150 per class, seed 90210, rebuilt by
`PYTHONPATH=. python -c "from edge.classify.refgen import write_default; write_default()"`) with
the paper's k = 13, Euclidean, so the ONNX and numpy backends agree by default."""
EPILOG = """\
examples:
  radar-edge export-onnx --out edge/data/knn_default.onnx          # the packaged default model
  radar-edge export-onnx --reference site/reference_set.npz --k 9 --metric manhattan --out site.onnx
  radar-edge export-onnx --drop-class truck --k 4 --out no-trucks.onnx   # Tavanti Table V set-up
  radar-edge export-onnx --out /tmp/m.onnx --latency 2000          # also time onnxruntime vs numpy
  radar-edge run --source sim://d2g --set classify.onnx.model=site.onnx   # use it
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--reference", metavar="FILE.npz", help="reference set (default: classify.knn.reference_set)")
    p.add_argument("--k", type=int, help="number of neighbours (default: classify.knn.k)")
    p.add_argument("--metric", choices=("euclidean", "manhattan", "chebyshev"), help="default: classify.knn.metric")
    p.add_argument("--weighting", choices=("balanced", "uniform"), help="default: classify.knn.weighting")
    p.add_argument("--drop-class", action="append", default=[], metavar="CLASS",
                   help="leave this class's vectors out (kept in the class list; repeatable)")
    p.add_argument("--out", required=True, metavar="FILE.onnx", help="model file to write")
    p.add_argument("--check", type=int, default=10_000, metavar="N",
                   help="random vectors for the parity check against numpy (default 10000; 0 = reference only)")
    p.add_argument("--latency", type=int, default=0, metavar="N",
                   help="also time N single-vector queries with onnxruntime and numpy")
    add_config_arguments(p)


def run(args: argparse.Namespace) -> int:
    from edge.extras import require

    require("onnx", "export-onnx")
    from edge.classify.modelio import build_and_export, parity_check
    from edge.classify.onnx_runtime import OnnxKnnClassifier, query_latency

    cfg = config_from_args(args)
    kc = cfg.section("classify.knn")
    reference = args.reference if args.reference is not None else kc.reference_set
    res = build_and_export(
        reference, args.out, k=args.k or kc.k, metric=args.metric or kc.metric,
        weighting=args.weighting or kc.weighting, drop=args.drop_class, features=kc.features,
        build={"command": "radar-edge export-onnx", "reference": reference or "packaged default",
               "dropped_classes": list(args.drop_class), "features": list(kc.features)},
    )
    model = OnnxKnnClassifier(args.out, threads=cfg.section("classify.onnx").threads)
    chk = parity_check(res.knn, model, res.reference.features, n_random=args.check, seed=0)
    size = res.path.stat().st_size
    print(f"wrote {res.path} ({size / 1024:.1f} KiB): k={res.knn.k} {res.knn.metric}, {res.knn.z_.shape[0]} reference "
          f"vectors ({', '.join(f'{c} {n}' for c, n in res.reference.class_counts().items())}), features "
          f"{', '.join(res.reference.feature_names)}")
    print(f"reference sha256 {res.reference_sha256}")
    print(f"parity with numpy: {chk['queries']} queries, labels equal, max |dp| {chk['max_abs_dp']:.1e}")
    if args.latency:
        lat = query_latency(model, res.knn, queries=args.latency)
        print("per-query latency (1 vector, 1 thread): " + json.dumps(
            {k: {kk: round(vv, 1) for kk, vv in v.items()} for k, v in lat.items() if isinstance(v, dict)}))
    return 0
