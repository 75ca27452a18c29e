"""Installation checks behind ``radar-edge doctor``: every failure comes with the fix.

Each check returns :class:`Check` results (``ok``, ``warn``, ``fail`` or ``skipped`` with the
reason). Everything the checks look at goes through :class:`System` -- the file-system root (a
mounted SD card image, or a fake tree in tests), the commands it runs (``ip``, ``vcgencmd``,
``timedatectl``, ``chronyc``), the user the service runs as, opening the board and binding a TCP
port -- so the checks are testable without a Raspberry Pi.
"""

from __future__ import annotations

import glob
import grp
import json
import logging
import math
import os
import pwd
import re
import shutil
import socket
import stat
import subprocess
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable
from urllib.parse import urlsplit

from hal.frame import SATURATED_FRACTION

log = logging.getLogger(__name__)

SERVICE_USER = "radar-edge"
DEFAULT_CONFIG = "/etc/radar-edge/radar-edge.toml"
#: CPU temperature (°C) above which the Pi starts to throttle (soft limit 80 °C, hard 85 °C)
TEMP_WARN_C = 75.0
TEMP_FAIL_C = 82.0
#: ``vcgencmd get_throttled`` bits: (bit, now?, meaning, fix)
THROTTLE_BITS = (
    (0, True, "under-voltage now", "use the official supply (5.1 V 3 A for a Pi 4, 5 A for a Pi 5) and a short cable"),
    (1, True, "ARM frequency capped now", "improve cooling (heatsink, fan, shade the enclosure)"),
    (2, True, "throttled now", "improve cooling and check the supply"),
    (3, True, "soft temperature limit active now", "improve cooling (heatsink, fan, shade the enclosure)"),
    (16, False, "under-voltage has occurred since boot", "use the official supply and a short cable"),
    (17, False, "ARM frequency capping has occurred since boot", "improve cooling"),
    (18, False, "throttling has occurred since boot", "improve cooling and check the supply"),
    (19, False, "soft temperature limit has occurred since boot", "improve cooling"),
)


@dataclass
class Check:
    name: str
    status: str  # ok | warn | fail | skipped
    detail: str
    fix: str = ""
    data: dict[str, Any] = field(default_factory=dict)


@dataclass
class Access:
    """Who the checks judge permissions for (the service user when it exists)."""

    user: str
    uid: int
    gids: frozenset[int]


class System:
    """The outside world of the checks; override attributes in tests."""

    def __init__(self, root: str | Path = "/", *, user: str | None = None) -> None:
        self.root = Path(root)
        self.access = self._access(user)

    # files
    def path(self, p: str | Path) -> Path:
        p = Path(p)
        return self.root / p.relative_to("/") if p.is_absolute() else self.root / p

    def read_text(self, p: str) -> str | None:
        try:
            return self.path(p).read_text(encoding="utf-8", errors="replace")
        except OSError:
            return None

    def glob(self, pattern: str) -> list[str]:
        """Absolute (in-root) paths matching ``pattern``."""
        base = str(self.root).rstrip("/")
        return sorted("/" + os.path.relpath(p, base) if base else p for p in glob.glob(base + pattern))

    # commands
    def which(self, name: str) -> bool:
        return shutil.which(name) is not None

    def run(self, argv: list[str], timeout_s: float = 5.0) -> tuple[int, str]:
        try:
            p = subprocess.run(argv, capture_output=True, text=True, timeout=timeout_s)
        except (OSError, subprocess.SubprocessError) as exc:
            return 127, str(exc)
        return p.returncode, p.stdout + p.stderr

    # network / board
    def tcp_bind(self, host: str, port: int) -> str | None:
        """None if ``host:port`` can be bound now, else the error."""
        fam = socket.AF_INET6 if ":" in host else socket.AF_INET
        with socket.socket(fam, socket.SOCK_STREAM) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                s.bind((host, port))
            except OSError as exc:
                return exc.strerror or str(exc)
        return None

    def probe_board(self, url: str) -> dict[str, Any]:
        """Open the source, describe it, close it (raises :class:`hal.errors.RadarError`)."""
        from hal import open_radar

        src = open_radar(url)
        try:
            src.open()
            fe = src.frontend
            info: dict[str, Any] = {"board": fe.board, "frame_shape": list(fe.frame_shape),
                                    "frame_period_s": fe.waveform.frame_period_s}
            eps = getattr(src, "endpoints", None)
            if eps:
                info["endpoints"] = dict(eps)
            tel = getattr(src, "telemetry", None)
            level = getattr(tel.get("fmcw"), "tx_power", None) if isinstance(tel, dict) else getattr(src, "tx_power", None)
            if level is not None and getattr(src, "max_tx_power", None) is not None:
                info["tx_power"] = f"{int(level)} of {int(src.max_tx_power)}"
            if isinstance(tel, dict) and tel.get("firmware") is not None:
                fw = tel["firmware"]
                if all(hasattr(fw, a) for a in ("major", "minor", "build")):
                    info["firmware"] = f"{fw.major}.{fw.minor}.{fw.build} {getattr(fw, 'description', '')}".strip()
                else:
                    info["firmware"] = str(fw)
            try:
                frame = src.read_frame(timeout=3.0)
                info["frame"] = "received"
                clipped, total = frame.clipped_samples()
                info["clipped_fraction"] = clipped / total if total else 0.0
                peak, full = frame.peak_counts()
                info["adc_peak_fraction"] = peak / full
            except Exception as exc:  # noqa: BLE001 - reported, the check goes on
                info["frame"] = f"none: {exc}"
            return info
        finally:
            src.close()

    @staticmethod
    def _access(user: str | None) -> Access:
        if user is None:
            try:
                pwd.getpwnam(SERVICE_USER)
                user = SERVICE_USER
            except KeyError:
                user = pwd.getpwuid(os.getuid()).pw_name if _has_pw(os.getuid()) else str(os.getuid())
        try:
            pw = pwd.getpwnam(user)
        except KeyError:
            return Access(user, os.getuid(), frozenset(os.getgroups()) | {os.getgid()})
        gids = {pw.pw_gid} | {g.gr_gid for g in grp.getgrall() if user in g.gr_mem}
        return Access(user, pw.pw_uid, frozenset(gids))


