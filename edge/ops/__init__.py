"""Operations on the device: systemd notification, on-disk event recording, live terminal view.

:func:`attach` is the one hook the ``run`` command calls: it adds the operations sinks the
configuration and the environment ask for and returns the pipeline to run (wrapped when the
recorder needs the raw frames).
"""

from __future__ import annotations

import logging
import os
from typing import Any

log = logging.getLogger(__name__)


def attach(cfg: Any, pipeline: Any, sinks: list, *, view: bool = False, env: dict | None = None) -> Any:
    """Append the sd_notify sink (under systemd), the event recorder (``ops.recorder.enabled``) and
    the live view (``view``) to ``sinks``; return the pipeline the loop should run."""
    env = os.environ if env is None else env
    if env.get("NOTIFY_SOCKET"):
        from edge.ops.sdnotify import NotifySink

        sinks.append(NotifySink(env=env))
        log.info("systemd notification on (%s)", env["NOTIFY_SOCKET"])
    rc = cfg["ops.recorder"]
    if rc.enabled:
        from edge.ops.recorder import EventRecorder

        rec = EventRecorder(rc, meta={"source": cfg["source"].url})
        sinks.append(rec)
        pipeline = rec.wrap(pipeline)
        log.info("recording events to %s (quota %.0f MB)", rc.directory, rc.quota_mb)
    if view:
        from edge.ops.view import LiveView

        sinks.append(LiveView(title=cfg["source"].url))
    return pipeline
