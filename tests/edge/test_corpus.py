"""The evaluation corpus (edge.evaluation.corpus) and rule ablation (edge.evaluation.ablation), through the CLI on the
CI smoke corpus (corpus/smoke.toml: two seeds x two variants of 40 frames) and on constructed tallies."""

import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from edge.cli import main
from edge.evaluation.corpus import (METRICS, CorpusError, Metric, parse_corpus, pool, pooled_confusion,
                                    resample_weights, run_job, run_job_group, run_metrics)

SMOKE = Path(__file__).resolve().parents[2] / "corpus" / "smoke.toml"
REPO = SMOKE.parent.parent


def _corpus(runs: list[dict], variants: list[dict] | None = None, profile: str = "lane") -> dict:
    return {"corpus": {"name": "t", "profile": profile}, "variant": variants or [{"name": "defaults"}], "run": runs}


def test_smoke_corpus_json_pools_ratio_of_sums_and_does_not_depend_on_jobs(tmp_path, capsys):
    out1, out2, svg = tmp_path / "j1.json", tmp_path / "j2.json", tmp_path / "plot.svg"
    assert main(["evaluate", "--corpus", str(SMOKE), "--part", "dev", "--jobs", "2", "--no-progress",
                 "--json", str(out2), "--plot", str(svg)]) == 0
    table = capsys.readouterr().out
    assert "detection_probability_separate" in table and "95 % CI" in table
    assert main(["evaluate", "--corpus", str(SMOKE), "--part", "dev", "--jobs", "1", "--no-progress",
                 "--json", str(out1)]) == 0
    d1, d2 = json.loads(out1.read_text()), json.loads(out2.read_text())
    assert d1 == d2  # seeded runs and resampling, ordered by the corpus: the worker count changes nothing

    part = d2["parts"]["dev"]
    assert list(d2["parts"]) == ["dev"]
    assert [(r["seed"], r["variant"]) for r in part["runs"]] == [(5, "defaults"), (5, "v1"), (7007, "defaults"),
                                                                 (7007, "v1")]
    names = [m.name for m in METRICS["lane"]]
    assert list(d2["metrics"]) == names
    for r in part["runs"]:
        assert r["frames"] == 40 and r["cold_start"] is True
        assert r["tallies"]["vehicle_frames_in_view"] > 100 and r["tallies"]["minutes"] == pytest.approx(40 * 0.033 / 60)
        assert "false_tracks_first_30s" in r["figures"] and set(r["metrics"]) == set(names)
        # a run's own figure from its tallies equals the evaluation's summary figure
        assert r["metrics"]["detection_probability"] == pytest.approx(r["figures"]["detection_probability"])
        assert r["metrics"]["lane_accuracy"] == pytest.approx(r["figures"]["lane_accuracy"])
    assert set(part["pooled"]["by_variant"]) == {"defaults", "v1"}
    for group, runs in (("all", part["runs"]), ("defaults", part["runs"][0::2])):
        rec = part["pooled"]["all"] if group == "all" else part["pooled"]["by_variant"][group]
        for m in METRICS["lane"]:
            num = sum(r["tallies"][m.num] for r in runs)
            den = sum(r["tallies"][m.den] for r in runs)
            want = math.sqrt(num / den) if m.sqrt else num / den
            assert rec[m.name]["value"] == pytest.approx(want), (group, m.name)
            assert rec[m.name]["runs"] == len(runs) and rec[m.name]["seeds"] == 2
            lo, hi = rec[m.name]["ci95"]
            assert lo <= rec[m.name]["value"] + 1e-12 and rec[m.name]["value"] - 1e-12 <= hi
    # position RMSE over frames within 200 m, speed MAE: sensible magnitudes on this road
    assert 0.0 < part["pooled"]["all"]["position_rmse_m"]["value"] < 2.0
    assert 0.5 < part["pooled"]["all"]["detection_probability_separate"]["value"] <= 1.0
    # visible = separate without the frames another body shadows: the same where the simulator does not shadow (v1)
    for r in part["runs"]:
        t = r["tallies"]
        if r["variant"] == "v1":
            assert (t["visible_frames_in_view"], t["visible_frames_tracked"]) == \
                (t["separate_frames_in_view"], t["separate_frames_tracked"])
        else:
            assert 0 < t["visible_frames_in_view"] <= t["separate_frames_in_view"]
            assert t["visible_frames_tracked"] <= t["separate_frames_tracked"]

    root = ET.parse(svg).getroot()
    texts = [t.text for t in root.iter("{http://www.w3.org/2000/svg}text")]
    assert all(any(t and t.startswith(n) for t in texts) for n in names)  # a panel per metric
    assert len(list(root.iter("{http://www.w3.org/2000/svg}circle"))) >= 3 * len(names)  # dev points + legend


