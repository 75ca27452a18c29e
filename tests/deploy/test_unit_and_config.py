"""The shipped systemd unit (hardening, measured by systemd-analyze) and the example configuration."""

from __future__ import annotations

import re
import shutil
import subprocess
import tomllib
from pathlib import Path

import pytest

from edge.config import SECTIONS, build_section, load_config

REPO = Path(__file__).resolve().parents[2]
UNIT = REPO / "deploy" / "radar-edge.service"
EXAMPLE = REPO / "deploy" / "radar-edge.example.toml"


def _unit_values(key: str) -> list[str]:
    return [line.split("=", 1)[1] for line in UNIT.read_text().splitlines() if line.startswith(key + "=")]


def test_unit_is_notify_with_watchdog_and_restart():
    assert _unit_values("Type") == ["notify"]
    assert _unit_values("Restart") == ["on-failure"]
    assert _unit_values("WatchdogSec") and _unit_values("NotifyAccess") == ["main"]
    assert _unit_values("CapabilityBoundingSet") == [""]  # empty: Modbus TCP on 5020 by default
    assert _unit_values("DevicePolicy") == ["closed"]
    assert _unit_values("ReadWritePaths") == ["/var/lib/radar-edge"]
    assert _unit_values("ProtectSystem") == ["strict"]


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze not installed (apt-get install systemd)")
def test_systemd_analyze_security_exposure_at_most_2():
    p = subprocess.run(["systemd-analyze", "security", "--offline=yes", str(UNIT)], capture_output=True, text=True,
                       timeout=120)
    m = re.search(r"Overall exposure level for \S+: (\d+\.\d+)", p.stdout + p.stderr)
    if m is None:
        pytest.skip(f"this systemd-analyze has no offline security analysis: {p.stderr.strip()[:200]}")
    assert float(m.group(1)) <= 2.0, p.stdout


def test_example_config_loads_and_sets_the_deployment_values():
    cfg = load_config(EXAMPLE, env={})
    assert cfg["source"].url == "d2g:///dev/radar-d2g"
    assert cfg["outputs.can"].channel == "can0" and cfg["outputs.can"].bitrate == 500_000
    assert cfg["ops.recorder"].enabled and cfg["ops.recorder"].directory == "/var/lib/radar-edge/recordings"


def test_commented_defaults_in_the_example_are_real_keys_with_the_real_defaults():
    """A '# key = value' line under [section] documents a default: it must be one."""
    section = None
    checked = 0
    for line in EXAMPLE.read_text().splitlines():
        if m := re.match(r"^\[([\w.]+)\]\s*$", line):
            section = m.group(1)
            assert section in SECTIONS, section
            continue
        if section and (m := re.match(r"^# (\w+) = (.+)$", line)):
            key, raw = m.groups()
            value = tomllib.loads(f"v = {raw}")["v"]
            default = getattr(build_section(section, {}), key)
            built = getattr(build_section(section, {key: value}), key)
            assert built == default, f"[{section}] {key}: example says {raw}, default is {default!r}"
            checked += 1
    assert checked >= 8


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze not installed (apt-get install systemd)")
def test_systemd_parses_every_directive(tmp_path):
    """`systemd-analyze verify` reports unknown keys and unparsable values (checked on a bad unit first)."""
    bad = tmp_path / "bad.service"
    bad.write_text("[Service]\nExecStart=/bin/true\nFrobnicate=yes\nProtectSystem=sideways\n")
    p = subprocess.run(["systemd-analyze", "verify", str(bad)], capture_output=True, text=True, timeout=60)
    if "Unknown key" not in p.stderr + p.stdout:
        pytest.skip(f"this systemd-analyze does not report unit syntax: {p.stderr.strip()[:200]}")
    unit = tmp_path / "radar-edge.service"
    text = UNIT.read_text()
    unit.write_text(re.sub(r"^ExecStart=\S+", "ExecStart=/bin/true", text, flags=re.M))
    p = subprocess.run(["systemd-analyze", "verify", str(unit)], capture_output=True, text=True, timeout=60)
    complaints = [ln for ln in (p.stderr + p.stdout).splitlines() if str(unit) in ln]
    assert complaints == []
