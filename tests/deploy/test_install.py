"""deploy/install.sh into a temporary root: files, idempotency, dry run, uninstall."""

from __future__ import annotations

import hashlib
import shutil
import subprocess
from pathlib import Path

import pytest

from edge.config import load_config

REPO = Path(__file__).resolve().parents[2]
INSTALL = REPO / "deploy" / "install.sh"

pytestmark = pytest.mark.skipif(shutil.which("bash") is None, reason="bash not available")


def _run(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    p = subprocess.run(["bash", str(INSTALL), *args], capture_output=True, text=True, timeout=60)
    if check and p.returncode != 0:
        raise AssertionError(f"install.sh {' '.join(args)} failed ({p.returncode}):\n{p.stdout}\n{p.stderr}")
    return p


def _tree(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture
def pi_root(tmp_path):
    """A Raspberry Pi OS bookworm boot partition with the serial console on."""
    root = tmp_path / "root"
    boot = root / "boot" / "firmware"
    boot.mkdir(parents=True)
    (boot / "config.txt").write_text("# Pi config\ndtparam=audio=on\n[all]\n")
    (boot / "cmdline.txt").write_text("console=serial0,115200 console=tty1 root=PARTUUID=1234-02 rootwait\n")
    return root


def test_help_teaches():
    out = _run("--help").stdout
    assert "usage:" in out and "--root" in out and "--uninstall" in out and "examples:" in out


def test_unknown_option_fails():
    p = _run("--frobnicate", check=False)
    assert p.returncode == 2 and "unknown option" in p.stderr


def test_install_into_root_lays_out_every_file(pi_root):
    out = _run("--root", str(pi_root)).stdout
    etc = pi_root / "etc"
    unit = (etc / "systemd/system/radar-edge.service").read_text()
    assert "Type=notify" in unit and "WatchdogSec=" in unit
    assert unit == (REPO / "deploy/radar-edge.service").read_text()  # default prefix: unit as shipped
    rule = (etc / "udev/rules.d/99-radar-edge-d2g.rules").read_text()
    assert 'ATTRS{idVendor}=="058b"' in rule and 'ATTRS{idProduct}=="0058"' in rule
    assert 'SYMLINK+="radar-d2g"' in rule and 'GROUP="dialout"' in rule and "ID_MM_DEVICE_IGNORE" in rule
    net = (etc / "systemd/network/80-radar-edge-can0.network").read_text()
    assert "BitRate=500000" in net and "RestartSec=100ms" in net and "Name=can0" in net
    assert "TransmitQueueLength=1024" in (etc / "systemd/network/80-radar-edge-can0.link").read_text()
    cfg_txt = (pi_root / "boot/firmware/config.txt").read_text()
    assert cfg_txt.startswith("# Pi config\ndtparam=audio=on\n[all]\n")  # the user's lines stay
    assert "dtoverlay=mcp2515-can0,oscillator=12000000,interrupt=25" in cfg_txt
    assert "dtoverlay=disable-bt" in cfg_txt and "enable_uart=1" in cfg_txt
    cmdline = (pi_root / "boot/firmware/cmdline.txt").read_text()
    assert "console=serial0" not in cmdline and "console=tty1" in cmdline and "rootwait" in cmdline
    assert (pi_root / "boot/firmware/cmdline.txt.radar-edge.orig").read_text().startswith("console=serial0")
    toml = etc / "radar-edge/radar-edge.toml"
    assert toml.read_text() == (REPO / "deploy/radar-edge.example.toml").read_text()
    load_config(toml)  # the installed configuration is valid
    assert (pi_root / "var/lib/radar-edge/recordings").is_dir()
    assert (pi_root / "usr/share/doc/radar-edge/README.md").read_text().startswith("# Installing radar-edge")
    # no system command ran: each is listed as skipped
    for cmd in ("apt-get install", "useradd", "usermod -a -G dialout", "-m venv", "systemctl enable radar-edge.service",
                "udevadm control --reload"):
        assert any(cmd in line and line.startswith("skipped") for line in out.splitlines()), cmd
    assert "reboot" in out


def test_second_run_changes_nothing_and_keeps_the_users_config(pi_root):
    _run("--root", str(pi_root), "--no-apt")
    toml = pi_root / "etc/radar-edge/radar-edge.toml"
    toml.write_text(toml.read_text().replace('profile = "auto"', 'profile = "surveillance"'))
    before = _tree(pi_root)
    out = _run("--root", str(pi_root), "--no-apt").stdout
    assert _tree(pi_root) == before
    assert "already installed, nothing changed" in out
    assert not any(line.startswith(("installed", "updated", "edited")) for line in out.splitlines())
    assert out.count("dtoverlay") == 0  # the block is not appended twice
    assert (pi_root / "boot/firmware/config.txt").read_text().count("mcp2515-can0") == 1


def test_changed_option_updates_the_managed_block_only(pi_root):
    _run("--root", str(pi_root))
    _run("--root", str(pi_root), "--can-oscillator", "16000000", "--can-bitrate", "250000")
    cfg_txt = (pi_root / "boot/firmware/config.txt").read_text()
    assert cfg_txt.count("mcp2515-can0") == 1 and "oscillator=16000000" in cfg_txt
    assert "BitRate=250000" in (pi_root / "etc/systemd/network/80-radar-edge-can0.network").read_text()


def test_dry_run_changes_nothing(pi_root):
    before = _tree(pi_root)
    out = _run("--root", str(pi_root), "--dry-run").stdout
    assert _tree(pi_root) == before
    assert "would install" in out and "would edit" in out and "dry run: nothing changed" in out
    assert not (pi_root / "etc").exists()


def test_not_a_pi_skips_the_hat(tmp_path):
    out = _run("--root", str(tmp_path / "r")).stdout
    assert "HAT set-up (no config.txt" in out
    assert not (tmp_path / "r/etc/systemd/network").exists()


def test_uninstall_keeps_config_and_recordings_purge_removes_them(pi_root):
    _run("--root", str(pi_root))
    rec = pi_root / "var/lib/radar-edge/recordings/x.npz"
    rec.write_bytes(b"data")
    _run("--root", str(pi_root), "--uninstall")
    etc = pi_root / "etc"
    assert not (etc / "systemd/system/radar-edge.service").exists()
    assert not (etc / "udev/rules.d/99-radar-edge-d2g.rules").exists()
    assert not (etc / "systemd/network/80-radar-edge-can0.network").exists()
    assert "mcp2515" not in (pi_root / "boot/firmware/config.txt").read_text()
    assert (pi_root / "boot/firmware/config.txt").read_text() == "# Pi config\ndtparam=audio=on\n[all]\n"
    assert (etc / "radar-edge/radar-edge.toml").exists() and rec.exists()
    _run("--root", str(pi_root), "--uninstall", "--purge")
    assert not (etc / "radar-edge").exists() and not (pi_root / "var/lib/radar-edge").exists()


def test_refuses_real_root_without_privileges_or_dry_run():
    import os

    import tempfile

    script = INSTALL
    cmd = ["bash", str(script), "--no-apt"]
    with tempfile.TemporaryDirectory() as d:
        if os.geteuid() == 0:
            if shutil.which("setpriv") is None:
                pytest.skip("running as root without setpriv: cannot run the installer as an ordinary user")
            # a copy the unprivileged user can read wherever the checkout lives
            os.chmod(d, 0o755)
            script = Path(d) / "install.sh"
            shutil.copy(INSTALL, script)
            os.chmod(script, 0o644)
            cmd = ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", "bash", str(script), "--no-apt"]
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=60, cwd="/")
    assert p.returncode == 2 and "run as root" in p.stderr, p.stderr


def test_arm64_check_script_parses_and_explains_itself():
    """The full qemu check is run by hand (deploy/check-arm64.sh, ~7 min, root); here: syntax and --help."""
    script = REPO / "deploy" / "check-arm64.sh"
    assert subprocess.run(["bash", "-n", str(script)], capture_output=True, timeout=30).returncode == 0
    p = subprocess.run(["bash", str(script), "--help"], capture_output=True, text=True, timeout=30)
    assert p.returncode == 0 and "qemu-user-static debootstrap binfmt-support" in p.stdout and "examples:" in p.stdout