def _has_pw(uid: int) -> bool:
    try:
        pwd.getpwuid(uid)
        return True
    except KeyError:
        return False


def can_read_write(st: os.stat_result, who: Access) -> bool:
    if who.uid == 0:
        return True
    if st.st_uid == who.uid:
        return bool(st.st_mode & stat.S_IRUSR and st.st_mode & stat.S_IWUSR)
    if st.st_gid in who.gids:
        return bool(st.st_mode & stat.S_IRGRP and st.st_mode & stat.S_IWGRP)
    return bool(st.st_mode & stat.S_IROTH and st.st_mode & stat.S_IWOTH)


def _group_name(gid: int) -> str:
    try:
        return grp.getgrgid(gid).gr_name
    except KeyError:
        return str(gid)


# --- checks ------------------------------------------------------------------------------------------
def check_config(sys_: System, path: str | None, overrides: dict[str, Any]) -> tuple[list[Check], Any]:
    from edge.config import ConfigError, load_config

    shown = path or DEFAULT_CONFIG
    file = None
    if path is not None:
        file = path
    elif sys_.path(DEFAULT_CONFIG).is_file():
        file = str(sys_.path(DEFAULT_CONFIG))
    try:
        cfg = load_config(file, overrides=overrides)
    except ConfigError as exc:
        return [Check("config", "fail", f"{shown}: {exc}", f"edit {shown} (compare with radar-edge.example.toml)")], None
    if file is None:
        return [Check("config", "warn", f"{shown} not found: using the built-in defaults",
                      "sudo deploy/install.sh creates it, or pass --config FILE")], cfg
    return [Check("config", "ok", f"{shown} is valid")], cfg


def _serial_port(sys_: System, name: str, dev: str, fix_missing: str) -> Check:
    p = sys_.path(dev)
    try:
        st = p.stat()
    except OSError:
        return Check(name, "fail", f"{dev} does not exist", fix_missing)
    target = os.path.realpath(p) if p.is_symlink() else str(p)
    root = str(sys_.root).rstrip("/")
    if root and target.startswith(root + "/"):
        target = target[len(root):]
    shown = dev if target == str(p) else f"{dev} -> {target}"
    who = sys_.access
    if not can_read_write(st, who):
        g = _group_name(st.st_gid)
        return Check(name, "fail", f"{shown}: user {who.user} may not read and write it "
                     f"(mode {stat.filemode(st.st_mode)}, group {g})",
                     f"sudo usermod -aG {g} {who.user} (then log in again / restart the service); "
                     "the udev rule of deploy/install.sh sets group dialout, mode 0660")
    return Check(name, "ok", f"{shown} readable and writable by {who.user}")


