"""A missing optional dependency is one line naming the extra, never a traceback.

The import is made to fail with a ``sys.modules`` entry set to None (what Python does for a module
that is not installed is an ImportError either way)."""

from __future__ import annotations

import json
import logging
import sys

import pytest

from edge.cli import main
from edge.extras import MissingExtraError, available, require


def test_require_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "onnx", None)
    assert not available("onnx")
    with pytest.raises(MissingExtraError, match=r"export-onnx needs the 'train' extra .*pip install 'radar-edge\[train\]'"):
        require("onnx", "export-onnx")


@pytest.mark.parametrize("argv", [["export-onnx", "--out", "m.onnx"], ["train", "--synthetic", "8", "--folds", "2", "--out", "trained"]])
def test_export_without_onnx_is_one_line_naming_the_extra(monkeypatch, capsys, tmp_path, argv):
    monkeypatch.setitem(sys.modules, "onnx", None)
    monkeypatch.chdir(tmp_path)
    rc = main(argv)
    err = capsys.readouterr().err
    assert rc == 2
    assert err.count("\n") == 1 and "Traceback" not in err
    assert f"radar-edge {argv[0]}: error: {argv[0]} needs the 'train' extra" in err
    assert "pip install 'radar-edge[train]'" in err
    assert not (tmp_path / "m.onnx").exists()


def test_evaluate_in_a_terminal_without_tqdm_runs_without_a_bar(monkeypatch, capsys, caplog, tmp_path):
    monkeypatch.setitem(sys.modules, "tqdm", None)
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)  # a terminal: the progress bar would be on
    out = tmp_path / "r.json"
    with caplog.at_level(logging.WARNING):
        rc = main(["evaluate", "--scenario", "single-car", "--frames", "10", "--json", str(out)])
    assert rc == 0
    assert json.loads(out.read_text())["frames"] == 10
    notes = [r.getMessage() for r in caplog.records if "tqdm" in r.getMessage()]
    assert notes == ["no progress bar: tqdm is not installed (pip install 'radar-edge[train]')"]
