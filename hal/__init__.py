"""Hardware abstraction layer: one :class:`RadarSource` contract, backends chosen by URL.

>>> from hal import open_radar
>>> with open_radar("sim://simo?scenario=single-car&seed=1&realtime=0") as src:
...     frame = src.read_frame(timeout=1.0)
"""

from hal.base import RadarSource, RawRead, SourceStats
from hal.errors import (
    DeviceError,
    FrameFormatError,
    ProtocolError,
    RadarError,
    RecordingError,
    SourceClosedError,
    SourceNotOpenError,
    SourceTimeoutError,
    SourceUrlError,
)
from hal.frame import RawFrame
from hal.registry import BACKENDS, EXAMPLES, open_radar
from hal.waveform import (
    ChirpSegment,
    FrontendInfo,
    RadarCharacteristics,
    Waveform,
    characteristics,
    d2g_frontend,
    simo_frontend,
)

__all__ = [
    "BACKENDS",
    "EXAMPLES",
    "ChirpSegment",
    "DeviceError",
    "FrameFormatError",
    "FrontendInfo",
    "RadarCharacteristics",
    "ProtocolError",
    "RadarError",
    "RadarSource",
    "RawFrame",
    "RawRead",
    "RecordingError",
    "SourceClosedError",
    "SourceNotOpenError",
    "SourceStats",
    "SourceTimeoutError",
    "SourceUrlError",
    "Waveform",
    "characteristics",
    "d2g_frontend",
    "open_radar",
    "simo_frontend",
]
