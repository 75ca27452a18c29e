"""``d2g://`` backend against the firmware emulator on a pty: session, frames bit-identical to
``sim://d2g``, dropped frames, telemetry, and every injected fault (garbage, truncation, stall,
unplug) with recovery. Synchronised on emulator events and blocking reads, never on sleeps."""

from __future__ import annotations

import concurrent.futures
import logging

import numpy as np
import pytest

from hal import SourceTimeoutError, SourceUrlError, open_radar
from hal.clock import FakeClock
from hal.d2g import D2GConfigError, D2GSource
from hal.errors import DeviceError
from hw_sim.d2g_device import D2GEmulator, SteppedClock
from tests.hal.d2g_emulator import TEST_PERIOD_MS, emulated_d2g_url

PERIOD_S = TEST_PERIOD_MS / 1e3
#: short timeouts so that fault tests stay fast
FAST = "timeout_s=0.3&gap_s=0.02&backoff_s=0.02&backoff_max_s=0.1"


def _url(emu: D2GEmulator, extra: str = "") -> str:
    return f"d2g://{emu.port}?period_ms={TEST_PERIOD_MS}" + (f"&{extra}" if extra else "")


def _read_until(src, pred, attempts=60, timeout=0.5):
    """read_frame until ``pred(frame)``; timeouts are expected while a fault lasts."""
    for _ in range(attempts):
        try:
            f = src.read_frame(timeout=timeout)
        except SourceTimeoutError:
            continue
        if pred(f):
            return f
    raise AssertionError(f"condition not reached; stats {src.stats}")


def _wait_for_fault(src, attempts=60):
    for _ in range(attempts):
        if src.stats.faults:
            return
        try:
            src.read_frame(timeout=0.2)
        except SourceTimeoutError:
            pass
    raise AssertionError(f"the fault was not detected; stats {src.stats}")


# --- session --------------------------------------------------------------------------------------


def test_session_configures_the_board_and_discovers_endpoints():
    order = ("RADX", "RTDC", "RFMC", "RBAS", "RIND")  # RBAS is not endpoint 1: the host must look it up
    with D2GEmulator("tavanti-test1", seed=1, endpoints=order) as emu:
        with open_radar(_url(emu)) as src:
            f = src.read_frame(timeout=5.0)
            assert src.endpoints["RBAS"] == 4 and src.endpoints["RFMC"] == 3
            assert emu.fw.fmcw.direction == 0  # the power-on ramps alternated; 21 chirps needs up-only
            assert emu.fw.fmt.chirps_per_frame == 21 and emu.fw.fmt.samples_per_chirp == 64
            assert emu.fw.trigger_us == 50_000
            assert src.telemetry["min_interval_us"] == 47_100
            assert src.telemetry["device"].n_rx == 1 and src.telemetry["firmware"].major == 1
            assert f.meta["temperature_c"] == pytest.approx(38.0)
            assert f.frontend.waveform.frame_period_s == pytest.approx(PERIOD_S)
            assert f.frontend.frame_shape == (1, 21, 64)
        assert emu.fw.trigger_us == 0  # close stops the trigger


def _assert_as_sim_d2g(frames, scenario, seed, extra=""):
    """``frames`` (from the emulator) are bit-identical to ``sim://d2g``'s frames of the same numbers."""
    with open_radar(f"sim://d2g?scenario={scenario}&seed={seed}&realtime=0{extra}") as sim:
        ref = {}
        while len(ref) <= frames[-1].seq:
            f = sim.read_frame(timeout=None)
            ref[f.seq] = f
    for f in frames:
        assert np.array_equal(f.i, ref[f.seq].i) and np.array_equal(f.q, ref[f.seq].q), f.seq
    return ref


def test_frames_are_bit_identical_to_sim_d2g():
    scenario, seed = "tavanti-test1", 3
    with emulated_d2g_url(scenario, seed) as url, open_radar(url) as src:
        frames = [src.read_frame(timeout=5.0) for _ in range(6)]
    _assert_as_sim_d2g(frames, scenario, seed)
    assert len({f.seq for f in frames}) == 6


