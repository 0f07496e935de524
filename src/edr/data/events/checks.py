"""What every event recording must satisfy, and the one error a bad file gives.

A reader decodes a file in chunks (structured arrays of ``EVENT_DTYPE``, built by
:func:`events_of`, which refuses a value its field cannot hold: a float time, an x beyond
int16, a polarity other than 0/1); :class:`Checked` checks each chunk as it comes (timestamps
>= 0 and sorted across chunks, x/y on the sensor) so a bad file is refused in one line naming
the file, its format and what is wrong. The other bounds every reader and writer share live
here too: :func:`regular_file`, :func:`bounded_sensor` (a sensor's size), :func:`stated_t0`
and :func:`time_origin` (the time a header states its timestamps count from),
:func:`column_length` (a file's t, x, y, p arrays: 1-d, of one length), :func:`rounded` (a
float column, refused where numpy's cast to int64 would not hold it) and
:func:`signed_times` (a signed clock read as signed, a negative time refused, never wrapped).
"""

from __future__ import annotations

import os
import stat
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numba import njit

from edr.checks.config import ConfigError

# One event: time (µs), position, polarity (1 ON, 0 OFF), as every reader returns it and as the
# simulated camera (representations/dvs.py) writes it.
EVENT_DTYPE = np.dtype([("t", np.int64), ("x", np.int16), ("y", np.int16), ("p", np.int8)])

CHUNK_EVENTS = 1 << 20  # events a reader decodes at a time: memory stays bounded on a large file
# The largest sensor side read or written (DAT's 14-bit x and y; real sensors are <= 1280): a
# header stating more is refused, and a recording that states no sensor spans at most this.
MAX_SIDE = 16384
HEADER_LINE_BYTES = 1 << 16  # a longer text header "line" is data: reading one stays bounded
MAX_HEADER_BYTES = 1 << 20  # a text header longer than this is no header (cameras: < 4 KiB)
# The latest time origin (µs, 146,000 years) a header may state: the origin plus any format's
# clock (32-bit AEDAT 2.0, wrapped 24-bit EVT 3.0) stays inside int64.
MAX_T0 = 1 << 62
# What a value beyond its field's integer type is, as its one line says
BEYOND = {"t": "µs, beyond int64", "x": "outside any sensor (beyond int16)",
          "y": "outside any sensor (beyond int16)", "p": "is not a polarity (0 OFF, 1 ON)"}  # fmt: skip


class RecordingError(ConfigError):
    """A file that cannot be read or written as an event recording; one line: file, format,
    what is wrong."""

    def __init__(self, path: str | Path, format_name: str, problem: str) -> None:
        super().__init__(f"{path}: {format_name}: {problem}")


class UnfitValue(ValueError):
    """A decoded value its EVENT_DTYPE field cannot hold; the caller, who knows the file and
    format, makes it a :class:`RecordingError` (the decoders that raise it do not)."""


def regular_file(path: Path) -> None:
    """Refuse anything but a regular file (a FIFO's open() would block forever, a folder's fail
    late), naming what it is."""
    try:
        mode = os.stat(path).st_mode
    except OSError as error:
        raise RecordingError(path, "event file", f"cannot be read ({error.strerror})") from None
    if not stat.S_ISREG(mode):
        kind = ("a folder" if stat.S_ISDIR(mode) else "a named pipe (FIFO)"
                if stat.S_ISFIFO(mode) else "a device or socket")  # fmt: skip
        raise RecordingError(path, "event file", f"not a regular file ({kind})")


def bounded_sensor(
    path: str | Path, format_name: str, sensor: tuple[int, int] | None, side: int = MAX_SIDE
) -> tuple[int, int] | None:
    """``sensor`` (height, width), refused unless each side lies in 1..``side``."""
    if sensor is not None and not all(0 < s <= side for s in sensor):
        raise RecordingError(
            path, format_name,
            f"sensor {sensor[1]}x{sensor[0]} (width x height) outside 1..{side} on a side",
        )  # fmt: skip
    return sensor


def stated_t0(path: str | Path, format_name: str, value: str | None) -> int:
    """The time origin (µs) a header's ``value`` states, 0 where it states none."""
    if value is None:
        return 0
    if not (value.isascii() and value.isdigit() and int(value) <= MAX_T0):
        raise RecordingError(path, format_name, f"its header's t0 {value!r} is not 0..2^62 µs")
    return int(value)


def time_origin(path: str | Path, format_name: str, t: np.ndarray, span_us: int) -> int:
    """The time a writer stores timestamps ``t`` after (the earliest; 0 for none), refused
    before anything is written when they span more than the format's clock holds (``span_us``)
    or the origin could not be read back (:func:`stated_t0`)."""
    if not len(t):
        return 0
    first, last = int(t.min()), int(t.max())  # a direct write may come unsorted
    if not 0 <= first <= MAX_T0:
        raise RecordingError(path, format_name, f"timestamp {first} µs outside 0..2^62")
    if last - first > span_us:
        raise RecordingError(
            path, format_name,
            f"timestamps span {last - first} µs ({first} to {last}); it holds at most "
            f"{span_us} µs after the first event",
        )  # fmt: skip
    return first


