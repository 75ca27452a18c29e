"""CPU pinning of the frame loop (``loop.cpus``) and of the Modbus server process (``outputs.modbus.cpus``)."""

from __future__ import annotations

import os

import pytest

from edge.config import LoopConfig, load_config
from edge.loop import FrameLoop
from edge.ops.affinity import AffinityError, check, pin, pinned
from edge.outputs.config import ModbusConfig
from edge.outputs.modbus import ModbusSink, OutputError
from hal.clock import FakeClock
from tests.edge.test_loop import FakeSource, ScriptedPipeline

pytestmark = pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="CPU affinity is Linux-only")

NO_SUCH_CPU = os.cpu_count() or 1  # CPUs are numbered 0 .. cpu_count-1


def _one_cpu() -> int:
    return min(os.sched_getaffinity(0))


def test_config_parses_cpu_lists_and_rejects_negative_ones():
    cfg = load_config(env={}, overrides={"loop.cpus": "0,1", "outputs.modbus.cpus": "[2, 3]"})
    assert cfg["loop"].cpus == (0, 1) and cfg["outputs.modbus"].cpus == (2, 3)
    assert load_config(env={}, overrides={})["loop"].cpus == ()
    with pytest.raises(ValueError, match="loop.cpus"):
        load_config(env={}, overrides={"loop.cpus": "-1"})


def test_a_cpu_the_machine_does_not_have_is_a_clear_error():
    with pytest.raises(AffinityError, match=rf"loop.cpus: CPU\(s\) \[{NO_SUCH_CPU}\] not on this machine"):
        check([NO_SUCH_CPU], "loop.cpus")
    clock = FakeClock()
    with pytest.raises(AffinityError, match="loop.cpus"):
        FrameLoop(FakeSource(clock, 3), ScriptedPipeline(clock, lambda n: 1.0), LoopConfig(cpus=(NO_SUCH_CPU,)),
                  clock=clock)
    with pytest.raises(OutputError, match="outputs.modbus.cpus"):
        ModbusSink(ModbusConfig(tcp_port=0, cpus=(NO_SUCH_CPU,)), 4).start()


def test_pinned_restores_the_previous_set_and_empty_means_untouched():
    before = os.sched_getaffinity(0)
    cpu = _one_cpu()
    with pinned([cpu], "test") as applied:
        assert applied == {cpu} and os.sched_getaffinity(0) == {cpu}
    assert os.sched_getaffinity(0) == before
    assert pin([], "test") is None and os.sched_getaffinity(0) == before


def test_the_frame_loop_runs_on_its_cpus_and_gives_them_back():
    before = os.sched_getaffinity(0)
    cpu = _one_cpu()
    clock = FakeClock()
    seen: list[set[int]] = []
    loop = FrameLoop(FakeSource(clock, 5), ScriptedPipeline(clock, lambda n: 1.0), LoopConfig(cpus=(cpu,)),
                     clock=clock, on_result=lambda r: seen.append(os.sched_getaffinity(0)))
    summary = loop.run()
    assert summary.frames == 5 and seen == [{cpu}] * 5
    assert os.sched_getaffinity(0) == before


def test_the_modbus_server_process_is_pinned():
    cpu = max(os.sched_getaffinity(0))
    sink = ModbusSink(ModbusConfig(tcp_host="127.0.0.1", tcp_port=0, cpus=(cpu,)), 4).start()
    try:
        # start() returns once the child reported ready, and the child pins itself before that
        assert os.sched_getaffinity(sink._proc.pid) == {cpu}
    finally:
        sink.close()
    unpinned = ModbusSink(ModbusConfig(tcp_host="127.0.0.1", tcp_port=0), 4).start()
    try:
        assert os.sched_getaffinity(unpinned._proc.pid) == os.sched_getaffinity(0)
    finally:
        unpinned.close()
