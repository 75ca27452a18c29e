"""Distance2Go firmware emulator: protocol behaviour without I/O (fake time), framing checks, and
one raw exchange over the pseudo-terminal."""

from __future__ import annotations

import os
import select

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hal import comlib as cl
from hal.comlib import Ep0, Rbas, Rfmc
from hw_sim.d2g_device import D2GEmulator, D2GFirmware, DeviceFramer, SteppedClock


class FakeTime:
    def __init__(self):
        self.t = 0.0
        self.waits = []

    def now(self):
        return self.t

    def wait(self, t):
        self.waits.append(t)
        self.t = max(self.t, t)
        return True


def _zeros(scene, fmt):
    shape = (1, fmt.chirps_per_frame, fmt.samples_per_chirp)
    return np.full(shape, scene % 2000, np.int16), np.zeros(shape, np.int16)


@pytest.fixture
def fw():
    t = FakeTime()
    f = D2GFirmware(_zeros, clock=t.now, wait=t.wait)
    f.fake_time = t
    return f


def _call(fw, ep, msg_type, body=b""):
    """Send one request; return (decoded payloads, status code)."""
    out = fw.handle(cl.Payload(ep, bytes([msg_type]) + body))
    d = cl.Decoder()
    msgs = d.feed(b"".join(out))
    assert d.discarded == 0 and isinstance(msgs[-1], cl.Status) and msgs[-1].endpoint == ep
    assert all(isinstance(m, cl.Payload) for m in msgs[:-1])
    return msgs[:-1], msgs[-1].code


def _format(fw, chirps=21, samples=64, rx=1, part=2):
    return _call(fw, 1, Rbas.FRAME_FORMAT, cl.FrameFormat(samples, chirps, rx, part).encode()[1:])


def _trigger(fw, us):
    return _call(fw, 1, Rbas.SET_AUTOMATIC_TRIGGER, us.to_bytes(4, "little"))


def _up_only(fw):
    cfg = fw.fmcw
    return _call(fw, 3, Rfmc.CONFIGURATION, cl.FmcwConfig(cfg.lower_khz, cfg.upper_khz, 0, cfg.tx_power).encode()[1:])


def _frame_numbers(payloads):
    return [cl.parse_frame(p.data)[0].frame_number for p in payloads if p.msg_type == Rbas.FRAME_DATA]


def test_endpoint_list_and_firmware_info(fw):
    p, code = _call(fw, 0, Ep0.QUERY_ENDPOINT_INFO)
    assert code == 0
    assert [r.tag for r in cl.parse_endpoint_list(p[0].data)] == ["RBAS", "RADX", "RFMC", "RDPL", "RIND", "RCAL", "RTDC"]
    p, code = _call(fw, 0, Ep0.QUERY_FW_INFO)
    assert code == 0 and cl.FirmwareInfo.parse(p[0].data).major == 1
    assert _call(fw, 0, 0x7F)[1] == 0xFFFF


def test_set_frame_format_announces_even_when_it_fails(fw):
    p, code = _format(fw, chirps=21)  # power-on ramps alternate: 21 chirps is odd
    assert code == 0x0020
    kinds = [(m.endpoint, m.msg_type) for m in p]
    assert kinds == [(1, Rbas.FRAME_FORMAT), (1, Rbas.CHIRP_DURATION), (1, Rbas.MIN_INTERVAL), (2, 0x01), (3, Rfmc.BW_PER_SECOND)]
    assert cl.FrameFormat.parse(p[0].data).chirps_per_frame == 16  # unchanged
    p, code = _up_only(fw)
    assert code == 0 and [(m.endpoint, m.msg_type) for m in p] == [(3, 0x01), (3, 0x02), (1, Rbas.TX_POWER)]
    p, code = _format(fw)
    assert code == 0 and cl.FrameFormat.parse(p[0].data) == cl.FrameFormat(64, 21, 1, 2)
    assert cl.parse_u32_reply(p[2].data, Rbas.MIN_INTERVAL, "min") == 47_100  # 21 x 2.1 ms + 3 ms


