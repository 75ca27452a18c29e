"""radar-edge doctor on a fake file-system root with scripted commands: each failure names its fix."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from edge.cli import main
from edge.config import load_config
from edge.ops import doctor as dr
from edge.ops.doctor import Access, System
from hal.errors import DeviceError

DIALOUT = 20


class FakeSystem(System):
    def __init__(self, root, *, uid=1000, gids=(1000,), commands=None, bind_error=None, board=None):
        super().__init__(root)
        self.access = Access("radar-edge", uid, frozenset(gids))
        self.commands = commands or {}
        self.bind_error = bind_error
        self.board = board
        self.bound = []

    def which(self, name):
        return name in self.commands

    def run(self, argv, timeout_s=5.0):
        out = self.commands[argv[0]]
        return out(argv) if callable(out) else out

    def tcp_bind(self, host, port):
        self.bound.append((host, port))
        return self.bind_error

    def probe_board(self, url):
        if isinstance(self.board, Exception):
            raise self.board
        return self.board


def _dev(root: Path, rel: str, mode=0o660, gid=DIALOUT) -> Path:
    p = root / rel.lstrip("/")
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text("")
    os.chmod(p, mode)
    os.chown(p, 0, gid) if os.geteuid() == 0 else None
    return p


def _cfg(**over):
    base = {"source.url": "d2g:///dev/radar-d2g"}
    base.update(over)
    return load_config(overrides=base, env={})


def _by_name(checks, name):
    (c,) = [c for c in checks if c.name == name]
    return c


needs_chown = pytest.mark.skipif(os.geteuid() != 0, reason="needs root to give the fake device node group dialout")


@needs_chown
def test_serial_port_permissions_judged_for_the_service_user(tmp_path):
    _dev(tmp_path, "/dev/radar-d2g")
    board = {"board": "d2g", "frame": "received", "endpoints": {"RBAS": 1, "RADX": 2, "RFMC": 3}}
    outsider = FakeSystem(tmp_path, gids=(1000,), board=board)
    c = _by_name(dr.check_source(outsider, _cfg(), True), "serial port")
    assert c.status == "fail" and "may not read and write" in c.detail
    assert "usermod -aG" in c.fix and "radar-edge" in c.fix
    member = FakeSystem(tmp_path, gids=(1000, DIALOUT), board=board)
    checks = dr.check_source(member, _cfg(), True)
    assert _by_name(checks, "serial port").status == "ok"
    b = _by_name(checks, "board")
    assert b.status == "ok" and "endpoints 1:RBAS, 2:RADX, 3:RFMC" in b.detail


def test_missing_board_and_board_errors_have_fixes(tmp_path):
    c = _by_name(dr.check_source(FakeSystem(tmp_path, uid=0), _cfg(), True), "serial port")
    assert c.status == "fail" and "lsusb -d 058b:0058" in c.fix
    _dev(tmp_path, "/dev/radar-d2g")
    sys_ = FakeSystem(tmp_path, uid=0, board=DeviceError("no radar base endpoint (RBAS) among ['X']: not a Distance2Go"))
    b = _by_name(dr.check_source(sys_, _cfg(), True), "board")
    assert b.status == "fail" and "reflash" in b.fix
    silent = FakeSystem(tmp_path, uid=0, board={"board": "d2g", "frame": "none: timeout"})
    assert _by_name(dr.check_source(silent, _cfg(), True), "board").status == "warn"
    assert _by_name(dr.check_source(silent, _cfg(), False), "board").status == "skipped"


def test_a_board_whose_frame_clips_is_reported_saturated(tmp_path):
    _dev(tmp_path, "/dev/radar-d2g")
    clean = FakeSystem(tmp_path, uid=0, board={"board": "d2g", "frame": "received", "clipped_fraction": 0.0})
    assert _by_name(dr.check_source(clean, _cfg(), True), "board").status == "ok"
    hot = FakeSystem(tmp_path, uid=0, board={"board": "d2g", "frame": "received", "clipped_fraction": 0.39})
    b = _by_name(dr.check_source(hot, _cfg(), True), "board")
    assert b.status == "warn" and "39.0% of the frame's samples at the ADC's full scale" in b.detail
    assert "saturated" in b.fix


def test_auto_url_finds_the_board_by_id(tmp_path):
    target = _dev(tmp_path, "/dev/ttyACM0")
    link = tmp_path / "dev/serial/by-id/usb-Infineon_IFX_CDC-if00"
    link.parent.mkdir(parents=True)
    link.symlink_to(target)
    checks = dr.check_source(FakeSystem(tmp_path, uid=0, board={"frame": "received"}), _cfg(**{"source.url": "d2g://auto"}), True)
    c = _by_name(checks, "serial port")
    assert c.status == "ok" and "usb-Infineon_IFX_CDC-if00 -> /dev/ttyACM0" in c.detail


def test_rtu_port_that_is_the_serial_console_fails(tmp_path):
    _dev(tmp_path, "/dev/ttyAMA0")
    (tmp_path / "proc").mkdir()
    (tmp_path / "proc/cmdline").write_text("console=serial0,115200 console=tty1 root=/dev/mmcblk0p2\n")
    cfg = _cfg(**{"outputs.modbus.rtu_port": "/dev/ttyAMA0"})
    c = _by_name(dr.check_modbus(FakeSystem(tmp_path, uid=0), cfg), "modbus rtu")
    assert c.status == "fail" and "serial console" in c.detail and "cmdline.txt" in c.fix
    (tmp_path / "proc/cmdline").write_text("console=tty1 root=/dev/mmcblk0p2\n")
    c = _by_name(dr.check_modbus(FakeSystem(tmp_path, uid=0), cfg), "modbus rtu")
    assert c.status == "ok" and "19200 baud E" in c.detail


def test_port_502_needs_the_capability(tmp_path):
    cfg = _cfg(**{"outputs.modbus.tcp_port": 502, "outputs.modbus.tcp_host": "0.0.0.0"})
    unit = tmp_path / "etc/systemd/system/radar-edge.service"
    unit.parent.mkdir(parents=True)
    unit.write_text("[Service]\nCapabilityBoundingSet=\n# CapabilityBoundingSet=CAP_NET_BIND_SERVICE\n")
    c = _by_name(dr.check_modbus(FakeSystem(tmp_path), cfg), "modbus tcp")
    assert c.status == "fail" and "AmbientCapabilities=CAP_NET_BIND_SERVICE" in c.fix
    unit.write_text("[Service]\nCapabilityBoundingSet=CAP_NET_BIND_SERVICE\nAmbientCapabilities=CAP_NET_BIND_SERVICE\n")
    s = FakeSystem(tmp_path)
    assert _by_name(dr.check_modbus(s, cfg), "modbus tcp").status == "ok" and s.bound == [("0.0.0.0", 502)]
    busy = FakeSystem(tmp_path, bind_error="Address already in use")
    c = _by_name(dr.check_modbus(busy, cfg), "modbus tcp")
    assert c.status == "warn" and "ss -ltnp" in c.fix


def _ip(state="ERROR-ACTIVE", bitrate=500000, restart_ms=100, flags=("NOARP", "UP", "LOWER_UP"), rc=0):
    link = {"ifname": "can0", "flags": list(flags), "txqlen": 1024, "operstate": "UP",
            "linkinfo": {"info_kind": "can", "info_data": {"state": state, "restart_ms": restart_ms,
                                                           "bittiming": {"bitrate": bitrate, "sample_point": "0.875"}}}}
    return {"ip": (rc, json.dumps([link]) if rc == 0 else 'Device "can0" does not exist.')}


@pytest.mark.parametrize(
    "kw,status,words",
    [
        ({}, "ok", "ERROR-ACTIVE at 500000 bit/s, restart-ms 100"),
        ({"bitrate": 250000}, "fail", "runs at 250000"),
        ({"state": "BUS-OFF"}, "fail", "BUS-OFF"),
        ({"state": "ERROR-PASSIVE"}, "warn", "not acknowledged"),
        ({"flags": ("NOARP",)}, "fail", "is down"),
        ({"restart_ms": 0}, "warn", "no bus-off recovery"),
        ({"rc": 1}, "fail", "no interface can0"),
    ],
)
def test_can_interface_state_and_bitrate(tmp_path, kw, status, words):
    cfg = _cfg(**{"outputs.can.interface": "socketcan"})
    (c,) = dr.check_can(FakeSystem(tmp_path, commands=_ip(**kw)), cfg)
    assert c.status == status and words in c.detail
    if status == "fail":
        assert c.fix


def test_can_skipped_without_ip_or_when_off(tmp_path):
    assert dr.check_can(FakeSystem(tmp_path), _cfg())[0].status == "skipped"
    cfg = _cfg(**{"outputs.can.interface": "socketcan"})
    (c,) = dr.check_can(FakeSystem(tmp_path), cfg)
    assert c.status == "skipped" and "iproute2" in c.detail


@pytest.mark.parametrize("milli_c,status", [("45123\n", "ok"), ("77000\n", "warn"), ("84500\n", "fail")])
def test_cpu_temperature(tmp_path, milli_c, status):
    z = tmp_path / "sys/class/thermal/thermal_zone0"
    z.mkdir(parents=True)
    (z / "temp").write_text(milli_c)
    checks = dr.check_temperature(FakeSystem(tmp_path))
    t = _by_name(checks, "cpu temperature")
    assert t.status == status and f"{int(milli_c) / 1000:.1f} °C" in t.detail
    assert _by_name(checks, "throttling").status == "skipped"


@pytest.mark.parametrize(
    "value,status,words",
    [("0x0", "ok", "no under-voltage"), ("0x50000", "warn", "under-voltage has occurred"),
     ("0x50005", "fail", "under-voltage now; throttled now")],
)
def test_throttling_bits(tmp_path, value, status, words):
    s = FakeSystem(tmp_path, commands={"vcgencmd": (0, f"throttled={value}\n")})
    c = _by_name(dr.check_temperature(s), "throttling")
    assert c.status == status and words in c.detail


def test_clock_sync(tmp_path):
    assert dr.check_clock(FakeSystem(tmp_path, commands={"timedatectl": (0, "yes\nyes\n")}))[0].status == "ok"
    c = dr.check_clock(FakeSystem(tmp_path, commands={"timedatectl": (0, "no\nyes\n")}))[0]
    assert c.status == "fail" and "set-ntp true" in c.fix
    chrony = "Reference ID    : C0A80001\nLeap status     : Normal\n"
    assert dr.check_clock(FakeSystem(tmp_path, commands={"chronyc": (0, chrony)}))[0].status == "ok"
    bad = chrony.replace("Normal", "Not synchronised")
    assert dr.check_clock(FakeSystem(tmp_path, commands={"chronyc": (0, bad)}))[0].status == "fail"
    assert dr.check_clock(FakeSystem(tmp_path))[0].status == "skipped"


def _onnx_model(path: Path, elem_type):
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper

    t = {"float": TensorProto.FLOAT, "int64": TensorProto.INT64}[elem_type]
    x = helper.make_tensor_value_info("features", t, [None, 4])
    y = helper.make_tensor_value_info("out", t, [None, 4])
    g = helper.make_graph([helper.make_node("Identity", ["features"], ["out"])], "g", [x], [y])
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 8
    onnx.save(m, str(path))


def test_model_files_load_and_have_float_inputs(tmp_path, monkeypatch):
    pytest.importorskip("onnxruntime")
    good, bad = tmp_path / "good.onnx", tmp_path / "bad.onnx"
    _onnx_model(good, "float")
    _onnx_model(bad, "int64")
    (tmp_path / "broken.onnx").write_bytes(b"not a model")
    fields = [("a.model_path", str(good)), ("b.model_path", str(bad)), ("c.model_path", str(tmp_path / "broken.onnx")),
              ("d.model_path", str(tmp_path / "missing.onnx"))]
    monkeypatch.setattr(dr, "_model_fields", lambda cfg: iter(fields))
    checks = dr.check_models(FakeSystem("/"), None)
    assert [c.status for c in checks] == ["ok", "fail", "fail", "fail"]
    assert "inputs [('features'" in checks[0].detail
    assert "expected tensor(float)" in checks[1].detail
    assert "does not load" in checks[2].detail and "file not found" in checks[3].detail


def test_recordings_directory(tmp_path):
    cfg = _cfg(**{"ops.recorder.enabled": True, "ops.recorder.directory": "/var/lib/radar-edge/recordings",
                  "ops.recorder.min_free_mb": 0, "ops.recorder.quota_mb": 1})
    c = dr.check_recorder(FakeSystem(tmp_path, uid=0), cfg)[0]
    assert c.status == "fail" and "install -d" in c.fix
    (tmp_path / "var/lib/radar-edge/recordings").mkdir(parents=True)
    assert dr.check_recorder(FakeSystem(tmp_path, uid=0), cfg)[0].status == "ok"
    huge = _cfg(**{"ops.recorder.enabled": True, "ops.recorder.directory": "/var/lib/radar-edge/recordings",
                   "ops.recorder.min_free_mb": 1e6})
    assert dr.check_recorder(FakeSystem(tmp_path, uid=0), huge)[0].status == "fail"


def test_bad_config_is_one_failure_with_the_key(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[loop]\nerror_policy = 'explode'\n")
    checks = dr.run_checks(FakeSystem(tmp_path), str(bad), open_board=False)
    c = checks[0]
    assert c.name == "config" and c.status == "fail" and "loop.error_policy" in c.detail


def test_cli_json_and_exit_status(tmp_path, capsys):
    cfg = tmp_path / "c.toml"
    cfg.write_text('[source]\nurl = "d2g:///dev/radar-d2g"\n')
    rc = main(["doctor", "--root", str(tmp_path), "--config", str(cfg), "--no-board", "--json",
               "--set", "outputs.modbus.tcp_enabled=false"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 1 and out["ok"] is False
    names = [c["name"] for c in out["checks"]]
    assert names[:2] == ["config", "serial port"] and "clock" in names and "cpu temperature" in names
    assert all(c["fix"] for c in out["checks"] if c["status"] == "fail")
    rc = main(["doctor", "--root", str(tmp_path), "--no-board", "--set", "outputs.modbus.tcp_enabled=false"])
    text = capsys.readouterr().out
    assert "checks:" in text and "radar-edge doctor" in text


def test_board_check_against_the_emulated_distance2go():
    """The real probe (open, endpoint list, one frame) on the Distance2Go firmware emulator's pty."""
    try:
        from tests.hal.d2g_emulator import emulated_d2g_url
    except ImportError as exc:  # pragma: no cover - the d2g backend is not in this build
        pytest.skip(f"the Distance2Go emulator is not available: {exc}")
    with emulated_d2g_url() as url:
        cfg = load_config(env={}, overrides={"source.url": url})
        checks = dr.check_source(System("/", user="root"), cfg, True)
    assert _by_name(checks, "serial port").status == "ok"
    b = _by_name(checks, "board")
    assert b.status == "ok", b.detail
    assert "RBAS" in b.detail and b.data["frame"] == "received"
    assert 0.0 <= b.data["clipped_fraction"] <= dr.CLIPPED_SAMPLES_WARN
    assert b.data["endpoints"]["RBAS"] >= 1
    # the installer reads the TX power level and how much of the ADC's range the frame used (the nominal board's
    # leakage: about two thirds)
    assert "TX power level 7 of 7" in b.detail
    assert 0.5 < b.data["adc_peak_fraction"] < 0.8 and "ADC peak" in b.detail
    with emulated_d2g_url(tx_power=2) as url:
        b = _by_name(dr.check_source(System("/", user="root"), load_config(env={}, overrides={"source.url": url}),
                                     True), "board")
    assert "TX power level 2 of 7" in b.detail and b.data["adc_peak_fraction"] < 0.45