def check_source(sys_: System, cfg: Any, open_board: bool) -> list[Check]:
    url = cfg["source"].url
    parts = urlsplit(url)
    out: list[Check] = []
    if parts.scheme in ("sim",):
        return [Check("board", "warn", f"source.url = {url!r} is the simulator, not a board",
                      'set [source] url = "d2g:///dev/radar-d2g" in the configuration')]
    if parts.scheme == "replay":
        path = parts.netloc + parts.path
        ok = sys_.path(path).is_file() if path.startswith("/") else Path(path).is_file()
        return [Check("board", "ok" if ok else "fail", f"replaying {path}" + ("" if ok else ": file not found"),
                      "" if ok else "fix source.url")]
    if parts.scheme != "d2g":
        return [Check("board", "skipped", f"no checks for source scheme {parts.scheme!r}")]
    dev = parts.path
    if parts.netloc == "auto" or not dev:
        found = sys_.glob("/dev/serial/by-id/*IFX_CDC*") + sys_.glob("/dev/radar-d2g")
        if not found:
            return [Check("serial port", "fail", "no Distance2Go found (/dev/serial/by-id/*IFX_CDC*, /dev/radar-d2g)",
                          "plug the board in (USB), check `lsusb -d 058b:0058`, and that the udev rule "
                          "/etc/udev/rules.d/99-radar-edge-d2g.rules is installed")]
        dev = found[0]
    out.append(_serial_port(sys_, "serial port", dev,
                            "plug the Distance2Go in and check `lsusb -d 058b:0058` and `dmesg | grep ttyACM`; "
                            "/dev/radar-d2g comes from the udev rule of deploy/install.sh"))
    if out[-1].status != "ok":
        return out
    if not open_board:
        out.append(Check("board", "skipped", "not opened (--no-board)"))
        return out
    from hal.errors import RadarError

    try:
        info = sys_.probe_board(url)
    except RadarError as exc:
        busy = "busy" in str(exc).lower() or "in use" in str(exc).lower()
        out.append(Check("board", "fail", f"{url}: {exc}",
                         "stop the service first (sudo systemctl stop radar-edge)" if busy else
                         "unplug and replug the board; if it persists, reflash the Radar GUI firmware "
                         "(an XMC board with other firmware has the same USB id)"))
        return out
    except (ImportError, KeyError) as exc:
        out.append(Check("board", "skipped", f"the d2g backend is not available: {exc}"))
        return out
    eps = info.get("endpoints") or {}
    detail = f"{info.get('board', '?')}; frame {info.get('frame', '?')}"
    if info.get("firmware"):
        detail += f"; firmware {info['firmware']}"
    if eps:
        detail += "; endpoints " + ", ".join(f"{n}:{t}" for t, n in sorted(eps.items(), key=lambda kv: kv[1]))
    if info.get("tx_power"):
        detail += f"; TX power level {info['tx_power']}"
    if info.get("adc_peak_fraction") is not None:
        detail += f"; ADC peak {info['adc_peak_fraction']:.0%} of full scale"
    status = "ok" if str(info.get("frame", "")).startswith("received") else "warn"
    fix = "" if status == "ok" else "the board answers but sends no frames: check the USB cable/power, then unplug and replug"
    clipped = info.get("clipped_fraction")
    if status == "ok" and clipped is not None and clipped > CLIPPED_SAMPLES_WARN:
        status = "warn"
        detail += f"; {clipped:.1%} of the frame's samples at the ADC's full scale"
        fix = ("the board is saturated (clipped samples mix every echo with the others and with the TX->RX leakage: "
               "ghost targets, wrong RCS): clear what stands close in front of the radome, check the radome and the "
               "mounting; if an empty scene still clips, the board's gain is too high for this site: lower its TX power "
               "level (radar-edge calibrate --headroom prints the source URL's tx_power), then measure C at it "
               "(calibrate --rcs)")
    out.append(Check("board", status, detail, fix, data=info))
    return out


#: a board frame with more than this share of its samples at the ADC's full scale is saturated (as calibrate --rcs)
CLIPPED_SAMPLES_WARN = SATURATED_FRACTION


def check_modbus(sys_: System, cfg: Any) -> list[Check]:
    try:
        mb = cfg["outputs.modbus"]
    except (KeyError, ValueError) as exc:
        return [Check("modbus", "skipped", f"outputs not available: {exc}")]
    out = []
    if mb.rtu_port:
        c = _serial_port(sys_, "modbus rtu", mb.rtu_port,
                         "enable the UART: deploy/install.sh --hat (enable_uart=1, dtoverlay=disable-bt in "
                         "config.txt) and reboot; or fix outputs.modbus.rtu_port")
        if c.status == "ok":
            cmdline = sys_.read_text("/proc/cmdline") or ""
            dev = os.path.basename(mb.rtu_port)
            m = re.search(r"console=(serial0|ttyAMA0|ttyS0|%s),\d+" % re.escape(dev), cmdline)
            if m:
                c = Check("modbus rtu", "fail", f"{mb.rtu_port} is also the serial console ({m.group(0)})",
                          "remove console=serial0,... from /boot/firmware/cmdline.txt (deploy/install.sh --hat does) "
                          "and reboot")
            else:
                c.detail += f", {mb.rtu_baudrate} baud {mb.rtu_parity}, unit {mb.unit_id}"
        out.append(c)
    else:
        out.append(Check("modbus rtu", "skipped", "off (outputs.modbus.rtu_port is empty)"))
    if mb.tcp_enabled:
        port = mb.tcp_port
        if 0 < port < 1024 and sys_.access.uid != 0:
            unit = sys_.read_text("/etc/systemd/system/radar-edge.service") or ""
            if "CAP_NET_BIND_SERVICE" not in re.sub(r"#.*", "", unit):
                out.append(Check("modbus tcp", "fail", f"port {port} needs CAP_NET_BIND_SERVICE, the unit has none",
                                 "sudo systemctl edit radar-edge: add CapabilityBoundingSet=CAP_NET_BIND_SERVICE and "
                                 "AmbientCapabilities=CAP_NET_BIND_SERVICE; or use port 5020"))
                return out
        err = sys_.tcp_bind(mb.tcp_host, port) if port else None
        if err:
            out.append(Check("modbus tcp", "warn", f"{mb.tcp_host}:{port} cannot be bound now: {err}",
                             "fine if radar-edge is running (systemctl is-active radar-edge); otherwise find the "
                             f"other program: sudo ss -ltnp 'sport = :{port}'"))
        else:
            out.append(Check("modbus tcp", "ok", f"{mb.tcp_host}:{port} is free"))
    else:
        out.append(Check("modbus tcp", "skipped", "off (outputs.modbus.tcp_enabled = false)"))
    return out