def test_tx_power_option_sets_the_board_and_scales_its_frames():
    scenario, seed = "tavanti-test1", 3
    with D2GEmulator(scenario, seed=seed) as emu:
        assert emu.fw.fmcw.tx_power == 7  # power-on: full power
        with open_radar(_url(emu, "tx_power=1")) as src:
            frames = [src.read_frame(timeout=5.0) for _ in range(4)]
            assert emu.fw.fmcw.tx_power == 1 and src.telemetry["fmcw"].tx_power == 1
    ref = _assert_as_sim_d2g(frames, scenario, seed, "&tx_power=1")
    with open_radar(f"sim://d2g?scenario={scenario}&seed={seed}&realtime=0") as sim:
        full = sim.read_frame(timeout=None)
    # 6 dB less TX power: the leakage-dominated samples halve (the noise does not scale)
    ratio = np.abs(ref[0].i.astype(float)).max() / np.abs(full.i.astype(float)).max()
    assert ratio == pytest.approx(10 ** (-6 / 20), rel=0.02)


def test_tx_power_beyond_the_board_is_a_configuration_error():
    with D2GEmulator("tavanti-test1", seed=1) as emu:
        with pytest.raises(D2GConfigError, match="0..7"):
            with open_radar(_url(emu, "tx_power=8")) as src:
                src.read_frame(timeout=5.0)


def test_sim_tx_power_option_is_checked():
    with pytest.raises(SourceUrlError, match="Distance2Go"):
        open_radar("sim://simo?tx_power=3")
    with pytest.raises(SourceUrlError, match="0..7"):
        open_radar("sim://d2g?tx_power=9")


def test_slow_host_counts_dropped_frames_and_temperature_telemetry():
    clock = SteppedClock()
    with D2GEmulator("tavanti-test1", seed=1, clock=clock) as emu, open_radar(_url(emu)) as src:
        clock.advance(PERIOD_S * 1.01)
        assert src.read_frame(timeout=5.0).seq == 0
        clock.advance(PERIOD_S * 4)  # frames 1..4 complete while the host is busy: only 4 is kept
        f = src.read_frame(timeout=5.0)
        assert f.seq == 4 and src.stats.dropped_frames == 3
        clock.advance(PERIOD_S * 26)
        f = src.read_frame(timeout=5.0)
        assert f.seq == 30 and src.stats.dropped_frames == 28
        assert f.meta["temperature_c"] == pytest.approx(38.125) == src.telemetry["temperature_c"]
        assert src.stats.faults == 0


def test_read_timeout_keeps_the_request_outstanding():
    """A read that times out must not desynchronise the exchange: the reply is taken by the next read."""
    clock = SteppedClock()
    with D2GEmulator("tavanti-test1", seed=1, clock=clock) as emu, open_radar(_url(emu)) as src:
        with pytest.raises(SourceTimeoutError):
            src.read_frame(timeout=0.05)  # the trigger clock has not moved: no frame
        requests = emu.counters.requests
        clock.advance(PERIOD_S * 1.01)
        assert src.read_frame(timeout=5.0).seq == 0
        assert emu.counters.requests == requests  # no second GET_FRAME_DATA was sent
        assert src.stats.faults == 0 and src.stats.timeouts == 1


# --- configuration and URLs -----------------------------------------------------------------------


def test_period_below_the_minimum_interval_is_refused():
    with D2GEmulator("tavanti-test1", seed=1) as emu:
        src = open_radar(f"d2g://{emu.port}?period_ms=45")  # longer than the burst, shorter than the board allows
        with pytest.raises(D2GConfigError, match="47.1 ms"):
            src.open()
        assert not src.is_open
    with pytest.raises(SourceUrlError, match="chirp burst"):
        open_radar("d2g:///dev/ttyACM0?period_ms=20")


def test_refused_frame_format_is_a_configuration_error(monkeypatch):
    import hw_sim.d2g_device as dev

    monkeypatch.setattr(dev, "MAX_CHIRPS", 16)  # a firmware build with a smaller frame buffer
    with D2GEmulator("tavanti-test1", seed=1) as emu:
        with pytest.raises(D2GConfigError, match="0x0008"):
            open_radar(_url(emu)).open()