class _FakeOnnxModule:
    """Stands in for edge.classify.onnx_runtime (the contract: OnnxKnnClassifier(path, threads=), ModelError)."""

    class ModelError(ValueError):
        pass

    class OnnxKnnClassifier:
        def __init__(self, path, threads=1):
            if path and "bad" in str(path):
                raise _FakeOnnxModule.ModelError(f"classifier model {path!r} expects features ['a'], the pipeline extracts ['b']")
            self.path = Path(path or "/pkg/edge/data/knn_default.onnx")
            self.k, self.metric = 13, "euclidean"
            self.classes = ("human", "vehicle")
            self.feature_names = ("f1", "f2", "f3")
            self.reference_sha256 = "0123456789abcdef"


def test_classifier_check_uses_the_pipelines_loader(monkeypatch, tmp_path):
    import sys
    from dataclasses import dataclass, field

    @dataclass(frozen=True)
    class OnnxConfig:
        backend: str = field(default="onnx", metadata={"choices": ("onnx", "numpy")})
        model: str = ""
        threads: int = 1

    fake = _FakeOnnxModule()
    fake.OnnxConfig = OnnxConfig
    monkeypatch.setitem(sys.modules, "edge.classify.onnx_runtime", fake)
    import edge.classify

    monkeypatch.setattr(edge.classify, "onnx_runtime", fake, raising=False)
    from edge import config as ec

    monkeypatch.setitem(ec.SECTIONS, "classify.onnx", "edge.classify.onnx_runtime:OnnxConfig")
    (c,) = dr.check_classifier(FakeSystem(tmp_path), load_config(env={}))
    assert c.status == "ok" and "knn_default.onnx: k=13 euclidean, classes human, vehicle, 3 features" in c.detail
    (c,) = dr.check_classifier(FakeSystem(tmp_path), load_config(env={}, overrides={"classify.onnx.model": "/x/bad.onnx"}))
    assert c.status == "fail" and "expects features" in c.detail and "export-onnx" in c.fix
    (c,) = dr.check_classifier(FakeSystem(tmp_path), load_config(env={}, overrides={"classify.onnx.backend": "numpy"}))
    assert c.status == "skipped"


