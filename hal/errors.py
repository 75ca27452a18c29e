"""Exception tree of the hardware abstraction layer.

Everything the HAL raises on purpose derives from :class:`RadarError`, so a caller can
catch one type at the frame-loop boundary and decide by subclass what to do.
"""

from __future__ import annotations


class RadarError(Exception):
    """Base class of every error raised by :mod:`hal`."""


class SourceUrlError(RadarError, ValueError):
    """A source URL has an unknown scheme, option or malformed value."""


class SourceNotOpenError(RadarError):
    """An operation needs an open source (use ``with open_radar(...)`` or ``.open()``)."""


class SourceTimeoutError(RadarError, TimeoutError):
    """No frame arrived within the requested timeout."""


class SourceClosedError(RadarError):
    """The source has ended (end of a recording) or was closed; no more frames will come."""


class FrameFormatError(RadarError):
    """A frame from a backend has the wrong shape, dtype or value range."""


class DeviceError(RadarError):
    """The radar device reported a fault or disappeared (unplug, stall, protocol error)."""


class ProtocolError(DeviceError):
    """The device broke its wire protocol or answered a request with an error status.

    :mod:`hal.comlib` derives one named class per Distance2Go status code from it.
    """


class RecordingError(RadarError):
    """A recording file is missing, corrupt or of an unsupported version."""