def test_close_with_a_request_outstanding_leaves_the_board_idle():
    clock = SteppedClock()
    with D2GEmulator("tavanti-test1", seed=1, clock=clock) as emu:
        src = open_radar(_url(emu, FAST))
        with src:
            with pytest.raises(SourceTimeoutError):
                src.read_frame(timeout=0.02)  # GET_FRAME_DATA is now waiting in the board
            clock.advance(PERIOD_S * 1.01)
        assert emu.fw.trigger_us == 0
        with src:  # a second session sees no stale reply
            clock.advance(PERIOD_S * 1.01)
            assert src.read_frame(timeout=5.0).seq == 0
            assert src.stats.faults == 0


def test_informational_requests_are_optional():
    """A firmware without firmware info, GET_FRAME_FORMAT, GET_MIN_INTERVAL and GET_CHIRP_DURATION still
    works: the minimum interval then comes from the announcement after SET_FRAME_FORMAT."""
    from hal.comlib import Ep0, Rbas

    with D2GEmulator("tavanti-test1", seed=1) as emu:
        rbas, ep0 = emu.fw._rbas, emu.fw._endpoint0
        missing = (Rbas.GET_CHIRP_DURATION, Rbas.GET_FRAME_FORMAT, Rbas.GET_MIN_INTERVAL)
        emu.fw._rbas = lambda d: ([], 0xFFFF) if d[0] in missing else rbas(d)
        emu.fw._endpoint0 = lambda d: ([], 0xFFFF) if d[0] == Ep0.QUERY_FW_INFO else ep0(d)
        with open_radar(_url(emu)) as src:
            assert src.read_frame(timeout=5.0).i.shape == (1, 21, 64)
            assert src.telemetry["min_interval_us"] == 47_100
            assert src.telemetry["chirp_duration_ns"] is None and src.telemetry["firmware"] is None
        emu.fw._rbas = lambda d: ([], 0x0005) if d[0] == Rbas.SET_AUTOMATIC_TRIGGER and d[1:] != bytes(4) else rbas(d)
        with pytest.raises(D2GConfigError, match="below the board's minimum"):
            open_radar(_url(emu)).open()


def test_missing_port_raises_device_error(tmp_path):
    src = open_radar(f"d2g://{tmp_path}/ttyNONE")
    with pytest.raises(DeviceError, match="cannot open"):
        src.open()


def test_url_errors():
    with pytest.raises(SourceUrlError, match="period_ms"):
        open_radar("d2g:///dev/ttyACM0?bogus=1")
    with pytest.raises(SourceUrlError, match="auto"):
        open_radar("d2g://")
    src = open_radar("d2g://auto?period_ms=250&timeout_s=2")
    assert isinstance(src, D2GSource) and src.period_s == 0.25 and src.timeout_s == 2.0 and not src.is_open


class _PortInfo:
    def __init__(self, device, vid=0x058B, pid=0x0058):
        self.device, self.vid, self.pid = device, vid, pid


def test_auto_finds_the_board_by_usb_id_and_endpoint_list(monkeypatch):
    from serial.tools import list_ports

    with D2GEmulator("tavanti-test1", seed=1) as d2g, D2GEmulator("tavanti-test1", seed=1, endpoints=("RADX", "RFMC")) as other:
        ports = [_PortInfo(other.port), _PortInfo("/dev/ttyS0", vid=None, pid=None), _PortInfo(d2g.port)]
        monkeypatch.setattr(list_ports, "comports", lambda: ports)
        with open_radar(f"d2g://auto?period_ms={TEST_PERIOD_MS}") as src:
            assert src.port_path == d2g.port
            assert src.read_frame(timeout=5.0).i.shape == (1, 21, 64)
        monkeypatch.setattr(list_ports, "comports", lambda: [_PortInfo(other.port)])
        with pytest.raises(D2GConfigError, match="no Distance2Go"):
            open_radar("d2g://auto").open()
    monkeypatch.setattr(list_ports, "comports", lambda: [])
    with pytest.raises(DeviceError, match="058B:0058"):
        open_radar("d2g://auto").open()