def test_classifier_check_on_the_packaged_model():
    ox = pytest.importorskip("edge.classify.onnx_runtime", reason="the ONNX classifier is not in this build")
    cfg = load_config(env={})
    (c,) = dr.check_classifier(System("/"), cfg)
    assert c.status == "ok", c.detail
    assert c.data["path"] == str(ox.default_model_path())
    assert "not compared" not in c.detail  # the packaged model records its reference set's feature settings


def test_classifier_check_warns_when_the_feature_settings_are_not_the_reference_sets():
    pytest.importorskip("edge.classify.onnx_runtime", reason="the ONNX classifier is not in this build")
    cfg = load_config(env={}, overrides={"classify.features.speed_feature": "doppler",
                                         "classify.features.extent_percentile": 50.0,
                                         "classify.features.rcs_calibration_db": 58.4})
    (c,) = dr.check_classifier(System("/"), cfg)
    assert c.status == "warn" and "export-onnx" in c.fix
    assert "speed_feature = 'doppler'" in c.detail and "extent_percentile = 50.0" in c.detail
    assert "rcs_calibration" not in c.detail  # a board's calibration is not a feature setting


def test_service_unit_and_state(tmp_path):
    (c,) = dr.check_service(FakeSystem(tmp_path))
    assert c.status == "warn" and c.fix == "sudo deploy/install.sh"
    unit = tmp_path / "etc/systemd/system/radar-edge.service"
    unit.parent.mkdir(parents=True)
    unit.write_text("[Service]\nExecStart=/opt/radar-edge/venv/bin/radar-edge run --config /etc/radar-edge/radar-edge.toml\n")
    (c,) = dr.check_service(FakeSystem(tmp_path))
    assert c.status == "fail" and "does not exist" in c.detail
    exe = tmp_path / "opt/radar-edge/venv/bin/radar-edge"
    exe.parent.mkdir(parents=True)
    exe.write_text("#!/bin/sh\n")
    (c,) = dr.check_service(FakeSystem(tmp_path))
    assert c.status == "ok" and "not queried" in c.detail