@pytest.mark.parametrize(
    "kwargs, code",
    [({"samples": 100}, 0x0050), ({"chirps": 0}, 0x0008), ({"chirps": 65}, 0x0008), ({"rx": 2}, 0x0006), ({"part": 0}, 0x000B)],
)
def test_frame_format_refusals(fw, kwargs, code):
    _up_only(fw)
    assert _format(fw, **kwargs)[1] == code


def test_busy_while_the_trigger_runs_and_interval_limits(fw):
    _up_only(fw)
    _format(fw)
    assert _trigger(fw, 47_000)[1] == 0x0005
    assert _trigger(fw, 50_000)[1] == 0
    assert _format(fw)[1] == 0x0002
    assert _up_only(fw)[1] == 0x0002
    assert _trigger(fw, 0)[1] == 0
    assert _format(fw)[1] == 0


def test_trigger_keeps_only_the_newest_frame_and_restarts_the_counter(fw):
    t = fw.fake_time
    _up_only(fw)
    _format(fw)
    _trigger(fw, 50_000)
    assert _call(fw, 1, Rbas.GET_FRAME_DATA, b"\x00")[1] == 0x0004  # wait=0, nothing yet
    p, code = _call(fw, 1, Rbas.GET_FRAME_DATA, b"\x01")  # wait=1 blocks until frame 0 is complete
    assert code == 0 and _frame_numbers(p) == [0] and t.waits[-1] == pytest.approx(0.05)
    assert _call(fw, 1, Rbas.GET_FRAME_DATA, b"\x00")[1] == 0x0004  # frame 0 already delivered
    t.t += 0.05 * 4 + 0.01  # a slow host: frames 1..4 complete, only 4 is kept
    p, _ = _call(fw, 1, Rbas.GET_FRAME_DATA, b"\x00")
    assert _frame_numbers(p) == [4]
    _trigger(fw, 50_000)  # restart: the counter starts again, the scene goes on
    p, _ = _call(fw, 1, Rbas.GET_FRAME_DATA, b"\x01")
    assert _frame_numbers(p) == [0]
    h, i, q = cl.parse_frame(p[0].data)
    assert int(i[0, 0, 0]) == 5  # scene index: 5 acquisitions (0..4) before the restart


def test_temperature_is_pushed_after_a_frame_only_when_it_changed(fw):
    _up_only(fw)
    _format(fw)
    _trigger(fw, 50_000)
    temps = []
    for _ in range(30):
        p, _ = _call(fw, 1, Rbas.GET_FRAME_DATA, b"\x01")
        temps.append([cl.parse_sensor_reply(m.data, Rbas.TEMPERATURE, "t")[1] for m in p if m.msg_type == Rbas.TEMPERATURE])
    assert temps[0] == [38_000] and temps[25] == [38_125]
    assert sum(len(x) for x in temps) == 2
    assert _call(fw, 1, Rbas.GET_TEMPERATURE, b"\x01")[1] == 0x0007
    p, code = _call(fw, 1, Rbas.GET_TEMPERATURE, b"\x00")
    assert code == 0 and cl.parse_sensor_reply(p[0].data, Rbas.TEMPERATURE, "t")[0] == 0


def test_wrong_length_and_unknown_types_are_invalid_payloads(fw):
    assert _call(fw, 1, Rbas.GET_FRAME_DATA)[1] == 0xFFFF
    assert _call(fw, 1, 0x7E)[1] == 0xFFFF
    assert _call(fw, 6, 0x02)[1] == 0xFFFF  # RCAL is not emulated