# --- faults -------------------------------------------------------------------------------------


def test_garbage_before_a_reply_costs_no_frame():
    clock = SteppedClock()
    with D2GEmulator("tavanti-test1", seed=1, clock=clock) as emu, open_radar(_url(emu, FAST)) as src:
        clock.advance(PERIOD_S * 1.01)
        src.read_frame(timeout=5.0)
        garbage = bytes(range(0x5C, 0xFF)) + b"\x00\x01\xdb\xe0"  # no start byte: skipped at once
        emu.inject_garbage(garbage)
        clock.advance(PERIOD_S)
        f = src.read_frame(timeout=5.0)
        assert f.seq == 1 and src.stats.dropped_frames == 0 and src.stats.faults == 0
        assert src._link.decoder.discarded >= len(garbage)


def test_random_garbage_with_start_bytes_is_survived():
    with D2GEmulator("tavanti-test1", seed=1) as emu, open_radar(_url(emu, FAST)) as src:
        src.read_frame(timeout=5.0)
        for k in range(5):
            emu.inject_garbage(200, seed=k)
            src.read_frame(timeout=5.0)
        first = src.stats.frames
        _read_until(src, lambda f: src.stats.frames >= first + 3)
        assert src.stats.reconnects == src.stats.faults  # any fault was recovered


@pytest.mark.parametrize("fault", ["truncate_next_frame", "corrupt_next_frame"],
                         ids=["truncated-frame-loses-only-that-frame", "damaged-header-dropped-and-counted-once"])
def test_a_damaged_frame_is_lost_alone_and_counted_once(fault):
    clock = SteppedClock()
    with D2GEmulator("tavanti-test1", seed=1, clock=clock) as emu, open_radar(_url(emu, FAST)) as src:
        clock.advance(PERIOD_S * 1.01)
        assert src.read_frame(timeout=5.0).seq == 0
        getattr(emu, fault)()
        clock.advance(PERIOD_S)
        with concurrent.futures.ThreadPoolExecutor(1) as pool:
            requests = emu.counters.requests
            fut = pool.submit(src.read_frame, 5.0)
            # frame 1 goes out damaged; the host abandons it and asks again (the second request waits)
            assert emu.wait_for(lambda: emu.counters.requests >= requests + 2, 5.0)
            clock.advance(PERIOD_S)
            f = fut.result(timeout=10)
        assert f.seq == 2
        assert src.corrupted_frames == 1 and src.stats.dropped_frames == 1 and src.stats.faults == 0


def test_stalled_board_is_reconnected_after_it_recovers(caplog):
    caplog.set_level(logging.WARNING, logger="hal.d2g")
    with D2GEmulator("tavanti-test1", seed=1) as emu, open_radar(_url(emu, FAST)) as src:
        before = src.read_frame(timeout=5.0)
        emu.stall()
        _wait_for_fault(src)
        assert "LinkStallError" in src.last_fault
        connects = emu.counters.trigger_starts
        emu.recover()
        after = _read_until(src, lambda f: True)
        assert after.seq > before.seq
        assert src.stats.faults == 1 and src.stats.reconnects == 1
        assert emu.counters.trigger_starts == connects + 1
        assert "reconnected" in caplog.text


def test_unplugged_board_is_reopened_behind_the_same_path():
    with D2GEmulator("tavanti-test1", seed=1) as emu, open_radar(_url(emu, FAST)) as src:
        before = src.read_frame(timeout=5.0)
        emu.disconnect()
        _wait_for_fault(src)
        assert "LinkLostError" in src.last_fault
        for _ in range(3):  # the port is gone: reads time out, nothing is raised
            with pytest.raises(SourceTimeoutError):
                src.read_frame(timeout=0.05)
        emu.reconnect()
        after = _read_until(src, lambda f: True)
        assert after.seq > before.seq  # sequence numbers stay monotonic across the board's counter reset
        assert src.stats.faults == 1 and src.stats.reconnects == 1 and emu.counters.connects == 2
        assert emu.fw.fmt.chirps_per_frame == 21  # the power-on board was configured again