def test_corpus_refuses_seed_shared_between_dev_and_holdout(tmp_path, capsys):
    bad = _corpus([{"part": "dev", "scenario": "highway4-traffic", "seeds": [1, 2], "frames": 10},
                   {"part": "holdout", "scenario": "highway4-traffic", "seeds": [3, 2], "frames": 10}])
    with pytest.raises(CorpusError, match="disjoint seeds.*highway4-traffic seed 2"):
        parse_corpus(bad)
    # the same seed of another scenario is allowed
    ok = _corpus([{"part": "dev", "scenario": "highway4-traffic", "seeds": [1, 2]},
                  {"part": "holdout", "scenario": "wrong-way-traffic", "seeds": [2]}])
    assert len(parse_corpus(ok).jobs("holdout")) == 1
    path = tmp_path / "bad.toml"
    path.write_text('[corpus]\nname = "b"\nprofile = "lane"\n'
                    '[[run]]\npart = "dev"\nscenario = "highway4-traffic"\nseeds = [4]\nframes = 5\n'
                    '[[run]]\npart = "holdout"\nscenario = "highway4-traffic"\nseeds = [4]\nframes = 5\n')
    assert main(["evaluate", "--corpus", str(path), "--part", "holdout", "--no-progress"]) == 2
    assert "disjoint seeds" in capsys.readouterr().err


@pytest.mark.parametrize("change, message", [
    ({"run": [{"part": "dev", "scenario": "x", "seeds": [1], "seed": 3}]}, "unknown key"),
    ({"run": [{"part": "test", "scenario": "x", "seeds": [1]}]}, "part must be one of"),
    ({"run": [{"part": "dev", "scenario": "x", "seeds": [1], "variants": ["nope"]}]}, "unknown variant"),
    ({"run": [{"part": "dev", "scenario": "x", "seeds": [1, 1]}]}, "seeds repeat"),
    ({"run": [{"part": "dev", "scenario": "x", "seeds": [1]}, {"part": "dev", "scenario": "x", "seeds": [1]}]},
     "twice"),
    ({"run": [{"part": "dev", "scenario": "x", "seeds": [1], "frames": 5, "duration_s": 1.0}]}, "not both"),
    ({"run": [{"part": "dev", "scenario": "x", "seeds": [1], "cold_start": False}]}, "not implemented"),
    ({"variant": [{"name": "a"}, {"name": "a"}]}, "used twice"),
    ({"variant": [{"name": "a", "set": ["no-equals"]}]}, "section.key=value"),
])
def test_corpus_schema_errors_name_the_key(change, message):
    raw = _corpus([{"part": "dev", "scenario": "x", "seeds": [1]}])
    raw.update(change)
    with pytest.raises(CorpusError, match=message):
        parse_corpus(raw)


def test_corpus_refuses_a_scenario_of_the_other_profile(tmp_path, capsys):
    path = tmp_path / "c.toml"
    path.write_text('[corpus]\nname = "c"\nprofile = "surveillance"\n'
                    '[[run]]\npart = "dev"\nscenario = "highway4-traffic"\nseeds = [1]\nframes = 5\n')
    assert main(["evaluate", "--corpus", str(path), "--no-progress"]) == 2
    assert "runs the lane profile, the corpus is surveillance" in capsys.readouterr().err
    path.write_text('[corpus]\nname = "c"\nprofile = "lane"\n[[variant]]\nname = "x"\nset = ["track.pdaf.nope=1"]\n'
                    '[[run]]\npart = "dev"\nscenario = "highway4-traffic"\nseeds = [1]\nframes = 5\n')
    assert main(["evaluate", "--corpus", str(path), "--no-progress"]) == 2
    assert "variant 'x'" in capsys.readouterr().err


