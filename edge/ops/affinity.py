"""CPU pinning: keep the frame loop on a core of its own.

A Raspberry Pi 4 has four cores and the frame loop needs one. Pinning the loop to one core
(``loop.cpus``, e.g. ``[3]``) and the Modbus server process to the others (``outputs.modbus.cpus``,
e.g. ``[0, 1, 2]``) keeps a SCADA master that polls hard from taking CPU time away from the radar:
the Modbus server then answers on the other cores and the loop only pays for handing over one
register image per frame. Empty (the default) leaves the operating system to schedule.

Linux only (``os.sched_setaffinity``); elsewhere a configured pinning is logged and skipped.
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Iterable, Iterator

log = logging.getLogger(__name__)


class AffinityError(ValueError):
    """A CPU set that this machine cannot honour (named CPUs it does not have)."""


def machine_cpus() -> set[int]:
    """The CPUs of this machine (0 .. cpu_count-1)."""
    return set(range(os.cpu_count() or 1))


def check(cpus: Iterable[int], what: str) -> None:
    """Raise :class:`AffinityError` if ``cpus`` names a CPU this machine does not have."""
    have = machine_cpus()
    missing = sorted({int(c) for c in cpus} - have)
    if missing:
        raise AffinityError(f"{what}: CPU(s) {missing} not on this machine (it has {sorted(have)})")


def pin(cpus: Iterable[int], what: str) -> set[int] | None:
    """Pin the calling thread to ``cpus``; return the set applied, or None when nothing was done.

    Call it from the thread that runs the work (the frame loop's, the server process's main
    thread); threads it starts afterwards inherit the set, threads already running keep theirs.
    Raises :class:`AffinityError` naming ``what`` when a CPU is not on this machine (a configuration
    for a bigger board on a smaller one) or the operating system refuses the set.
    """
    want = {int(c) for c in cpus}
    if not want:
        return None
    if not hasattr(os, "sched_setaffinity"):
        log.warning("%s: CPU pinning %s requested but not supported on this OS; not pinned", what, sorted(want))
        return None
    check(want, what)
    try:
        os.sched_setaffinity(0, want)
    except OSError as exc:  # EINVAL: none of them allowed (a container's cpuset); EPERM
        raise AffinityError(f"{what}: cannot pin to CPU(s) {sorted(want)}: {exc.strerror}") from None
    log.info("%s pinned to CPU(s) %s", what, sorted(want))
    return want


@contextlib.contextmanager
def pinned(cpus: Iterable[int], what: str) -> Iterator[set[int] | None]:
    """Pin the calling thread to ``cpus`` for the ``with`` block, then restore its previous set."""
    before = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    applied = pin(cpus, what)
    try:
        yield applied
    finally:
        if applied is not None and before is not None:
            os.sched_setaffinity(0, before)