def layout_of(value: Any) -> str:
    """What an array-like ``value`` is, for a refusal: 'a scalar', 'of shape (3, 2)', or, where
    it holds no array (an HDF5 group), its type."""
    shape = getattr(value, "shape", None)
    if shape is None:
        return f"a {type(value).__name__} (no array)"
    return "a scalar" if shape == () else f"of shape {tuple(shape)}"


def column_length(path: str | Path, format_name: str, columns: Mapping[str, Any]) -> int:
    """N, where every one of ``columns`` (name -> a numpy array or an HDF5 dataset) is 1-d
    (N,); refused, naming the column, where one is a scalar, of another rank, no array at all,
    or of another length (``len`` of a scalar would fail with a TypeError)."""
    lengths: dict[str, int] = {}
    for name, column in columns.items():
        shape = getattr(column, "shape", None)
        if shape is None or len(shape) != 1:
            raise RecordingError(path, format_name, f"{name} is {layout_of(column)}, not 1-d")
        lengths[name] = int(shape[0])
    if len(set(lengths.values())) > 1:
        found = ", ".join(f"{name} {n}" for name, n in lengths.items())
        raise RecordingError(path, format_name, f"its columns differ in length ({found})")
    return next(iter(lengths.values()), 0)


def rounded(name: str, values: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """A float column of field ``name`` times ``scale`` (to its unit: s -> µs), rounded to
    int64; UnfitValue where a value is not a finite number or beyond int64 (numpy's cast makes
    either -2^63, with only a warning)."""
    if values.dtype.kind not in "biuf":
        raise UnfitValue(f"{name} holds {values.dtype} values, not numbers")
    scaled = np.round(values * scale)
    bad = ~(np.abs(scaled) < 2.0**63)  # NaN compares False: bad too
    if bad.any():
        value = float(scaled[np.argmax(bad)])
        if not np.isfinite(value):
            raise UnfitValue(f"{name} = {value} is not a finite number")
        raise unfit(name, value)
    return scaled.astype(np.int64)


def signed_times(t: np.ndarray) -> np.ndarray:
    """Timestamps ``t`` of a signed clock (AEDAT 3.1's int32), as int64, UnfitValue at a
    negative one: read through an unsigned view, -5 would be 4294967291 µs."""
    t = t.astype(np.int64)
    if len(t) and t.min() < 0:
        raise UnfitValue(f"timestamp {int(t.min())} µs is negative")
    return t


def unfit(name: str, value: float) -> UnfitValue:
    """The error for ``value`` of field ``name`` beyond what the field holds."""
    return UnfitValue(f"{name} = {value} {BEYOND[name]}")


def _fitted(name: str, column: np.ndarray) -> np.ndarray:
    """``column`` unchanged where field ``name`` of EVENT_DTYPE holds its every value: numpy's
    assignment would wrap the others silently (x 70000 -> 4464, t 0.5 s -> 0, p 256 -> 0)."""
    if column.dtype.kind not in ("biu" if name == "p" else "iu"):  # p may come as bool (ON)
        unit = ": timestamps are integer microseconds" if name == "t" else ""
        raise UnfitValue(f"{name} holds {column.dtype} values, not integers{unit}")
    field = EVENT_DTYPE[name]
    if not len(column) or column.dtype == bool:
        return column
    if name == "p":  # int8, but only 0 and 1 mean something
        low, high = 0, 1
    elif np.can_cast(column.dtype, field):  # a type no wider: every value fits
        return column
    else:
        low, high = int(np.iinfo(field).min), int(np.iinfo(field).max)
    found_low = 0 if column.dtype.kind == "u" else int(column.min())  # one pass less
    found_high = int(column.max())
    if found_low < low or found_high > high:
        raise unfit(name, found_low if found_low < low else found_high)
    return column


def events_of(t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Four equal-length integer columns -> events (N,) EVENT_DTYPE (p: 1 ON, 0 OFF); a value
    its field cannot hold raises :class:`UnfitValue`."""
    events = np.empty(len(t), EVENT_DTYPE)
    for name, column in zip("txyp", (t, x, y, p), strict=True):
        events[name] = _fitted(name, np.asarray(column))
    return events


def event_array(path: str | Path, format_name: str, events: Any) -> np.ndarray:
    """``events`` if a writer can take them: a 1-d numpy structured array with fields t, x, y
    and p (EVENT_DTYPE or wider); one line saying what they are otherwise (a plain array would
    fail in the writer with an IndexError)."""
    names = getattr(getattr(events, "dtype", None), "names", None) or ()
    if isinstance(events, np.ndarray) and events.ndim == 1 and {"t", "x", "y", "p"} <= set(names):
        return events
    found = (f"{events.dtype} {layout_of(events)}" if isinstance(events, np.ndarray)
             else f"a {type(events).__name__}")  # fmt: skip
    raise RecordingError(
        path, format_name,
        f"events must be a 1-d structured array with fields t, x, y, p (EVENT_DTYPE); got {found}",
    )  # fmt: skip


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
        sensor = "its sensor" if self.stated else f"the largest sensor read ({MAX_SIDE})"
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