def test_pooled_proportion_and_its_bootstrap_interval_on_constructed_runs():
    m = Metric("p", "hits", "trials", "", "")
    rng = np.random.default_rng(11)
    p_true = 0.9
    trials = rng.integers(50, 400, size=12)
    runs = [{"hits": int(rng.binomial(t, p_true)), "trials": int(t)} for t in trials]
    w = resample_weights(list(range(12)), 2000, 0, 0)
    rec = pool(runs, [m], w)["p"]
    assert rec["value"] == sum(r["hits"] for r in runs) / sum(r["trials"] for r in runs)  # ratio of sums
    assert rec["value"] != pytest.approx(np.mean([r["hits"] / r["trials"] for r in runs]), abs=1e-9)
    lo, hi = rec["ci95"]
    assert lo < p_true < hi and lo < rec["value"] < hi
    assert 0.005 < hi - lo < 0.08
    # the interval covers the truth in about 95 % of repeated corpora (12 runs each)
    cover = 0
    for k in range(200):
        r2 = np.random.default_rng(1000 + k)
        t2 = r2.integers(50, 400, size=12)
        rs = [{"hits": int(r2.binomial(t, p_true)), "trials": int(t)} for t in t2]
        lo, hi = pool(rs, [m], resample_weights(list(range(12)), 1000, k, 0))["p"]["ci95"]
        cover += lo <= p_true <= hi
    assert 0.86 <= cover / 200 <= 0.99
    # an RMSE pools as sqrt(sum of squares / n)
    rm = Metric("rmse", "sq", "n", "m", "", sqrt=True)
    assert pool([{"sq": 4.0, "n": 1}, {"sq": 14.0, "n": 2}], [rm], None)["rmse"]["value"] == pytest.approx(math.sqrt(6))
    # one run: no interval, and it says so
    one = pool(runs[:1], [m], resample_weights([0], 2000, 0, 0))["p"]
    assert one["ci95"] is None and one["ci_note"] == "n/a: one run"
    assert run_metrics({"hits": 3, "trials": 0}, [m]) == {"p": None}


def test_bootstrap_clusters_are_seeds_not_variants():
    # two variants of each of three seeds: a resample draws seeds, and both variants of a drawn seed come with it
    w = resample_weights([("s", 1), ("s", 1), ("s", 2), ("s", 2), ("s", 3), ("s", 3)], 500, 0, 0)
    assert np.array_equal(w[:, 0], w[:, 1]) and np.array_equal(w[:, 2], w[:, 3])
    assert np.all(w.sum(axis=1) == 6)
    assert resample_weights([("s", 1), ("s", 1)], 500, 0, 0) is None  # one seed: no interval


def test_surveillance_run_job_tallies_match_its_summary():
    job = {"run": 0, "part": "dev", "scenario": "multi-random", "seed": 5, "variant": "defaults", "duration_s": None,
           "frames": None, "events": 1, "cold_start": True, "patch": {}, "set": []}
    r = run_job(job)
    t, f = r["tallies"], r["figures"]
    assert r["profile"] == "surveillance" and t["events"] == 1 and t["targets"] >= 2
    assert t["multi_targets"] == t["targets"] and t["single_targets"] == 0
    got = run_metrics(t, METRICS["surveillance"])
    assert got["classification_accuracy"] == pytest.approx(f["classification_accuracy"])
    assert got["classification_accuracy_multi"] == pytest.approx(f["classification_accuracy"])
    assert got["detection_probability"] == pytest.approx(f["detection_probability"])
    assert got["classification_accuracy_single"] is None
    # the run keeps its per-class confusion matrix: one row per target, the diagonal is the correct ones
    cm = r["confusion_matrix"]
    m = np.asarray(cm["matrix"])
    assert cm["columns"] == cm["labels"] + ["missed"] and m.shape == (len(cm["labels"]), len(cm["labels"]) + 1)
    assert m.sum() == t["targets"] and np.trace(m[:, :-1]) == t["correct"]