def test_service_state_from_systemctl(monkeypatch):
    answers = {"is-enabled": "enabled\n", "is-active": "failed\n"}
    s = FakeSystem("/", commands={"systemctl": lambda argv: (0, answers[argv[1]])})
    monkeypatch.setattr(s, "read_text", lambda p: "[Service]\nExecStart=/bin/sh\n")
    (c,) = dr.check_service(s)
    assert c.status == "fail" and c.detail == "enabled, failed" and "journalctl -u radar-edge" in c.fix
    answers["is-active"] = "active\n"
    assert dr.check_service(s)[0].status == "ok"
    answers["is-enabled"] = "disabled\n"
    (c,) = dr.check_service(s)
    assert c.status == "warn" and "enable --now" in c.fix


def test_service_user_in_dialout(monkeypatch):
    import grp
    import pwd

    (c,) = dr.check_user(FakeSystem("/tmp"))
    assert c.status == "skipped"
    users = {"radar-edge": pwd.struct_passwd(("radar-edge", "x", 999, 999, "", "/var/lib/radar-edge", "/usr/sbin/nologin"))}
    groups = [grp.struct_group(("dialout", "x", 20, [])), grp.struct_group(("radar-edge", "x", 999, []))]

    def getpwnam(name):
        if name not in users:
            raise KeyError(name)
        return users[name]

    monkeypatch.setattr(dr.pwd, "getpwnam", getpwnam)
    monkeypatch.setattr(dr.grp, "getgrnam", lambda n: next(g for g in groups if g.gr_name == n))
    monkeypatch.setattr(dr.grp, "getgrall", lambda: groups)
    (c,) = dr.check_user(FakeSystem("/"))
    assert c.status == "fail" and "usermod -aG dialout radar-edge" in c.fix
    groups[0] = grp.struct_group(("dialout", "x", 20, ["radar-edge"]))
    assert dr.check_user(FakeSystem("/"))[0].status == "ok"
    users.clear()
    assert dr.check_user(FakeSystem("/"))[0].status == "warn"


