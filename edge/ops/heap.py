"""Garbage-collector policy of the frame loop: the start-up heap is frozen while frames run (issue 9).

CPython's cyclic garbage collector runs a full (generation 2) collection from time to time, and a full
collection visits every container object of the process. After start-up the lane process holds about
70 000 of them (the modules of numpy, scipy and the outputs, the pipeline, its caches): measured on the
development machine, one full collection takes 35 ms of CPU time -- more than a 33 ms lane frame, so the
frame it lands in overruns. The frames themselves create few container objects (arrays of numbers are not
tracked), so full collections are rare (none in 4800 recorded highway4-traffic frames; the young
generations are collected a few times per thousand frames in 0.02 ms), but when one comes it costs a frame.

:func:`frozen_heap` collects once and moves everything that survived start-up into the collector's
permanent generation (``gc.freeze``, the pattern CPython documents for pre-fork servers and long-running
services): later collections, full ones included, only visit what was created afterwards (0.04 ms instead
of 35 ms). On exit the objects are handed back to the collector (``gc.unfreeze``), so a process that runs
several loops (tests, tools) does not keep their garbage for good. The frame loop (:mod:`edge.loop`) and
``radar-edge bench`` (:mod:`edge.bench`) both time frames inside it, so the bench measures what runs.
"""

from __future__ import annotations

import contextlib
import gc
import logging
from collections.abc import Iterator

log = logging.getLogger(__name__)


@contextlib.contextmanager
def frozen_heap() -> Iterator[int]:
    """Collect, freeze the surviving objects for the duration of the block, unfreeze at its end.

    Yields the number of frozen objects. Nesting is harmless (the inner block freezes what the outer one
    did not, and its exit unfreezes everything)."""
    gc.collect()
    gc.freeze()
    n = gc.get_freeze_count()
    log.debug("%d start-up objects frozen for the garbage collector", n)
    try:
        yield n
    finally:
        gc.unfreeze()