@pytest.mark.parametrize(
    "wire, code",
    [
        (b"\x00\x01", 0x0002),
        (bytes.fromhex("5A090100") + b"\x00\xdb\xe0", 0x0003),
        (bytes.fromhex("5A010000"), 0x0005),
        (bytes.fromhex("5A01FF01"), 0x0006),
        (bytes.fromhex("5A010100001234"), 0x0007),
    ],
)
def test_device_framing_errors(wire, code):
    f = DeviceFramer(7)
    msgs, err = f.feed(wire)
    assert msgs == [] and err == code
    assert f.feed(cl.request(1, Rbas.GET_DEVICE_INFO)) == ([], None)  # ignored until the line is quiet
    assert f.quiet() is None
    msgs, err = f.feed(cl.request(1, Rbas.GET_DEVICE_INFO))
    assert err is None and msgs == [cl.Payload(1, bytes([Rbas.GET_DEVICE_INFO]))]


def test_incomplete_message_gets_0001_when_the_line_goes_quiet():
    f = DeviceFramer(7)
    assert f.feed(cl.request(1, Rbas.GET_DEVICE_INFO)[:5]) == ([], None)
    assert f.quiet() == 0x0001


def test_raw_exchange_over_the_pty():
    clock = SteppedClock()
    with D2GEmulator("tavanti-test1", seed=1, clock=clock) as emu:
        fd = os.open(emu.port, os.O_RDWR | os.O_NOCTTY)
        try:
            import tty

            tty.setraw(fd)
            os.write(fd, cl.request(0, Ep0.QUERY_ENDPOINT_INFO) + b"\x77")  # then a bad start byte
            d = cl.Decoder()
            msgs = []
            while len([m for m in msgs if isinstance(m, cl.Status)]) < 2:
                r, _, _ = select.select([fd], [], [], 5.0)
                assert r, "the emulator did not answer"
                msgs += d.feed(os.read(fd, 4096))
            assert isinstance(msgs[0], cl.Payload) and msgs[0].endpoint == 0
            assert msgs[1] == cl.Status(0, 0) and msgs[2] == cl.Status(0, 0x0002)
            assert emu.counters.framing_errors == 1
        finally:
            os.close(fd)


def test_command_line_prints_the_port_and_serves_until_terminated():
    import subprocess
    import sys

    from hal import open_radar

    env = dict(os.environ, PYTHONPATH=os.getcwd())
    proc = subprocess.Popen(
        [sys.executable, "-m", "hw_sim.d2g_device", "--scenario", "tavanti-test1", "--seed", "2"],
        stdout=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        port = proc.stdout.readline().strip()
        assert port.endswith("ttyD2G") and os.path.islink(port)
        with open_radar(f"d2g://{port}?period_ms=50") as src:
            f = src.read_frame(timeout=10.0)
        assert f.i.shape == (1, 21, 64)
    finally:
        proc.terminate()
        assert proc.wait(timeout=10) == 0
    assert not os.path.lexists(port)  # the emulator cleaned up its port link


def test_fault_schedule_syntax():
    from hw_sim.d2g_device import _fault_spec

    assert _fault_spec("stall@40:3") == ("stall", 40, 3.0)
    assert _fault_spec("garbage@5") == ("garbage", 5, 2.0)
    import argparse

    with pytest.raises(argparse.ArgumentTypeError, match="KIND@FRAME"):
        _fault_spec("melt@3")


@settings(max_examples=300, deadline=None)
@given(
    requests=st.lists(
        st.tuples(
            st.integers(0, 7),
            st.one_of(st.sampled_from([0x00, 0x01, 0x02, 0x22, 0x30, 0x36, 0x40, 0x41]), st.integers(0, 255)),
            st.binary(max_size=12),
        ),
        max_size=12,
    )
)
def test_fuzz_firmware_answers_every_request_with_one_status(requests):
    t = FakeTime()
    fw = D2GFirmware(_zeros, clock=t.now, wait=t.wait)
    for ep, msg_type, body in requests:
        t.t += 0.013
        out = fw.handle(cl.Payload(ep, bytes([msg_type]) + body))
        msgs = cl.Decoder().feed(b"".join(out))
        assert isinstance(msgs[-1], cl.Status) and msgs[-1].endpoint == ep
        assert all(isinstance(m, cl.Payload) for m in msgs[:-1])