def test_traffic_calibration_file(tmp_path):
    from edge.traffic import Lane
    from edge.traffic.calibration import Calibration, CalibrationWriter

    assert dr.check_traffic_calibration(FakeSystem(tmp_path, uid=0), _cfg())[0].status == "skipped"
    cfg = _cfg(**{"traffic.calibration_file": "/var/lib/radar-edge/traffic-calibration.json"})
    c = dr.check_traffic_calibration(FakeSystem(tmp_path, uid=0), cfg)[0]
    assert c.status == "fail" and "install -d" in c.fix
    d = tmp_path / "var/lib/radar-edge"
    d.mkdir(parents=True)
    c = dr.check_traffic_calibration(FakeSystem(tmp_path, uid=0), cfg)[0]
    assert c.status == "ok" and "none saved yet" in c.detail
    w = CalibrationWriter(d / "traffic-calibration.json")
    w.submit(Calibration(0.05, 0.001, 42, "learned", (Lane(-1.75, 3.5, -1), Lane(1.75, 3.5, 1))))
    w.close()
    c = dr.check_traffic_calibration(FakeSystem(tmp_path, uid=0), cfg)[0]
    assert c.status == "ok" and "yaw 2.86 +- 0.06 deg from 42 tracks, 2 lanes (learned)" in c.detail
    (d / "traffic-calibration.json").write_text("{broken")
    c = dr.check_traffic_calibration(FakeSystem(tmp_path, uid=0), cfg)[0]
    assert c.status == "warn" and "delete" in c.fix
    if os.geteuid() == 0:  # the service user (uid 1000) may not write a root-owned 0755 directory
        os.chmod(d, 0o755)
        c = dr.check_traffic_calibration(FakeSystem(tmp_path, uid=1000), cfg)[0]
        assert c.status == "fail" and "chown" in c.fix