def test_confusion_matrices_sum_per_variant_and_scenario():
    def run(variant, scenario, seed, matrix):
        return {"variant": variant, "scenario": scenario, "seed": seed,
                "confusion_matrix": {"labels": ["a", "b"], "columns": ["a", "b", "missed"], "matrix": matrix}}

    rs = [run("defaults", "single-random", 1, [[2, 0, 0], [1, 1, 0]]),
          run("defaults", "single-random", 2, [[1, 1, 0], [0, 2, 1]]),
          run("defaults", "multi-random", 1, [[0, 0, 1], [0, 3, 0]]),
          run("gain-6", "single-random", 1, [[0, 2, 0], [0, 1, 1]]),
          {"variant": "v1", "scenario": "highway4", "seed": 1}]  # no matrix (lane): left out
    got = pooled_confusion(rs)
    assert set(got) == {"defaults", "gain-6"}
    d = got["defaults"]
    assert d["labels"] == ["a", "b"] and d["columns"] == ["a", "b", "missed"]
    assert d["by_scenario"] == {"single-random": [[3, 1, 0], [1, 3, 1]], "multi-random": [[0, 0, 1], [0, 3, 0]]}
    assert d["all"] == [[3, 1, 1], [1, 6, 1]]
    assert got["gain-6"]["all"] == [[0, 2, 0], [0, 1, 1]]
    # the console table prints each variant's summed matrix
    from edge.evaluation.corpus import _confusion_lines

    text = "\n".join(_confusion_lines(got))
    assert "confusion matrix, defaults" in text and "confusion matrix, gain-6" in text
    assert [ln.split() for ln in text.splitlines() if ln.split()[:1] == ["b"]][0] == ["b", "1", "6", "1"]
    bad = run("defaults", "single-random", 3, [[1, 0, 0], [0, 1, 0]])
    bad["confusion_matrix"]["labels"] = ["b", "a"]
    with pytest.raises(ValueError, match="classes differ"):
        pooled_confusion(rs + [bad])


def test_surveillance_corpus_has_the_gain_offsets_of_issue_31():
    from edge.evaluation.corpus import load_corpus

    c = load_corpus(REPO / "corpus" / "surveillance.toml")
    gains = {v.name: v.patch.get("physics", {}).get("gain_offset_db") for v in c.variants}
    assert [gains[n] for n in ("gain-6", "gain-3", "gain+3", "gain+6")] == [-6.0, -3.0, 3.0, 6.0]
    assert c.variants[0].name == "defaults" and not c.variants[0].patch
    assert [n for n, g in gains.items() if g is not None] == ["gain-6", "gain-3", "gain+3", "gain+6"]
    assert {"defaults", "v1", "gain-6"} <= {v.name for v in c.variants}


