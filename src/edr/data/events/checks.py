"""What every event recording must satisfy, and the one error a bad file gives.

A reader decodes a file in chunks (structured arrays of ``EVENT_DTYPE``); :class:`Checked`
checks each chunk as it comes (timestamps >= 0 and sorted across chunks, x/y on the sensor)
so a bad file is refused in one line naming the file, its format and what is wrong.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numba import njit

from edr.checks.config import ConfigError

# One event: time (µs), position, polarity (1 ON, 0 OFF), as every reader returns it and as the
# simulated camera (representations/dvs.py) writes it.
EVENT_DTYPE = np.dtype([("t", np.int64), ("x", np.int16), ("y", np.int16), ("p", np.int8)])

CHUNK_EVENTS = 1 << 20  # events a reader decodes at a time: memory stays bounded on a large file
# The widest sensor any format here addresses (EVT 3.0: 11-bit x and y). A recording that does
# not state its sensor is taken to span its events, refused beyond this side.
MAX_SIDE = 2048


class RecordingError(ConfigError):
    """A file that cannot be read as an event recording; one line: file, format, what is wrong."""

    def __init__(self, path: str | Path, format_name: str, problem: str) -> None:
        super().__init__(f"{path}: {format_name}: {problem}")


def events_of(t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Four equal-length columns -> events (N,) EVENT_DTYPE (p: 1 ON, 0 OFF)."""
    events = np.empty(len(t), EVENT_DTYPE)
    events["t"], events["x"], events["y"], events["p"] = t, x, y, p
    return events


def joined(parts: list[np.ndarray]) -> np.ndarray:
    """Structured arrays of one dtype, end to end (through their bytes: numpy's own
    concatenate of structured arrays takes a slow path per field)."""
    if len(parts) == 1:
        return parts[0]
    dtype = parts[0].dtype
    return np.concatenate([np.ascontiguousarray(p).view(np.uint8) for p in parts]).view(dtype)


@njit(cache=True)
def _summary(events):  # pragma: no cover (numba)
    """One pass over ``events`` (N >= 1,) EVENT_DTYPE (3x faster than numpy's five over its
    strided fields): (the index of the first event earlier than the one before it, or -1;
    x min, x max, y min, y max)."""
    backwards = -1
    x_low = x_high = events[0].x
    y_low = y_high = events[0].y
    for i in range(1, len(events)):
        event = events[i]
        if backwards < 0 and event.t < events[i - 1].t:
            backwards = i
        x_low, x_high = min(x_low, event.x), max(x_high, event.x)
        y_low, y_high = min(y_low, event.y), max(y_high, event.y)
    return backwards, x_low, x_high, y_low, y_high


class Checked:
    """Checks a recording's chunks in order: ``check(chunk)`` raises :class:`RecordingError`."""

    def __init__(self, path: Path, format_name: str, sensor: tuple[int, int] | None) -> None:
        self.path, self.format_name = path, format_name
        self.height, self.width = sensor or (MAX_SIDE, MAX_SIDE)
        self.stated = sensor is not None
        self.last_t: int | None = None
        self.count = 0

    def fail(self, problem: str) -> RecordingError:
        return RecordingError(self.path, self.format_name, problem)

    def check(self, chunk: np.ndarray) -> np.ndarray:
        """``chunk`` (N,) EVENT_DTYPE, unchanged when it is good."""
        if not len(chunk):
            return chunk
        t = chunk["t"]
        backwards, x_low, x_high, y_low, y_high = _summary(chunk)
        if self.last_t is not None and t[0] < self.last_t:
            backwards = 0
        if backwards >= 0:
            raise self.fail(
                f"timestamps go backwards at event {self.count + backwards} "
                "(events must be sorted by time)"
            )
        if t[0] < 0:  # sorted: the first is the least
            raise self.fail(f"timestamp {int(t[0])} µs is negative (event {self.count})")
        sensor = "its sensor" if self.stated else "the widest sensor a format addresses"
        for field, low, high, size, axis in (("x", x_low, x_high, self.width, "width"),
                                             ("y", y_low, y_high, self.height, "height")):  # fmt: skip
            if low < 0 or high >= size:
                bad = low if low < 0 else high
                raise self.fail(
                    f"{field} = {bad} outside {sensor} ({axis} {size}: {field} in 0..{size - 1})"
                )
        self.last_t = int(t[-1])
        self.count += len(chunk)
        return chunk
