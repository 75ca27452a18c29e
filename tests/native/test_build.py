"""The kernel build and its reporting: every kernel of ``edge.native.KERNELS`` is built and loads,
``RADAR_EDGE_KERNELS=0`` turns them all off, and ``doctor`` and the start-up log say which state holds.
A failed build (no compiler) still installs and leaves the numpy fallback (``setup.py``)."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
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


def test_doctor_runs_the_kernel_check(tmp_path, monkeypatch):
    monkeypatch.setattr(doctor.System, "tcp_bind", lambda self, host, port: None)  # binds no port
    (c,) = [c for c in doctor.run_checks(doctor.System(tmp_path), None, open_board=False) if c.name == "kernels"]
    assert c.status == "skipped" and "--root" in c.detail  # another root's installation cannot be imported
    assert doctor.check_kernels(doctor.System("/"))[0].status in ("ok", "warn", "skipped")


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


def test_end_to_end_comparison_finds_a_difference():
    """edge.native.check's comparison: equal outputs agree; a changed value or a lost track does not."""
    from edge.native.check import agree, compare

    def rec(x, ids):
        return {"range_m": np.array([x, 2.0]), "track_id": np.array(ids), "track_x_m": np.array([1.0] * len(ids))}

    a = [rec(10.0, [1, 2]), rec(11.0, [1])]
    assert agree(compare(a, [rec(10.0, [1, 2]), rec(11.0, [1])]))
    moved = compare(a, [rec(10.0, [1, 2]), rec(11.0 + 1e-6, [1])])
    assert not agree(moved) and moved["max_abs_diff"]["range_m"] == pytest.approx(1e-6)
    assert agree(moved, atol=1e-5)
    lost = compare(a, [rec(10.0, [1]), rec(11.0, [1])])
    assert lost["count_mismatch_frames"] == [0] and not agree(lost, atol=1.0)


def test_pi_installer_installs_the_toolchain(tmp_path):
    """deploy/install.sh installs the C toolchain before pip builds the package (and its kernels) on the Pi."""
    out = subprocess.run(["bash", str(ROOT / "deploy/install.sh"), "--root", str(tmp_path / "img"), "--dry-run"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    apt = next(i for i, line in enumerate(lines) if "apt-get install" in line)
    pip = next(i for i, line in enumerate(lines) if "/pip install" in line)
    assert "build-essential" in lines[apt] and "python3-dev" in lines[apt] and apt < pip


def test_wheel_manifest_ships_compiled_kernels_only():
    """A wheel carries the compiled modules, not the .pyx/.c (pyproject exclude-package-data); the sdist the .pyx
    (MANIFEST.in), from which the target builds them."""
    import tomllib

    excl = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["exclude-package-data"]
    assert {"*.pyx", "*.c"} <= set(excl["edge.native"])
    manifest = (ROOT / "MANIFEST.in").read_text().splitlines()
    assert "include edge/native/*.pyx" in manifest and "exclude edge/native/*.c" in manifest


def test_lane_pipeline_copies_and_pickles_with_its_kernels():
    """Every stage and role holding a kernel module deep-copies and pickles (tests and replays copy pipelines),
    and the copy still runs the same compiled modules."""
    import copy
    import pickle
    from types import ModuleType

    from hal.waveform import simo_frontend
    from edge.pipelines.lane import LaneConfig, LanePipeline

    for name in ("_spectra", "_peaks", "_track"):
        require_kernel(name)
    pipe = LanePipeline(simo_frontend(), LaneConfig())

    def kernels(obj, seen=None, depth=0):
        seen = set() if seen is None else seen
        found = []
        if id(obj) in seen or depth > 6:
            return found
        seen.add(id(obj))
        for v in getattr(obj, "__dict__", {}).values():
            if isinstance(v, ModuleType) and v.__name__.startswith("edge.native."):
                found.append(v)
            elif hasattr(v, "__dict__") and type(v).__module__.startswith("edge."):
                found += kernels(v, seen, depth + 1)
        return found

    before = kernels(pipe)
    assert {m.__name__ for m in before} >= {"edge.native._spectra", "edge.native._peaks", "edge.native._track"}
    for other in (copy.deepcopy(pipe), pickle.loads(pickle.dumps(pipe))):
        after = kernels(other)
        assert [m.__name__ for m in after] == [m.__name__ for m in before]
        assert all(a is b for a, b in zip(after, before))