def check_can(sys_: System, cfg: Any) -> list[Check]:
    try:
        cn = cfg["outputs.can"]
    except (KeyError, ValueError) as exc:
        return [Check("can", "skipped", f"outputs not available: {exc}")]
    if not cn.interface:
        return [Check("can", "skipped", "off (outputs.can.interface is empty)")]
    if cn.interface != "socketcan":
        return [Check("can", "skipped", f"interface {cn.interface!r}: only socketcan is checked")]
    if not sys_.which("ip"):
        return [Check("can", "skipped", "`ip` (iproute2) is not installed")]
    rc, text = sys_.run(["ip", "-details", "-json", "link", "show", cn.channel])
    up_cmd = (f"sudo ip link set {cn.channel} up type can bitrate {cn.bitrate} restart-ms 100 "
              f"(permanent: /etc/systemd/network/80-radar-edge-can0.network from deploy/install.sh)")
    if rc != 0:
        return [Check("can", "fail", f"no interface {cn.channel}: {text.strip()[:120]}",
                      "check the MCP2515 overlay in config.txt (dtoverlay=mcp2515-can0,oscillator=...,interrupt=...) "
                      "matches the HAT's crystal, reboot, and look at `dmesg | grep -i mcp251`")]
    try:
        link = json.loads(text)[0]
    except (ValueError, IndexError, KeyError):
        return [Check("can", "warn", f"cannot parse `ip -json link show {cn.channel}`", "")]
    info = (link.get("linkinfo") or {}).get("info_data") or {}
    flags = link.get("flags") or []
    bitrate = int((info.get("bittiming") or {}).get("bitrate") or 0)
    state = info.get("state", "?")
    restart_ms = info.get("restart_ms")
    data = {"state": state, "bitrate": bitrate, "restart_ms": restart_ms, "txqlen": link.get("txqlen"),
            "operstate": link.get("operstate")}
    if "UP" not in flags:
        return [Check("can", "fail", f"{cn.channel} is down", up_cmd, data)]
    if bitrate and bitrate != cn.bitrate:
        return [Check("can", "fail", f"{cn.channel} runs at {bitrate} bit/s, the configuration says {cn.bitrate}",
                      f"make them equal: {up_cmd}", data)]
    if state in ("BUS-OFF", "STOPPED"):
        return [Check("can", "fail", f"{cn.channel} is {state}",
                      "check wiring, 120 ohm termination at both ends and the bitrate of the other nodes; "
                      f"restart-ms recovers bus-off automatically: {up_cmd}", data)]
    if state in ("ERROR-PASSIVE", "ERROR-WARNING"):
        return [Check("can", "warn", f"{cn.channel} is {state} (frames are not acknowledged)",
                      "is another node on the bus? check termination (120 ohm at both ends)", data)]
    if not restart_ms:
        return [Check("can", "warn", f"{cn.channel} up at {bitrate} bit/s but restart-ms is 0 (no bus-off recovery)",
                      up_cmd, data)]
    return [Check("can", "ok", f"{cn.channel} {state} at {bitrate} bit/s, restart-ms {restart_ms}, "
                  f"txqueuelen {link.get('txqlen')}", data=data)]


#: configuration keys that name a model or data file the pipelines load (empty = the packaged default)
MODEL_FILE_KEYS = ("classify.onnx.model", "classify.knn.reference_set")
#: a string value with one of these suffixes is a model file whatever its key is called
MODEL_SUFFIXES = (".onnx", ".npz")