def test_reconnect_back_off_on_the_injected_clock(monkeypatch):
    clock = FakeClock()
    with D2GEmulator("tavanti-test1", seed=1) as emu:
        with open_radar(_url(emu, "backoff_s=0.1&backoff_max_s=0.4"), clock=clock) as src:
            src.read_frame(timeout=5.0)
            attempts = []
            connect = src._connect

            def recording_connect():
                attempts.append(clock.now_ns())
                connect()

            monkeypatch.setattr(src, "_connect", recording_connect)
            emu.disconnect()
            _wait_for_fault(src)
            for _ in range(6):  # each read waits (on the fake clock) for one attempt, which fails
                with pytest.raises(SourceTimeoutError):
                    src.read_frame(timeout=0.5)
            emu.reconnect()
            _read_until(src, lambda f: True)
    gaps_s = np.diff(attempts) / 1e9
    assert len(attempts) >= 6
    assert gaps_s[:5] == pytest.approx([0.2, 0.4, 0.4, 0.4, 0.4])  # doubling from 0.1 s, capped at backoff_max_s
    assert src.stats.faults == 1 and src.stats.reconnects == 1


# --- the frame loop over the emulated board -------------------------------------------------------


@pytest.mark.parametrize("fault", ["garbage", "truncate", "stall", "disconnect"])
def test_frame_loop_keeps_running_through_each_fault(fault):
    """The product's frame loop on d2g://: the fault is reported by the source, the loop never sees it."""
    from edge.loop import FrameLoop
    from edge.pipelines.minimal import MinimalConfig, MinimalPipeline

    with D2GEmulator("tavanti-test1", seed=1) as emu, open_radar(_url(emu, FAST)) as src:
        seqs: list[int] = []
        state = {"injected": False, "recovered": False}

        class FaultSink:
            def publish(self, result, health):
                if result is not None:
                    seqs.append(result.seq)
                    if len(seqs) == 3 and not state["injected"]:
                        state["injected"] = True
                        {"garbage": lambda: emu.inject_garbage(300, seed=5), "truncate": emu.truncate_next_frame,
                         "stall": emu.stall, "disconnect": emu.disconnect}[fault]()
                elif state["injected"] and not state["recovered"]:  # the loop saw no frame for a while
                    state["recovered"] = True
                    if fault == "stall":
                        emu.recover()
                    elif fault == "disconnect":
                        emu.reconnect()

            def close(self):
                pass

        loop = FrameLoop(src, MinimalPipeline(src.frontend, MinimalConfig()), sinks=[FaultSink()], read_timeout_s=0.2)
        summary = loop.run(max_frames=8)
    assert summary.frames == 8 and summary.stop_reason == "8 frames"
    assert seqs == sorted(seqs) and len(set(seqs)) == 8
    # what the source absorbed reaches the loop's errors and reconnects (they stayed 0 before)
    assert summary.errors == src.stats.errors >= 1 and loop.health().errors == summary.errors
    assert summary.reconnects == src.stats.reconnects
    if fault in ("stall", "disconnect"):
        assert src.stats.faults == 1 and src.stats.reconnects == 1 and summary.reconnects == 1
    if fault == "truncate":
        assert src.corrupted_frames == src.stats.malformed_frames == 1
    if fault == "garbage":
        assert src.stats.resyncs >= 1