EXAMPLE_TOML = Path(__file__).resolve().parents[3] / "deploy" / "radar-edge.example.toml"
UNIT_FILE = Path(__file__).resolve().parents[3] / "deploy" / "radar-edge.service"


def test_default_install_passes_and_motion_model_is_not_a_file(tmp_path):
    """Built-in defaults on an empty root: warnings (no config file, simulator source), no failure.

    ``track.pdaf.motion_model = "imm"`` used to be taken for a model file because of its name."""
    checks = dr.run_checks(FakeSystem(tmp_path, uid=0), None, open_board=False)
    failed = [(c.name, c.detail) for c in checks if c.status == "fail"]
    assert failed == []
    assert not any("motion_model" in c.detail for c in checks)
    assert ("track.pdaf.motion_model", "imm") not in list(dr._model_fields(load_config(env={})))


def test_model_fields_are_the_file_keys_and_model_suffixes(tmp_path):
    cfg = load_config(env={}, overrides={"classify.knn.reference_set": str(tmp_path / "ref.npz"),
                                         "classify.onnx.model": "site.onnx"})
    assert dict(dr._model_fields(cfg)) == {"classify.knn.reference_set": str(tmp_path / "ref.npz"),
                                           "classify.onnx.model": "site.onnx"}
    c = _by_name(dr.check_models(FakeSystem(tmp_path, uid=0), cfg), "model")
    assert c.status == "fail" and "classify.knn.reference_set" in c.detail and "file not found" in c.detail