def _model_fields(cfg: Any) -> Iterable[tuple[str, str]]:
    """(dotted key, path) of every configured model file: the keys of :data:`MODEL_FILE_KEYS` and any
    string value ending in a model suffix. A field is never taken for a path by its name alone
    (``track.pdaf.motion_model = "imm"`` is a choice, not a file)."""
    import dataclasses

    from edge.config import SECTIONS

    for name in sorted(SECTIONS):
        try:
            sec = cfg[name]
        except Exception:  # noqa: BLE001 - a section whose module is missing is reported by other checks
            continue
        for f in dataclasses.fields(sec):
            v = getattr(sec, f.name)
            key = f"{name}.{f.name}"
            if isinstance(v, str) and v and (key in MODEL_FILE_KEYS or v.lower().endswith(MODEL_SUFFIXES)):
                yield key, v


def check_classifier(sys_: System, cfg: Any) -> list[Check]:
    """The surveillance classifier exactly as the pipeline loads it (``classify.onnx``): file, graph,
    radar-edge metadata and feature schema."""
    try:
        from edge.classify import onnx_runtime as ox
    except ImportError as exc:
        return [Check("classifier", "skipped", f"the ONNX classifier is not in this build ({exc})")]
    try:
        oc = cfg["classify.onnx"]
    except (KeyError, ValueError) as exc:
        return [Check("classifier", "skipped", f"no classify.onnx section: {exc}")]
    if getattr(oc, "backend", "onnx") != "onnx":
        return [Check("classifier", "skipped", f"classify.onnx.backend = {oc.backend!r} (no model file)")]
    path = oc.model or None
    if path and path.startswith("/"):
        path = str(sys_.path(path))
    try:
        clf = ox.OnnxKnnClassifier(path, threads=1)
    except ox.ModelError as exc:
        return [Check("classifier", "fail", str(exc),
                      "set classify.onnx.model to a model made by `radar-edge export-onnx` with this version, "
                      "or leave it empty for the packaged default")]
    detail = (f"{clf.path.name}: k={clf.k} {clf.metric}, classes {', '.join(clf.classes)}, "
              f"{len(clf.feature_names)} features, reference {clf.reference_sha256[:12]}")
    data = {"path": str(clf.path), "classes": list(clf.classes), "features": list(clf.feature_names)}
    from edge.classify.features import feature_setting_mismatches

    recorded = (getattr(clf, "metadata", None) or {}).get("build", {}).get("classify.features", {})
    bad = feature_setting_mismatches(recorded, cfg["classify.features"])
    if bad:
        return [Check("classifier", "warn", f"{detail}; classify.features differ from its reference set's: "
                      + "; ".join(bad), "set them as the model's reference set was built, or rebuild the set "
                      "(edge.classify.refgen) and the model (radar-edge export-onnx)", data=data)]
    if not recorded:
        detail += " (no feature settings recorded: not compared)"
    return [Check("classifier", "ok", detail, data=data)]


def check_models(sys_: System, cfg: Any) -> list[Check]:
    models = [(k, v) for k, v in _model_fields(cfg) if not k.startswith("classify.onnx.")]
    if not models:
        return [Check("model", "skipped", "no other model file in the configuration")]
    out = []
    for key, path in models:
        p = Path(path) if not path.startswith("/") else sys_.path(path)
        if not p.is_file():
            pkg = Path(__file__).resolve().parents[1] / "data" / path
            if pkg.is_file():
                p = pkg
            else:
                out.append(Check("model", "fail", f"{key} = {path!r}: file not found",
                                 "reinstall the package (deploy/install.sh) or train/export the model and fix the path"))
                continue
        if p.suffix != ".onnx":
            out.append(Check("model", "ok", f"{key}: {p} ({p.stat().st_size} bytes)"))
            continue
        try:
            import onnxruntime as ort

            sess = ort.InferenceSession(str(p), providers=["CPUExecutionProvider"])
        except ImportError as exc:
            out.append(Check("model", "fail", f"onnxruntime is missing: {exc}", "pip install onnxruntime (deploy/install.sh)"))
            continue
        except Exception as exc:  # noqa: BLE001 - onnxruntime raises its own exception types
            out.append(Check("model", "fail", f"{key}: {p.name} does not load: {exc}", "re-export the model"))
            continue
        ins = [(i.name, i.shape, i.type) for i in sess.get_inputs()]
        outs = [(o.name, o.shape, o.type) for o in sess.get_outputs()]
        detail = f"{key}: {p.name}; inputs {ins}; outputs {[o[0] for o in outs]}"
        bad = [i for i in ins if i[2] != "tensor(float)"]
        if bad:
            out.append(Check("model", "fail", detail + f"; input type {bad[0][2]}, expected tensor(float)",
                             "re-export with float32 inputs (radar-edge export-onnx)"))
        else:
            out.append(Check("model", "ok", detail, data={"inputs": ins, "outputs": outs}))
    return out


