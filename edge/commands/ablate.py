"""``radar-edge ablate``: an evaluation corpus once as configured and once per rule switched off, paired."""

from __future__ import annotations

import argparse
import sys

from edge.commands.common import add_config_arguments, config_from_args, emit_json

NAME = "ablate"
HELP = "rule ablation: run a corpus once per rule switched off and tabulate each metric's paired difference"
DESCRIPTION = """\
Runs one part of an evaluation corpus (edge.evaluation.corpus) as configured (the baseline) and once per rule
switched off (--rule SECTION.KEY=VALUE, one rule each, or the [[rule]] tables of --rules FILE, each a name and the
settings that switch it off). Every run is paired with its baseline run by (run, seed, variant). Per rule and
metric the table gives the pooled baseline (ratio of sums over runs), the pooled ablated figure, their difference
(ablated - baseline) and the difference's 95 % interval from a paired cluster bootstrap over (scenario, seed):
a rule whose removal moves no figure beyond its interval is not earning its keep on this corpus."""
EPILOG = """\
examples:
  radar-edge ablate --corpus corpus/lane.toml --part dev --rule pipeline.lane.unalias_by_lane=false --jobs 2
  radar-edge ablate --corpus corpus/lane.toml --rules corpus/lane-rules.toml --jobs 2 --json out/ablation.json
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--corpus", required=True, metavar="FILE", help="an evaluation corpus file (TOML)")
    p.add_argument("--part", choices=("dev", "holdout"), default="dev", help="which part to run (default dev)")
    p.add_argument("--rule", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="a rule switched off by this setting (repeatable: one rule each)")
    p.add_argument("--rules", metavar="FILE", help="a rules file of [[rule]] tables (name, set = [...])")
    p.add_argument("--jobs", type=int, default=1, metavar="N", help="worker processes (default 1)")
    p.add_argument("--json", metavar="OUT", help="write the document here (default: print it)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_config_arguments(p)


def run(args: argparse.Namespace) -> int:
    from edge.evaluation.ablation import ablation_document, check_rules, console_table, load_rules, rule_from_assignment
    from edge.evaluation.corpus import check_scenarios, load_corpus, run_jobs

    rules = [rule_from_assignment(r) for r in args.rule] + (load_rules(args.rules) if args.rules else [])
    if not rules:
        print("radar-edge ablate: give at least one --rule or --rules FILE", file=sys.stderr)
        return 2
    if args.jobs < 1:
        print("radar-edge ablate: --jobs must be at least 1", file=sys.stderr)
        return 2
    config_from_args(args)  # a bad --config or --set stops here
    check_rules(rules)
    corpus = load_corpus(args.corpus)
    check_scenarios(corpus, args.part)
    base_jobs = [dict(j, config=args.config, extra_set=list(args.set)) for j in corpus.jobs(args.part)]
    if not base_jobs:
        print(f"radar-edge ablate: the corpus has no {args.part} runs", file=sys.stderr)
        return 2
    jobs = list(base_jobs)
    for rule in rules:
        # the rule's settings come last: they switch the rule off whatever the variant or --set says
        jobs += [dict(j, extra_set=list(args.set) + list(rule.set), rule=rule.name) for j in base_jobs]
    results = run_jobs(jobs, args.jobs, progress=not args.no_progress, desc=f"ablate {args.part}", share_frames=True,
                       label=lambda j: f"{j.get('rule', 'baseline')}: {j['scenario']} seed {j['seed']} {j['variant']}")
    n = len(base_jobs)
    base = results[:n]
    ablated = {rule.name: results[n * (i + 1): n * (i + 2)] for i, rule in enumerate(rules)}
    doc = ablation_document(corpus, args.part, rules, base, ablated, list(args.set))
    emit_json(doc, args.json)
    print(console_table(doc), file=sys.stdout if args.json else sys.stderr)
    return 0
