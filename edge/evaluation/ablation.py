"""Rule ablation over an evaluation corpus: the corpus once as configured (the baseline) and once per rule switched
off, each run paired with its baseline run by (run, seed, variant), and per metric the pooled baseline, the pooled
ablated figure and their difference with a paired cluster-bootstrap 95 % interval.

A rule is a name and the configuration changes that switch it off (``SECTION.KEY=VALUE``, as ``--set``). A rules
file (TOML) lists them::

    [[rule]]
    name = "unalias-by-lane"                                     # required, unique
    set = ["pipeline.lane.unalias_by_lane=false"]                # required, non-empty
    description = "move grating-lobe aliases back into a lane of their direction"

Pooling and intervals as in :mod:`edge.evaluation.corpus`: ratios of sums over runs; each bootstrap resample
draws (scenario, seed) clusters with replacement and applies the same draw to the baseline and the ablated runs,
so the difference's interval reflects the pairing (a rule that changes nothing has a difference of exactly 0 and
the interval [0, 0]).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from edge.evaluation.corpus import (METRICS, Corpus, CorpusError, _cluster, _finite, _fmt, _percentile_ci,
                                    read_toml,
                                    resample_weights, run_metrics)


@dataclass(frozen=True)
class Rule:
    name: str
    set: tuple[str, ...]
    description: str = ""


def rule_from_assignment(text: str) -> Rule:
    """``--rule KEY=VALUE``: a rule named by its one assignment."""
    if "=" not in text:
        raise CorpusError(f"--rule expects SECTION.KEY=VALUE, got {text!r}")
    return Rule(text, (text,))


def load_rules(path: str | Path) -> list[Rule]:
    """The ``[[rule]]`` tables of a rules file (module doc)."""
    p = Path(path)
    raw = read_toml(p, "rules file")
    bad = sorted(set(raw) - {"rule"})
    if bad:
        raise CorpusError(f"{p}: unknown table(s) {bad}; a rules file holds [[rule]] tables")
    rules = []
    for i, r in enumerate(raw.get("rule", [])):
        where = f"{p} rule[{i}]"
        extra = sorted(set(r) - {"name", "set", "description"})
        if extra:
            raise CorpusError(f"{where}: unknown key(s) {extra}")
        sets = r.get("set")
        if not isinstance(r.get("name"), str) or not r["name"]:
            raise CorpusError(f"{where}: name is required")
        if not isinstance(sets, list) or not sets or not all(isinstance(x, str) and "=" in x for x in sets):
            raise CorpusError(f"{where} ({r['name']}): set must be a non-empty list of \"section.key=value\" strings")
        rules.append(Rule(r["name"], tuple(sets), str(r.get("description", ""))))
    if not rules:
        raise CorpusError(f"{p}: no [[rule]] tables")
    return rules


def check_rules(rules: list[Rule]) -> None:
    """Rule names unique; each rule's settings must be known configuration keys with valid values."""
    from edge.config import load_config, parse_set_option

    names = [r.name for r in rules]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise CorpusError(f"rules named twice: {dup}")
    for r in rules:
        load_config(None, env={}, overrides=dict(parse_set_option(x) for x in r.set))


def paired_difference(base: list[dict], abl: list[dict], corpus: Corpus, stream: int) -> dict:
    """Per metric: pooled baseline and ablated value, their difference (ablated - baseline) and its paired
    cluster-bootstrap 95 % interval (None with fewer than two seeds)."""
    metrics = METRICS[corpus.profile]
    w = resample_weights([_cluster(r) for r in base], corpus.bootstrap_resamples, corpus.bootstrap_seed, stream)
    out = {}
    for m in metrics:
        nb = np.array([float(r["tallies"].get(m.num, 0.0)) for r in base])
        db = np.array([float(r["tallies"].get(m.den, 0.0)) for r in base])
        na = np.array([float(r["tallies"].get(m.num, 0.0)) for r in abl])
        da = np.array([float(r["tallies"].get(m.den, 0.0)) for r in abl])
        vb = _finite(m.of(nb.sum(), db.sum())) if db.sum() > 0 else None
        va = _finite(m.of(na.sum(), da.sum())) if da.sum() > 0 else None
        rec: dict[str, Any] = {"baseline": vb, "ablated": va,
                               "difference": (va - vb) if va is not None and vb is not None else None, "ci95": None}
        if rec["difference"] is None:
            rec["ci_note"] = "n/a: no data"
        elif w is None:
            rec["ci_note"] = "n/a: one seed"
        else:
            _percentile_ci(rec, m.of(w @ na, w @ da) - m.of(w @ nb, w @ db))
        out[m.name] = rec
    return out


def ablation_document(corpus: Corpus, part: str, rules: list[Rule], base: list[dict],
                      ablated: dict[str, list[dict]], config_set: list[str] | None = None) -> dict:
    """The JSON document of ``radar-edge ablate``: the baseline's runs and, per rule, its runs and the paired
    differences (module doc)."""
    metrics = METRICS[corpus.profile]
    key = lambda r: (r["run"], r["scenario"], r["seed"], r["variant"])  # noqa: E731
    doc: dict[str, Any] = {
        "corpus": corpus.name, "profile": corpus.profile, "source": corpus.source, "part": part,
        "set": list(config_set or []),
        "method": {"pairing": "(run, seed, variant)", "pooling": "ratio of sums over runs",
                   "ci": "95 % percentile, paired cluster bootstrap over (scenario, seed)",
                   "resamples": corpus.bootstrap_resamples, "seed": corpus.bootstrap_seed},
        "metrics": {m.name: {"unit": m.unit, "doc": m.doc} for m in metrics},
        "baseline": {"runs": [dict(r, metrics=run_metrics(r["tallies"], metrics)) for r in base]},
        "rules": [],
    }
    for i, rule in enumerate(rules):
        abl = ablated[rule.name]
        if [key(r) for r in abl] != [key(r) for r in base]:
            raise RuntimeError(f"rule {rule.name!r}: its runs do not pair with the baseline's")
        doc["rules"].append({
            "name": rule.name, "set": list(rule.set), "description": rule.description,
            "runs": [{"run": r["run"], "scenario": r["scenario"], "seed": r["seed"], "variant": r["variant"],
                      "tallies": r["tallies"], "metrics": run_metrics(r["tallies"], metrics)} for r in abl],
            "difference": paired_difference(base, abl, corpus, stream=5000 + i),
        })
    return doc


def console_table(doc: dict) -> str:
    """Per rule and metric: baseline, ablated, difference and its 95 % interval."""
    lines = [f"{doc['corpus']} ({doc['profile']}), part {doc['part']}: {len(doc['baseline']['runs'])} runs per rule; "
             "difference = ablated - baseline [95 % paired cluster-bootstrap interval]"]
    rows = [["rule", "metric", "baseline", "ablated", "difference", "95 % CI"]]
    for r in doc["rules"]:
        for k, (m, d) in enumerate(r["difference"].items()):
            ci = f"[{_fmt(d['ci95'][0])}, {_fmt(d['ci95'][1])}]" if d.get("ci95") else "n/a"
            rows.append([r["name"] if k == 0 else "", m, _fmt(d["baseline"]), _fmt(d["ablated"]),
                         _fmt(d["difference"]), ci])
    w = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines += ["  " + "  ".join(c.ljust(w[i]) for i, c in enumerate(r)).rstrip() for r in rows]
    return "\n".join(lines)