def check_temperature(sys_: System) -> list[Check]:
    out = []
    zones = sys_.glob("/sys/class/thermal/thermal_zone*/temp")
    if zones:
        raw = (sys_.read_text(zones[0]) or "").strip()
        try:
            t = int(raw) / 1000.0
        except ValueError:
            out.append(Check("cpu temperature", "skipped", f"cannot read {zones[0]}: {raw!r}"))
        else:
            fix = "improve cooling: heatsink or fan, a vented or shaded enclosure"
            if t >= TEMP_FAIL_C:
                out.append(Check("cpu temperature", "fail", f"{t:.1f} °C (the Pi throttles from 80-85 °C)", fix))
            elif t >= TEMP_WARN_C:
                out.append(Check("cpu temperature", "warn", f"{t:.1f} °C, close to the throttling limit", fix))
            else:
                out.append(Check("cpu temperature", "ok", f"{t:.1f} °C", data={"temp_c": t}))
    else:
        out.append(Check("cpu temperature", "skipped", "no /sys/class/thermal/thermal_zone*/temp (not a Pi?)"))
    if not sys_.which("vcgencmd"):
        out.append(Check("throttling", "skipped", "vcgencmd not installed (Raspberry Pi OS has it in raspi-utils)"))
        return out
    rc, text = sys_.run(["vcgencmd", "get_throttled"])
    m = re.search(r"throttled=(0x[0-9a-fA-F]+)", text)
    if rc != 0 or m is None:
        out.append(Check("throttling", "skipped", f"vcgencmd get_throttled failed: {text.strip()[:100]}"))
        return out
    bits = int(m.group(1), 16)
    now = [(what, fix) for b, is_now, what, fix in THROTTLE_BITS if is_now and bits >> b & 1]
    past = [(what, fix) for b, is_now, what, fix in THROTTLE_BITS if not is_now and bits >> b & 1]
    if now:
        out.append(Check("throttling", "fail", f"{m.group(1)}: " + "; ".join(w for w, _ in now), now[0][1]))
    elif past:
        out.append(Check("throttling", "warn", f"{m.group(1)}: " + "; ".join(w for w, _ in past), past[0][1]))
    else:
        out.append(Check("throttling", "ok", f"{m.group(1)}: no under-voltage or throttling since boot"))
    return out


def check_clock(sys_: System) -> list[Check]:
    fix = ("sudo timedatectl set-ntp true; make sure the NTP server is reachable (lane statistics and "
           "recordings carry wall-clock times)")
    if sys_.which("timedatectl"):
        rc, text = sys_.run(["timedatectl", "show", "-p", "NTPSynchronized", "-p", "NTP", "--value"])
        vals = text.split()
        if rc == 0 and vals:
            if vals[0] == "yes":
                return [Check("clock", "ok", "synchronised (timedatectl)")]
            return [Check("clock", "fail", "not synchronised (timedatectl NTPSynchronized=no)", fix)]
    if sys_.which("chronyc"):
        rc, text = sys_.run(["chronyc", "tracking"])
        m = re.search(r"Leap status\s*:\s*(.+)", text)
        if rc == 0 and m:
            if m.group(1).strip() == "Normal":
                return [Check("clock", "ok", "synchronised (chrony)")]
            return [Check("clock", "fail", f"chrony leap status {m.group(1).strip()}", "chronyc sources -v; " + fix)]
    return [Check("clock", "skipped", "neither timedatectl nor chronyc could tell")]


def check_recorder(sys_: System, cfg: Any) -> list[Check]:
    rc = cfg["ops.recorder"]
    if not rc.enabled:
        return [Check("recordings", "skipped", "off (ops.recorder.enabled = false)")]
    d = sys_.path(rc.directory)
    if not d.is_dir():
        return [Check("recordings", "fail", f"{rc.directory} does not exist",
                      f"sudo install -d -o {SERVICE_USER} -g {SERVICE_USER} -m 0750 {rc.directory}")]
    st = d.stat()
    who = sys_.access
    writable = who.uid == 0 or (st.st_uid == who.uid and st.st_mode & stat.S_IWUSR) or (
        st.st_gid in who.gids and st.st_mode & stat.S_IWGRP)
    if not writable:
        return [Check("recordings", "fail", f"{rc.directory} is not writable by {who.user}",
                      f"sudo chown -R {who.user}: {rc.directory}")]
    free_mb = shutil.disk_usage(d).free / 1e6
    used_mb = sum(p.stat().st_size for p in d.glob("*.npz")) / 1e6
    detail = f"{rc.directory}: {used_mb:.0f} of {rc.quota_mb:.0f} MB used, {free_mb:.0f} MB free"
    if free_mb < rc.min_free_mb:
        return [Check("recordings", "fail", detail + f" (< min_free_mb {rc.min_free_mb:.0f}): recording is stopped",
                      "free space on the SD card, or lower ops.recorder.quota_mb")]
    if free_mb + used_mb - rc.min_free_mb < rc.quota_mb:
        return [Check("recordings", "warn", detail + ": the quota does not fit on the disk",
                      "lower ops.recorder.quota_mb below the free space")]
    return [Check("recordings", "ok", detail)]