def _example_install(root: Path) -> None:
    """A fake root laid out as deploy/install.sh leaves a Pi with the HAT: board, UART, state dirs, unit."""
    _dev(root, "/dev/radar-d2g")
    _dev(root, "/dev/ttyAMA0")
    (root / "proc").mkdir()
    (root / "proc/cmdline").write_text("console=tty1 root=/dev/mmcblk0p2\n")
    (root / "var/lib/radar-edge/recordings").mkdir(parents=True)
    unit = root / "etc/systemd/system/radar-edge.service"
    unit.parent.mkdir(parents=True)
    unit.write_text(UNIT_FILE.read_text())
    exe = _dev(root, "/opt/radar-edge/venv/bin/radar-edge", mode=0o755, gid=0)
    assert exe.is_file()


def test_example_config_on_a_complete_install_passes_and_a_missing_board_fails(tmp_path):
    _example_install(tmp_path)
    board = {"board": "d2g", "frame": "received", "endpoints": {"RBAS": 1, "RADX": 2, "RFMC": 3}}
    fine = FakeSystem(tmp_path, uid=0, commands=_ip(), board=board)
    checks = dr.run_checks(fine, str(EXAMPLE_TOML), open_board=True)
    assert [(c.name, c.detail) for c in checks if c.status == "fail"] == []
    assert {c.name: c.status for c in checks}["board"] == "ok"
    (tmp_path / "dev/radar-d2g").unlink()  # the board unplugged: a real failure, with its fix
    checks = dr.run_checks(FakeSystem(tmp_path, uid=0, commands=_ip(), board=board), str(EXAMPLE_TOML),
                           open_board=True)
    failed = [c for c in checks if c.status == "fail"]
    assert [c.name for c in failed] == ["serial port"] and "/dev/radar-d2g does not exist" in failed[0].detail
    assert "lsusb" in failed[0].fix


def test_rcs_calibration_shows_c_and_whether_it_was_measured():
    from edge.classify.calibration import DATASHEET_C_DB

    c = dr.check_rcs_calibration(_cfg())[0]  # a Distance2Go on the datasheet constant
    assert c.status == "warn" and "datasheet" in c.detail and "calibrate --rcs" in c.fix
    assert c.data["c_db"] == DATASHEET_C_DB and c.data["source"] == "datasheet"
    c = dr.check_rcs_calibration(_cfg(**{"classify.features.rcs_calibration_db": 57.3,
                                         "classify.features.rcs_calibration_sd_db": 0.2,
                                         "classify.features.rcs_calibration_source": "measured"}))[0]
    assert c.status == "ok" and "57.30 +- 0.20 dB, measured" in c.detail
    assert c.data["c_db"] == 57.3
    c = dr.check_rcs_calibration(_cfg(**{"source.url": "simo:///dev/ttyACM0"}))[0]  # lane board: not used
    assert c.status == "ok" and "not surveillance" in c.detail