def test_ablation_of_a_rule_that_changes_nothing_and_of_one_that_does(tmp_path, capsys):
    corpus = tmp_path / "c.toml"
    corpus.write_text('[corpus]\nname = "abl"\nprofile = "lane"\nbootstrap_resamples = 500\n'
                      '[[run]]\npart = "dev"\nscenario = "highway4-traffic"\nseeds = [5, 7007]\nframes = 40\n')
    rules = tmp_path / "rules.toml"
    # a surveillance setting cannot change a lane run; one motion model instead of the IMM changes the tracks
    rules.write_text('[[rule]]\nname = "no-op"\nset = ["pipeline.surveillance.min_points=5"]\n'
                     '[[rule]]\nname = "cv"\nset = ["track.pdaf.motion_model=cv"]\n')
    out = tmp_path / "abl.json"
    assert main(["ablate", "--corpus", str(corpus), "--rules", str(rules), "--jobs", "2", "--no-progress",
                 "--json", str(out)]) == 0
    assert "difference" in capsys.readouterr().out
    doc = json.loads(out.read_text())
    assert [r["name"] for r in doc["rules"]] == ["no-op", "cv"]
    assert len(doc["baseline"]["runs"]) == 2
    noop, cv = (r["difference"] for r in doc["rules"])
    for name, d in noop.items():
        assert d["difference"] == 0.0 and d["ci95"] == [0.0, 0.0], name
    assert [r["tallies"] for r in doc["rules"][0]["runs"]] == [r["tallies"] for r in doc["baseline"]["runs"]]
    changed = [n for n, d in cv.items() if d["difference"] not in (0.0, None)]
    assert changed, cv
    for n in changed:
        assert cv[n]["difference"] == pytest.approx(cv[n]["ablated"] - cv[n]["baseline"])
        lo, hi = cv[n]["ci95"]
        assert lo <= cv[n]["difference"] <= hi


def test_lane_jobs_of_one_world_share_frames_and_report_as_if_simulated_alone():
    base = {"run": 0, "part": "dev", "scenario": "highway4-traffic", "seed": 7007, "variant": "defaults",
            "duration_s": None, "frames": 30, "events": None, "cold_start": True, "patch": {}, "set": []}
    cv = dict(base, extra_set=["track.pdaf.motion_model=cv"])
    alone = [run_job(base), run_job(cv)]
    shared = run_job_group([base, cv])
    assert [r["tallies"] for r in shared] == [r["tallies"] for r in alone]
    assert [r["figures"] for r in shared] == [r["figures"] for r in alone]
    assert alone[0]["tallies"] != alone[1]["tallies"]  # the two configurations differ, so the test can tell


def test_ablate_refuses_an_unknown_setting(tmp_path, capsys):
    assert main(["ablate", "--corpus", str(SMOKE), "--rule", "track.pdaf.no_such_rule=0", "--no-progress"]) == 2
    assert "no_such_rule" in capsys.readouterr().err


@pytest.mark.parametrize("name", sorted(p.name for p in (REPO / "corpus").glob("*.toml") if p.name != "lane-rules.toml"))
def test_shipped_corpora_parse(name):
    """Every corpus file parses and names known scenarios; each has a holdout part, and a dev part except the
    rule ablation's dense-traffic corpus (the lane corpus's holdout seeds only)."""
    from edge.evaluation.corpus import check_scenarios, load_corpus

    c = load_corpus(REPO / "corpus" / name)
    parts = ("dev", "holdout") if name != "lane-ablation.toml" else ("holdout",)
    for part in parts:
        assert c.jobs(part)
    check_scenarios(c, parts)  # each (scenario, variant) loaded once for both parts


@pytest.mark.parametrize("lo, hi", [(0.75, 0.851), (0.0, 0.0), (0.0012, 0.0034), (3.0, 250.0), (-2.0, 0.5)])
def test_plot_axis_ticks_cover_every_value(lo, hi):
    from edge.evaluation.corpus_plot import _nice_ticks

    t = _nice_ticks(lo, hi)
    assert t[0] <= lo and t[-1] >= hi and 3 <= len(t) <= 24
    assert np.allclose(np.diff(t), t[1] - t[0])


def test_shipped_lane_rules_parse_and_each_switch_changes_a_default():
    """corpus/lane-rules.toml: every rule's settings are valid and differ from the running defaults (a rule
    whose 'off' setting equals its default would ablate nothing)."""
    from edge.config import load_config, parse_set_option
    from edge.evaluation.ablation import check_rules, load_rules

    rules = load_rules(REPO / "corpus" / "lane-rules.toml")
    check_rules(rules)
    base = load_config(None, env={})
    assert len({r.name for r in rules}) == len(rules) >= 10
    for r in rules:
        for item in r.set:
            key, val = parse_set_option(item)
            section, _, field = key.rpartition(".")
            off = load_config(None, env={}, overrides={key: val})
            assert getattr(off.section(section), field) != getattr(base.section(section), field), r.name