def check_traffic_calibration(sys_: System, cfg: Any) -> list[Check]:
    """The lane profile's saved self-calibration (``traffic.calibration_file``): readable, which yaw and
    lanes, how old; its directory writable (or nothing is kept across restarts)."""
    import time

    from edge.traffic.calibration import CalibrationError, load_calibration

    path = cfg["traffic"].calibration_file
    if not path:
        return [Check("traffic calibration", "skipped", "off (traffic.calibration_file is empty)")]
    p = sys_.path(path)
    if not p.parent.is_dir():
        return [Check("traffic calibration", "fail", f"{p.parent} does not exist: the calibration cannot be saved",
                      f"sudo install -d -o {SERVICE_USER} -g {SERVICE_USER} -m 0750 {Path(path).parent}")]
    st = p.parent.stat()
    who = sys_.access
    if not (who.uid == 0 or (st.st_uid == who.uid and st.st_mode & stat.S_IWUSR)
            or (st.st_gid in who.gids and st.st_mode & stat.S_IWGRP)):
        return [Check("traffic calibration", "fail", f"{Path(path).parent} is not writable by {who.user}",
                      f"sudo chown {who.user}: {Path(path).parent}")]
    try:
        cal = load_calibration(p)
    except CalibrationError as e:
        return [Check("traffic calibration", "warn", f"{path} is ignored at start: {e}",
                      f"delete {path}; the service learns the yaw and lanes again from traffic")]
    if cal is None:
        return [Check("traffic calibration", "ok", f"{path}: none saved yet (written once the yaw is estimated)")]
    age_h = max(time.time() - cal.saved_unix_s, 0.0) / 3600.0 if cal.saved_unix_s else float("nan")
    detail = (f"{path}: yaw {math.degrees(cal.yaw_rad):.2f} +- {math.degrees(cal.yaw_stderr_rad):.2f} deg from "
              f"{cal.yaw_votes} tracks, {len(cal.lanes)} lanes ({cal.lane_mode}), saved {age_h:.1f} h ago")
    return [Check("traffic calibration", "ok", detail,
                  data={"yaw_deg": math.degrees(cal.yaw_rad), "lanes": len(cal.lanes), "age_h": age_h})]


def check_rcs_calibration(cfg: Any) -> list[Check]:
    """The surveillance RCS calibration constant C (``classify.features.rcs_calibration_*``): its value, uncertainty
    and whether it was measured (`radar-edge calibrate --rcs`) or is the datasheet default (warn: a unit's gain
    spread of several dB moves the classes of vehicles)."""
    from edge.classify.calibration import DATASHEET_C_DB

    try:
        fc = cfg["classify.features"]
    except (KeyError, ValueError) as exc:
        return [Check("rcs calibration", "skipped", f"no classify.features section: {exc}")]
    c, sd, source = fc.rcs_calibration_db, fc.rcs_calibration_sd_db, fc.rcs_calibration_source
    data = {"c_db": c, "sd_db": sd, "source": source, "datasheet_c_db": DATASHEET_C_DB}
    detail = f"C = {c:.2f} +- {sd:.2f} dB, {source} ({c - DATASHEET_C_DB:+.2f} dB from the datasheet's {DATASHEET_C_DB:.2f})"
    profile = cfg["loop"].profile
    if profile == "auto":
        url = cfg["source"].url
        profile = "surveillance" if url.startswith("d2g:") or url.startswith("sim://d2g") else "other"
    if source == "measured" or profile != "surveillance":
        if profile != "surveillance":
            detail += " (not used: the profile is not surveillance)"
        return [Check("rcs calibration", "ok", detail, data=data)]
    return [Check("rcs calibration", "warn", detail + ": not measured on this board (surveillance profile)",
                  "with a corner reflector on boresight: radar-edge calibrate --rcs --source d2g:///dev/ttyACM0 "
                  "--range-m R --reflector-edge-m A, then store the printed [classify.features] settings",
                  data=data)]


