"""The kernel build and its reporting: every kernel of ``edge.native.KERNELS`` is built and loads,
``RADAR_EDGE_KERNELS=0`` turns them all off, and ``doctor`` and the start-up log say which state holds.
A failed build (no compiler) still installs and leaves the numpy fallback (``setup.py``)."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest

from edge import native
from edge.ops import doctor
from tests.native.conftest import require_kernel

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def fresh_native(monkeypatch):
    """edge.native with an empty load cache and the start-up warning not yet given (restored afterwards)."""
    monkeypatch.setattr(native, "_cache", {})
    monkeypatch.setattr(native, "_errors", {})
    monkeypatch.setattr(native, "_warned", False)
    return native


@pytest.mark.parametrize("name", native.KERNELS)
def test_every_kernel_is_built_and_loads(name):
    mod = require_kernel(name)
    assert mod.__name__ == f"edge.native.{name}"
    assert Path(mod.__file__).suffix in (".so", ".pyd")  # compiled, not a stray .py


def test_probe_reports_its_abi_version():
    assert require_kernel("_probe").abi_version() == 1


def test_kernels_disabled_give_none_and_nothing_missing(fresh_native, monkeypatch):
    monkeypatch.setenv("RADAR_EDGE_KERNELS", "0")
    assert not native.enabled()
    assert all(native.load(k) is None for k in native.KERNELS)
    assert native.missing() == []
    assert "RADAR_EDGE_KERNELS=0" in native.status()


def test_doctor_line_when_loaded(fresh_native):
    if not native.enabled():
        pytest.skip("RADAR_EDGE_KERNELS=0: compiled kernels disabled")
    require_kernel("_probe")
    if native.missing():
        pytest.fail(f"kernels not built: {native.missing()}")
    (c,) = doctor.check_kernels()
    assert c.status == "ok" and f"compiled kernels loaded ({len(native.KERNELS)})" in c.detail
    assert c.data["loaded"] == list(native.KERNELS)


def test_doctor_line_and_start_warning_when_missing(fresh_native, monkeypatch, caplog):
    monkeypatch.delenv("RADAR_EDGE_KERNELS", raising=False)
    monkeypatch.setattr(native, "KERNELS", native.KERNELS + ("_not_built",))
    (c,) = doctor.check_kernels()
    assert c.status == "warn"
    assert "_not_built" in c.detail and "numpy fallback" in c.detail
    assert "build-essential" in c.fix and "deploy/install.sh" in c.fix
    assert c.data["missing"] == ["_not_built"]
    assert "No module named" in native.error("_not_built")
    with caplog.at_level(logging.WARNING, logger="edge.native"):
        native.warn_if_missing()
        native.warn_if_missing()  # once per process
    warned = [r for r in caplog.records if r.name == "edge.native"]
    assert len(warned) == 1 and "_not_built" in warned[0].getMessage()


def test_doctor_line_when_disabled(fresh_native, monkeypatch):
    monkeypatch.setenv("RADAR_EDGE_KERNELS", "0")
    (c,) = doctor.check_kernels()
    assert c.status == "skipped" and "RADAR_EDGE_KERNELS=0" in c.detail


def test_doctor_runs_the_kernel_check(tmp_path):
    checks = doctor.run_checks(doctor.System(tmp_path), None, open_board=False)
    assert [c.name for c in checks].count("kernels") == 1


def test_build_pipeline_warns_at_start_when_a_kernel_is_missing(fresh_native, monkeypatch, caplog):
    from edge.config import load_config
    from edge.pipeline import build_pipeline

    monkeypatch.delenv("RADAR_EDGE_KERNELS", raising=False)
    monkeypatch.setattr(native, "KERNELS", native.KERNELS + ("_not_built",))
    from hal import open_radar

    with open_radar("sim://simo?realtime=0", scenario="highway4", seed=1, frames=1) as src:
        fe = src.frontend
    with caplog.at_level(logging.WARNING, logger="edge.native"):
        build_pipeline("minimal", fe, load_config(None))
    assert any("_not_built" in r.getMessage() and r.levelno == logging.WARNING for r in caplog.records)


def test_failed_build_installs_the_fallback(tmp_path):
    """``setup.py build_ext`` with a compiler that always fails (``CC=/bin/false``) exits 0 and builds nothing."""
    env = dict(os.environ, CC="/bin/false", LDSHARED="/bin/false")
    out = subprocess.run([sys.executable, "setup.py", "-q", "build_ext", "--build-lib", str(tmp_path / "lib"),
                          "--build-temp", str(tmp_path / "tmp")],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=240)
    assert out.returncode == 0, out.stderr
    assert "numpy fallback will run" in out.stderr
    assert not list((tmp_path / "lib").rglob("*.so"))