def test_calibrated_surveillance_corpus_carries_each_boards_measured_c(tmp_path):
    # the calibrated corpus runs the surveillance corpus's seeds and gain offsets, each board at the TX power level
    # `radar-edge calibrate --headroom` picks on the empty site at its offset and with the C that `calibrate --rcs`
    # measures there (C follows the offset less the TX back-off, 1 dB a level)
    import itertools
    from importlib import resources

    from edge.classify.calibration import DATASHEET_C_DB
    from edge.commands.calibrate import adc_headroom, pick_tx_power
    from edge.evaluation.corpus import load_corpus
    from hal import open_radar

    plain = load_corpus(REPO / "corpus" / "surveillance.toml")
    cal = load_corpus(REPO / "corpus" / "surveillance-calibrated.toml")
    key = lambda j: (j["part"], j["scenario"], j["seed"], j["events"])  # noqa: E731
    for part in ("dev", "holdout"):
        assert {key(j) for j in cal.jobs(part)} == {key(j) for j in plain.jobs(part)}
    empty = resources.files("hw_sim").joinpath("scenarios", "empty-d2g.toml").read_text(encoding="utf-8")
    levels = {}
    for k, v in enumerate(cal.variants):
        off = v.patch.get("physics", {}).get("gain_offset_db", 0.0)
        level = v.patch.get("radar", {}).get("tx_power", 7)
        levels[off] = level
        site = tmp_path / f"empty-{k}.toml"
        site.write_text(empty + f"\n[physics]\ngain_offset_db = {off}\n", encoding="utf-8")

        def measure(lv, site=site):
            with open_radar(f"sim://d2g?scenario={site}&realtime=0&tx_power={lv}") as src:
                return adc_headroom(itertools.islice(iter(src), 3))

        assert pick_tx_power(measure, 7, 0.8)["level"] == level, v.name
        c = [float(s.split("=")[1]) for s in v.set if s.startswith("classify.features.rcs_calibration_db=")]
        assert c and c[0] - DATASHEET_C_DB == pytest.approx(off - (7 - level), abs=0.05), v.name
    assert levels == {-6.0: 7, -3.0: 7, 0.0: 7, 3.0: 5, 6.0: 2}


def test_surveillance_corpus_varies_mounting_gait_population_and_clutter():
    """Issue 31 item 5: each variant beyond the gain offsets changes the scene it names, and only that."""
    import numpy as np

    from edge.evaluation.corpus import load_corpus
    from hw_sim.scenario import load_scenario_for_eval

    variants = {v.name: v for v in load_corpus(REPO / "corpus" / "surveillance.toml").variants}

    def scene(name):
        return load_scenario_for_eval("single-random", 4, variants[name].patch).build_scene(3)

    base = scene("defaults")
    assert (base.pose.yaw_deg, base.pose.height_m, base.physics.gait, base.physics.site_clutter) == \
        (10.0, 1.0, "boulic", "urban")
    assert scene("yaw5").pose.yaw_deg == 5.0 and scene("yaw25").pose.yaw_deg == 25.0
    assert scene("height2").pose.height_m == 2.0
    assert scene("gait-sinusoid").physics.gait == "sinusoid"
    sparse = scene("sparse-clutter")
    assert sparse.physics.site_clutter == "v1" and len(sparse.clutter.rcs_m2) < len(base.clutter.rcs_m2)
    wide = load_scenario_for_eval("single-random", 4, variants["wide-vehicles"].patch)
    assert wide.raw["d2g_events"][0]["population"] == "wide"

    def lengths(sc, cls):
        return [float(np.ptp(t.offsets_m[:, 1])) for t in sc.targets if t.cls == cls]

    # 40 events: the wide population's trucks reach lengths the site's 7-12 m never does
    many = {n: load_scenario_for_eval("single-random", 40, variants[n].patch).build_scene(3)
            for n in ("defaults", "wide-vehicles")}
    site_trucks, wide_trucks = lengths(many["defaults"], "truck"), lengths(many["wide-vehicles"], "truck")
    assert site_trucks and wide_trucks
    assert max(wide_trucks) > max(site_trucks) + 1.0 or min(wide_trucks) < min(site_trucks) - 0.5