def check_user(sys_: System) -> list[Check]:
    """The service user exists and is in ``dialout`` (the group of the serial ports and the udev rule)."""
    if str(sys_.root) != "/":
        return [Check("service user", "skipped", "not checked inside --root")]
    try:
        pwd.getpwnam(SERVICE_USER)
    except KeyError:
        return [Check("service user", "warn", f"user {SERVICE_USER} does not exist", "sudo deploy/install.sh")]
    try:
        dialout = grp.getgrnam("dialout").gr_gid
    except KeyError:
        return [Check("service user", "skipped", "no dialout group on this system")]
    who = System._access(SERVICE_USER)
    if dialout not in who.gids:
        return [Check("service user", "fail", f"{SERVICE_USER} is not in the dialout group: no access to serial ports",
                      f"sudo usermod -aG dialout {SERVICE_USER} && sudo systemctl restart radar-edge")]
    return [Check("service user", "ok", f"{SERVICE_USER} is in dialout")]


def check_service(sys_: System) -> list[Check]:
    unit_path = "/etc/systemd/system/radar-edge.service"
    unit = sys_.read_text(unit_path)
    if unit is None:
        return [Check("service", "warn", f"{unit_path} is not installed", "sudo deploy/install.sh")]
    m = re.search(r"^ExecStart=(\S+)", unit, re.M)
    exe = m.group(1) if m else ""
    if exe and not sys_.path(exe).exists():
        return [Check("service", "fail", f"the unit starts {exe}, which does not exist",
                      "sudo deploy/install.sh (creates the virtual environment)")]
    if str(sys_.root) != "/" or not sys_.which("systemctl"):
        return [Check("service", "ok", f"{unit_path} installed (state not queried)")]
    _, enabled = sys_.run(["systemctl", "is-enabled", "radar-edge.service"])
    _, active = sys_.run(["systemctl", "is-active", "radar-edge.service"])
    enabled, active = enabled.strip().splitlines()[-1:] or ["?"], active.strip().splitlines()[-1:] or ["?"]
    detail = f"{enabled[0]}, {active[0]}"
    if active[0] == "failed":
        return [Check("service", "fail", detail, "journalctl -u radar-edge -n 50 shows why; then "
                      "sudo systemctl restart radar-edge")]
    if enabled[0] != "enabled":
        return [Check("service", "warn", detail, "sudo systemctl enable --now radar-edge")]
    return [Check("service", "ok", detail)]


def check_kernels(sys_: System | None = None) -> list[Check]:
    """The compiled post-FFT kernels (``edge.native``) of this interpreter's installation: all loaded (ok), some
    not built (warn: the numpy fallback runs, correct but several times slower), or disabled on purpose with
    ``RADAR_EDGE_KERNELS=0`` (skipped). Not judged for another root (``--root``): only this interpreter's
    installation can be imported."""
    from edge import native

    if sys_ is not None and str(sys_.root) != "/":
        return [Check("kernels", "skipped", "not checked inside --root (only this interpreter's installation)")]
    if not native.enabled():
        return [Check("kernels", "skipped", native.status())]
    gone = native.missing()
    if gone:
        return [Check("kernels", "warn", native.status(),
                      "sudo apt-get install build-essential python3-dev, then reinstall to build them: "
                      "sudo deploy/install.sh on the Pi, or pip install -e . in a checkout",
                      data={"missing": gone})]
    return [Check("kernels", "ok", f"{native.status()}: {', '.join(native.KERNELS)}",
                  data={"loaded": list(native.KERNELS)})]


def run_checks(sys_: System, config_path: str | None = None, overrides: dict[str, Any] | None = None,
               *, open_board: bool = True) -> list[Check]:
    checks, cfg = check_config(sys_, config_path, dict(overrides or {}))
    if cfg is not None:
        for fn in (lambda: check_source(sys_, cfg, open_board), lambda: check_modbus(sys_, cfg),
                   lambda: check_can(sys_, cfg), lambda: check_classifier(sys_, cfg), lambda: check_models(sys_, cfg),
                   lambda: check_recorder(sys_, cfg), lambda: check_traffic_calibration(sys_, cfg),
                   lambda: check_rcs_calibration(cfg)):
            checks.extend(_guard(fn))
    else:
        checks.append(Check("outputs", "skipped", "the configuration does not load"))
    checks.extend(_guard(lambda: check_kernels(sys_)))
    checks.extend(_guard(lambda: check_user(sys_)))
    checks.extend(_guard(lambda: check_service(sys_)))
    checks.extend(_guard(lambda: check_temperature(sys_)))
    checks.extend(_guard(lambda: check_clock(sys_)))
    return checks


def _guard(fn: Callable[[], list[Check]]) -> list[Check]:
    try:
        return fn()
    except Exception as exc:  # noqa: BLE001 - one broken check must not hide the others
        log.debug("check failed", exc_info=True)
        return [Check("doctor", "fail", f"a check crashed: {type(exc).__name__}: {exc}", "report this as a bug")]


def as_json(checks: list[Check]) -> str:
    return json.dumps({"ok": not any(c.status == "fail" for c in checks), "checks": [asdict(c) for c in checks]},
                      indent=2, default=str)