def test_pipeline_results_on_d2g_match_sim_d2g():
    """The board's profile pipeline (minimal until surveillance is registered) gives the same results."""
    from edge.config import load_config
    from edge.loop import FrameLoop
    from edge.pipeline import build_pipeline, resolve_profile

    cfg = load_config(env={})
    n = 12

    def run(src, after_each=lambda: None):
        out = []

        def on_result(r):
            out.append(r)
            after_each()

        profile = resolve_profile("auto", src.frontend.board)
        loop = FrameLoop(src, build_pipeline(profile, src.frontend, cfg), cfg["loop"], pace="none", on_result=on_result)
        summary = loop.run(max_frames=n)
        assert summary.frames == n
        return out

    clock = SteppedClock()
    with D2GEmulator("tavanti-test1", seed=4, clock=clock) as emu:
        src = open_radar(f"d2g://{emu.port}").open()  # Tavanti's 200 ms: the same front end as sim://d2g
        clock.advance(0.2 * 1.01)  # the trigger started at open: frame 0 is complete
        got = run(src, lambda: clock.advance(0.2))
    ref = run(open_radar("sim://d2g?scenario=tavanti-test1&seed=4&realtime=0"))
    assert [r.seq for r in got] == [r.seq for r in ref] == list(range(n))
    for a, b in zip(got, ref):
        assert a.profile == b.profile
        for name in ("range_m", "radial_speed_mps", "az_rad", "snr_db", "x_m", "y_m"):
            assert np.array_equal(getattr(a.detections, name), getattr(b.detections, name), equal_nan=True)
        assert a.tracks == b.tracks and a.classifications == b.classifications and a.events == b.events
    assert sum(len(r.detections) for r in got) > 0


def test_framing_error_from_the_board_makes_the_host_wait_for_a_quiet_line():
    import os

    with D2GEmulator("tavanti-test1", seed=1, quiet_s=0.3) as emu:
        with open_radar(_url(emu, FAST + "&quiet_s=0.4")) as src:
            before = src.read_frame(timeout=5.0)
            fd = os.open(emu.port, os.O_WRONLY | os.O_NOCTTY)  # another writer on the line: a stray byte
            try:
                os.write(fd, b"\x77")
            finally:
                os.close(fd)
            assert emu.wait_for(lambda: emu.counters.framing_errors == 1, 5.0)
            _wait_for_fault(src)
            assert "BadStartByteError" in src.last_fault
            after = _read_until(src, lambda f: True)
            assert after.seq > before.seq
            assert src.stats.faults == 1 and src.stats.reconnects == 1
            assert src.failed_attempts == 0  # the host did not talk into the board's quiet time


def test_run_summary_agrees_with_the_log_over_five_reconnects_and_malformed_frames(caplog):
    """Five unplugs and two corrupted frames: the summary's reconnects equal the reconnects the log shows
    and ``errors`` counts every fault (before: ``reconnects 0, errors 0``)."""
    import logging

    from edge.loop import FrameLoop
    from edge.pipelines.minimal import MinimalConfig, MinimalPipeline

    with D2GEmulator("tavanti-test1", seed=1) as emu, open_radar(_url(emu, FAST)) as src:
        plan = {2: emu.disconnect, 4: emu.disconnect, 6: emu.corrupt_next_frame, 8: emu.disconnect,
                10: emu.disconnect, 12: emu.truncate_next_frame, 14: emu.disconnect}
        state = {"down": False}

        class FaultSink:
            def publish(self, result, health):
                if result is not None:
                    inject = plan.pop(health.frames, None)
                    if inject is not None:
                        inject()
                        state["down"] = inject == emu.disconnect
                elif state["down"]:  # the loop saw no frame for a while: plug the board back in
                    state["down"] = False
                    emu.reconnect()

            def close(self):
                pass

        loop = FrameLoop(src, MinimalPipeline(src.frontend, MinimalConfig()), sinks=[FaultSink()], read_timeout_s=0.2)
        with caplog.at_level(logging.INFO, logger="hal.d2g"):
            summary = loop.run(max_frames=18)
    logged = sum("Distance2Go reconnected" in r.getMessage() for r in caplog.records)
    faults = sum("Distance2Go fault" in r.getMessage() for r in caplog.records)
    assert logged == faults == 5 and summary.reconnects == 5
    assert f"reconnects {logged}," in summary.lines()[0]
    assert src.stats.malformed_frames == 2
    assert summary.errors == src.stats.errors == 5 + 2 + src.stats.resyncs
    assert f"errors {summary.errors}," in summary.lines()[0]