def test_corpus_svg_draws_each_variants_confusion_matrix():
    """Issue 31: the per-class confusion matrices per gain offset are in the plot as well as the JSON."""
    import xml.etree.ElementTree as ET

    from edge.evaluation.corpus_plot import corpus_svg

    def rec(v):
        return {"value": v, "ci95": [v - 0.1, v + 0.1], "runs": 2}

    pooled = {"by_variant": {"defaults": {"acc": rec(0.5)}, "gain-6": {"acc": rec(0.4)}}, "all": {"acc": rec(0.45)}}
    cms = {"defaults": {"labels": ["car", "truck"], "columns": ["car", "truck", "missed"],
                        "all": [[7, 2, 1], [0, 3, 0]]},
           "gain-6": {"labels": ["car", "truck"], "columns": ["car", "truck", "missed"], "all": [[1, 4, 5], [2, 0, 1]]}}
    doc = {"corpus": "s", "profile": "surveillance", "metrics": {"acc": {"unit": ""}},
           "parts": {"dev": {"runs": [{}, {}], "pooled": pooled, "confusion_by_variant": cms}}}
    root = ET.fromstring(corpus_svg(doc))
    texts = ["".join(e.itertext()) for e in root.iter() if e.tag.endswith("text")]
    assert "confusion, defaults (dev)" in texts and "confusion, gain-6 (dev)" in texts
    titles = [e.text for e in root.iter() if e.tag.endswith("title")]
    assert "car -> missed: 1 of 10" in titles and "truck -> car: 2 of 3" in titles and "car -> missed: 5 of 10" in titles
    # counts printed in their cells; the panels lie inside the drawing
    for n in ("7", "3", "4", "5"):
        assert n in texts
    height = float(root.attrib["height"])
    assert all(float(e.attrib["y"]) + float(e.attrib["height"]) <= height for e in root.iter()
               if e.tag.endswith("rect") and "y" in e.attrib)
    doc["parts"]["dev"].pop("confusion_by_variant")
    assert float(ET.fromstring(corpus_svg(doc)).attrib["height"]) < height  # a lane document: no panels


def test_targets_lists_every_runs_target_rows_beside_an_unchanged_document(tmp_path, capsys):
    """--targets: one JSON line per target of every run, keyed by part, scenario, seed and variant; the corpus
    document is the same with and without it."""
    with_rows, without, rows = tmp_path / "a.json", tmp_path / "b.json", tmp_path / "t" / "rows.jsonl"
    args = ["evaluate", "--corpus", str(SMOKE), "--part", "dev", "--jobs", "1", "--no-progress"]
    assert main(args + ["--json", str(with_rows), "--targets", str(rows)]) == 0
    assert main(args + ["--json", str(without)]) == 0
    doc = json.loads(with_rows.read_text())
    assert doc == json.loads(without.read_text())
    lines = [json.loads(x) for x in rows.read_text().splitlines()]
    runs = doc["parts"]["dev"]["runs"]
    assert {(x["scenario"], x["seed"], x["variant"]) for x in lines} == {(r["scenario"], r["seed"], r["variant"])
                                                                          for r in runs}
    assert all(x["part"] == "dev" for x in lines)
    for r in runs:  # every run's rows, once each: their frames in view are the run's tally
        mine = [x for x in lines if (x["seed"], x["variant"]) == (r["seed"], r["variant"])]
        assert len(mine) == len({x["id"] for x in mine}) > 0
        assert sum(x["frames_in_view"] for x in mine) == r["tallies"]["vehicle_frames_in_view"]
    capsys.readouterr()
    assert main(["evaluate", "--scenario", "highway4", "--targets", str(rows)]) == 2
    assert "--targets applies to --corpus" in capsys.readouterr().err
