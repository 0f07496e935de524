"""Event-camera recordings on disk: one reader for every format, writers for four.

``read_recording(path)`` -> events (N,) ``EVENT_DTYPE`` (t µs, x, y, p with 1 = ON), sorted by
time, for AEDAT 2.0 and 3.1 (jAER / cAER), AEDAT 4 (iniVation DV), EVT 2.0, EVT 3.0 and DAT
(Prophesee), N-MNIST binary, HDF5 (DSEC, MVSEC) and the suite's ``.npz``;
``recording_sensor_size(path)`` -> (height, width) where the file states it.
``write_recording(path, events, sensor)`` writes EVT 3.0 (``.raw``), AEDAT 4 (``.aedat4``),
AEDAT 2.0 (``.aedat``) and ``.npz``. A recordings folder is laid out like KTH:
``<root>/<action>/<recording>``, any of these formats.
"""

from edr.data.events.checks import RecordingError
from edr.data.events.jaer import write_aedat2
from edr.data.events.recording import (
    FORMATS,
    RECORDING_SUFFIXES,
    check_writable,
    detect_format,
    iter_recording,
    list_recordings,
    read_recording,
    recording_sensor_size,
    sensor_of,
    streamed_sensor,
    write_recording,
)

__all__ = [
    "FORMATS",
    "RECORDING_SUFFIXES",
    "RecordingError",
    "check_writable",
    "detect_format",
    "iter_recording",
    "list_recordings",
    "read_recording",
    "recording_sensor_size",
    "sensor_of",
    "streamed_sensor",
    "write_aedat2",
    "write_recording",
]
