"""Configuration sections of the outputs: ``outputs.modbus``, ``outputs.can``, ``outputs.failsafe``.

Modbus TCP is on by default on the loopback interface (development: 127.0.0.1:5020; use
``0.0.0.0:502`` on a deployed box, which needs ``CAP_NET_BIND_SERVICE``). Modbus RTU and CAN stay
off until a serial port or a CAN interface is configured.
"""

from __future__ import annotations

from dataclasses import dataclass, field

#: Modbus RTU baud codes of configuration register 2001 (index = code)
BAUD_CODES: tuple[int, ...] = (9600, 19200, 38400, 57600, 115200)
#: parity codes of configuration register 2002 (index = code)
PARITY_CODES: tuple[str, ...] = ("N", "E", "O")
#: CAN bitrate codes of configuration register 2007 (index = code)
CAN_BITRATE_CODES: tuple[int, ...] = (125_000, 250_000, 500_000, 1_000_000)


@dataclass(frozen=True)
class ModbusConfig:
    tcp_enabled: bool = field(default=True, metadata={"doc": "serve Modbus TCP"})
    tcp_host: str = field(
        default="127.0.0.1",
        metadata={"doc": "TCP bind address (127.0.0.1 = this machine only; 0.0.0.0 = all interfaces)"},
    )
    tcp_port: int = field(
        default=5020,
        metadata={"doc": "TCP port (502 is the Modbus standard and needs root or CAP_NET_BIND_SERVICE; "
                         "0 = let the OS choose)", "min": 0, "max": 65535},
    )
    rtu_port: str = field(
        default="",
        metadata={"doc": "serial port for Modbus RTU on RS-485, e.g. /dev/ttyAMA0 or /dev/ttySC0 "
                         "(empty = RTU off)"},
    )
    rtu_baudrate: int = field(
        default=19200, metadata={"unit": "bit/s", "doc": "RTU baud rate (Modbus spec default 19200)",
                                 "choices": BAUD_CODES},
    )
    rtu_parity: str = field(
        default="E", metadata={"doc": "RTU parity: E (Modbus spec default, 8E1), N (then use 2 stop bits "
                                      "per the spec; many devices ship 8N1), O", "choices": PARITY_CODES},
    )
    rtu_stopbits: int = field(default=1, metadata={"doc": "RTU stop bits", "choices": (1, 2)})
    rtu_retry_s: float = field(
        default=5.0,
        metadata={"unit": "s", "doc": "a serial port that cannot be opened (USB RS-485 adapter unplugged at "
                                      "start) is retried this often; Modbus TCP serves meanwhile",
                  "min": 0.05, "max": 600.0},
    )
    unit_id: int = field(
        default=1,
        metadata={"doc": "RTU unit (slave) id on the shared RS-485 line; requests for other ids get no "
                         "reply. Modbus TCP answers every unit id.", "min": 1, "max": 247},
    )
    config_writes: bool = field(
        default=False,
        metadata={"doc": "allow writes to the configuration block 2000-2099 (staged, applied by the "
                         "command register 2090); off = FC6/FC16 are not served (exception 01)"},
    )
    serial_number: int = field(
        default=0, metadata={"doc": "device serial number reported in registers 7-8", "min": 0, "max": 0xFFFFFFFE}
    )
    stale_image_s: float = field(
        default=1.0,
        metadata={"unit": "s", "doc": "the Modbus server process shows the fault itself (alarm 4, loop state 5) "
                                      "when the frame loop sent no image for this long (frozen, hung or crashed); "
                                      "keep it above loop.health_period_s", "min": 0.1, "max": 1.9},
    )
    start_timeout_s: float = field(
        default=30.0, metadata={"unit": "s", "doc": "give up starting the server process after this long "
                                                    "(about 0.5 s on a PC, several s on a slow board)",
                                "min": 0.1, "max": 300.0},
    )
    cpus: tuple[int, ...] = field(
        default=(),
        metadata={"doc": "CPUs the Modbus server process is pinned to, e.g. [0, 1, 2] with loop.cpus = [3], "
                         "so that masters polling hard never take the frame loop's core (Linux; empty = "
                         "not pinned)", "min": 0, "max": 1023},
    )


@dataclass(frozen=True)
class CanConfig:
    interface: str = field(
        default="",
        metadata={"doc": "python-can interface: socketcan on the Pi, virtual in tests, slcan/serial over a "
                         "serial port (empty = CAN off)"},
    )
    channel: str = field(default="can0", metadata={"doc": "python-can channel (can0, a virtual bus name, a tty)"})
    bitrate: int = field(
        default=500_000,
        metadata={"unit": "bit/s", "doc": "bus bitrate (ARS408 default 500 kbit/s); on socketcan set it with "
                                          "`ip link`, python-can does not", "choices": CAN_BITRATE_CODES},
    )
    sensor_id: int = field(
        default=0, metadata={"doc": "ARS408 sensor id: every ARS408 message id is offset by 0x10 x sensor_id",
                             "min": 0, "max": 7},
    )
    send_quality: bool = field(default=False, metadata={"doc": "send 0x60C Obj_2_Quality per object"})
    send_extended: bool = field(default=True, metadata={"doc": "send 0x60D Obj_3_Extended (class, size) per object"})
    send_lane_stats: bool = field(default=True, metadata={"doc": "send 0x690-0x692 lane statistics per interval"})
    send_presence: bool = field(default=True, metadata={"doc": "send 0x693 lane presence every frame"})
    max_bus_load: float = field(
        default=0.5,
        metadata={"doc": "rate limit: fraction of the bitrate our frames may use (worst-case stuffed "
                         "135-bit frames); object lists are truncated (nearest first) to stay below",
                  "min": 0.01, "max": 0.9},
    )
    state_period_s: float = field(
        default=1.0, metadata={"unit": "s", "doc": "period of 0x201 RadarState and 0x700 VersionID "
                                                   "(sent at once when the health changes)", "min": 0.05, "max": 10.0},
    )
    reconnect_s: float = field(
        default=2.0, metadata={"unit": "s", "doc": "retry opening a missing/failed interface after this long",
                               "min": 0.1, "max": 300.0},
    )
    queue_frames: int = field(
        default=4, metadata={"doc": "results waiting for the CAN thread; older ones are dropped and counted",
                             "min": 1, "max": 64},
    )


@dataclass(frozen=True)
class FailsafeConfig:
    stale_after_s: float = field(
        default=1.0,
        metadata={"unit": "s", "doc": "no frame result for this long = fault: status and CAN state show it, "
                                      "presence goes to the fail-safe state (must stay below 2 s)",
                  "min": 0.1, "max": 1.9},
    )
    presence: str = field(
        default="on",
        metadata={"doc": "per-lane presence while in fault: on (call every lane, as detector rack cards "
                         "do), off, or hold the last value", "choices": ("on", "off", "hold")},
    )
    stats_stale_intervals: float = field(
        default=2.0,
        metadata={"doc": "lane statistics older than this many interval lengths are flagged stale",
                  "min": 1.0, "max": 100.0},
    )
