"""``radar-edge plot REPORT.json``: the accuracy figure of an evaluation report."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("matplotlib")

from edge.cli import main  # noqa: E402
from edge.ops.plots import PlotError  # noqa: E402
from edge.ops.report_plots import load_report  # noqa: E402


def _png_size(path):
    import matplotlib.image

    img = matplotlib.image.imread(str(path))
    return img.shape[1], img.shape[0]


@pytest.mark.parametrize("scenario,frames,size", [("highway4", 60, (1650, 506)), ("tavanti-test1", 25, (1210, 506))])
def test_plot_of_an_evaluation_report(scenario, frames, size, tmp_path, capsys):
    rep = tmp_path / f"{scenario}.json"
    assert main(["evaluate", "--scenario", scenario, "--frames", str(frames), "--json", str(rep), "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["plot", str(rep), "--out", str(tmp_path / "png")]) == 0
    out = capsys.readouterr().out.strip()
    assert out == str(tmp_path / "png" / f"{scenario}-accuracy.png")
    assert _png_size(out) == size


def test_report_errors_are_clear(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"summary": {}}))
    minimal = tmp_path / "minimal.json"
    minimal.write_text(json.dumps({"profile": "minimal", "summary": {}}))
    for path, msg in ((tmp_path / "none.json", "no such file"), (bad, "not a JSON evaluation report"),
                      (other, "not a radar-edge evaluate report"), (minimal, "no figure for profile 'minimal'")):
        with pytest.raises(PlotError, match=msg):
            load_report(path)
        assert main(["plot", str(path), "--out", str(tmp_path)]) == 2
        assert msg in capsys.readouterr().out
