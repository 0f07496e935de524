"""One reader for every event format, writers for four, and the recordings of a folder.

The format comes from the file's first bytes (its magic or header), then from its suffix.
Every reader returns ``EVENT_DTYPE`` events (t µs, x, y, p with 1 = ON) sorted by time, checked
chunk by chunk (:mod:`edr.data.events.checks`): a bad file is one line naming the file, the
format found and what is wrong. Only regular files are opened, and a stated sensor is bounded
here, for every format; what a writer is given is checked here before any format's writer runs.
"""

from __future__ import annotations

import operator
import os
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from edr.checks.config import ConfigError
from edr.data.events import aedat4, datasets, jaer, prophesee
from edr.data.events.checks import (
    EVENT_DTYPE,
    MAX_SIDE,
    Checked,
    RecordingError,
    UnfitValue,
    bounded_sensor,
    event_array,
    events_of,
    joined,
    regular_file,
)
from edr.data.fingerprint import shared_files

# The most events read_recording returns at once (436 MiB decoded); iter_recording reads any
# number, a chunk at a time
MAX_READ_EVENTS = 1 << 25


@dataclass(frozen=True)
class EventFormat:
    """A format: its name, suffixes, how to find its sensor and decode it, how to write it; the
    largest sensor side it addresses (a larger one stated or written is refused); and, where it
    is cheaper than decoding, how many events a file holds (read_recording then fills one array
    instead of joining a list of chunks, which holds the events twice)."""

    name: str
    suffixes: tuple[str, ...]
    sensor: Callable[[Path], tuple[int, int] | None]
    chunks: Callable[[Path], Iterator[np.ndarray]]
    write: Callable[[Path, np.ndarray, tuple[int, int]], Path] | None = None
    max_side: int = MAX_SIDE
    count: Callable[[Path], int] | None = None


def _faery_writer(name: str) -> Callable[[Path, np.ndarray, tuple[int, int]], Path]:
    return lambda path, events, sensor: prophesee.write_with_faery(path, events, sensor, name)


FORMATS = {
    f.name: f
    for f in (
        EventFormat("AEDAT 2.0", (".aedat", ".dat"), jaer.aedat2_sensor, jaer.aedat2_chunks,
                    jaer.write_aedat2),
        EventFormat("AEDAT 3.1", (".aedat", ".aedat3"), jaer.aedat31_sensor, jaer.aedat31_chunks),
        EventFormat("AEDAT 4", (".aedat4",), aedat4.aedat4_sensor, aedat4.aedat4_chunks,
                    _faery_writer("AEDAT 4")),
        EventFormat("EVT 2.0", (".raw",), prophesee.prophesee_sensor, prophesee.evt2_chunks,
                    max_side=prophesee.EVT_SIDE),
        EventFormat("EVT 3.0", (".raw",), prophesee.prophesee_sensor, prophesee.evt3_chunks,
                    _faery_writer("EVT 3.0"), prophesee.EVT_SIDE, prophesee.evt3_count),
        EventFormat("DAT", (".dat",), prophesee.prophesee_sensor, prophesee.dat_chunks),
        EventFormat("N-MNIST", (".bin",), lambda path: datasets.NMNIST_SENSOR,
                    datasets.nmnist_chunks),
        EventFormat("HDF5", (".h5", ".hdf5"), datasets.hdf5_sensor, datasets.hdf5_chunks),
        EventFormat(".npz", (".npz",), datasets.npz_sensor, datasets.npz_chunks,
                    datasets.write_npz),
    )
}  # fmt: skip
RECORDING_SUFFIXES = tuple(sorted({s for f in FORMATS.values() for s in f.suffixes}))
WRITE_SUFFIXES = {".raw": "EVT 3.0", ".aedat4": "AEDAT 4", ".aedat": "AEDAT 2.0", ".npz": ".npz"}
MAGIC = {b"#!AER-DAT2": "AEDAT 2.0", b"#!AER-DAT3": "AEDAT 3.1", b"#!AER-DAT4": "AEDAT 4",
         b"\x89HDF\r\n\x1a\n": "HDF5", b"PK\x03\x04": ".npz"}  # fmt: skip
HEADERLESS = {".bin": "N-MNIST", ".dat": "DAT"}  # formats known by their suffix alone


def detect_format(path: str | Path) -> EventFormat:
    """The file's format: its magic or header first, then its suffix (a regular file only)."""
    path = Path(path)
    regular_file(path)
    try:
        with path.open("rb") as f:
            head = f.read(16)
    except OSError as error:
        raise RecordingError(path, "event file", f"cannot be read ({error.strerror})") from None
    if not head:
        raise RecordingError(path, "event file", "empty (0 bytes)")
    found = next((name for magic, name in MAGIC.items() if head.startswith(magic)), None)
    if found is None and head.startswith(b"%"):
        found = prophesee.evt_version(path) or ("DAT" if path.suffix == ".dat" else None)
        if found is None:
            raise RecordingError(
                path, "Prophesee RAW", "its '%' header states no EVT version ('% evt 3.0')"
            )
    if found is None:
        found = HEADERLESS.get(path.suffix.lower())
    if found is None:
        raise RecordingError(
            path, "event file",
            f"no known header or magic, and {path.suffix or 'no suffix'} is not a headerless "
            f"format ({', '.join(HEADERLESS)}); readable: {', '.join(FORMATS)}",
        )  # fmt: skip
    return FORMATS[found]


def _stated_sensor(path: Path, fmt: EventFormat) -> tuple[int, int] | None:
    """(height, width) as ``path`` states it, refused beyond the format's side (at most
    MAX_SIDE): the one place every reader's header size passes (a 30000 x 30000 one would have
    a sensor-sized array binned)."""
    stated = _unreadable_is_one_line(path, fmt.name, fmt.sensor)
    return bounded_sensor(path, fmt.name, stated, fmt.max_side)


def recording_sensor_size(path: str | Path) -> tuple[int, int] | None:
    """(height, width) of the recording's sensor where the file states it, else None."""
    path = Path(path)
    return _stated_sensor(path, detect_format(path))


def _unreadable_is_one_line(path: Path, name: str, read: Callable[[Path], Any]) -> Any:
    """``read(path)``, with a file that fails to read (OSError, EOFError, a decoder's
    ValueError, a value its field cannot hold) as one line naming it."""
    try:
        return read(path)
    except RecordingError:
        raise
    except UnfitValue as error:
        raise RecordingError(path, name, str(error)) from None
    except (OSError, EOFError, ValueError) as error:
        raise RecordingError(path, name, f"cannot be read ({error})") from None


def _decoded(path: Path, fmt: EventFormat) -> Iterator[np.ndarray]:
    """``fmt``'s chunks of ``path``, a read failure as one line (see above)."""
    chunks = fmt.chunks(path)
    while True:
        chunk = _unreadable_is_one_line(path, fmt.name, lambda _: next(chunks, None))
        if chunk is None:
            return
        yield chunk


def iter_recording(path: str | Path, duration_us: float | None = None) -> Iterator[np.ndarray]:
    """A recording's events, checked, a chunk at a time (bounded memory); with ``duration_us``
    only those before its first event's time + ``duration_us``, and decoding stops there."""
    path = Path(path)
    fmt = detect_format(path)
    checked = Checked(path, fmt.name, _stated_sensor(path, fmt))
    end: float | None = None
    for chunk in _decoded(path, fmt):
        if fmt.name == ".npz":  # the suite's own lists may come unsorted
            chunk = np.sort(chunk, order="t", kind="stable")
        checked.check(chunk)
        if duration_us is None or not len(chunk):
            yield chunk
            continue
        end = int(chunk["t"][0]) + duration_us if end is None else end
        inside = chunk[: np.searchsorted(chunk["t"], end)]
        yield inside
        if len(inside) < len(chunk):
            return
    if not checked.count:
        raise checked.fail("no events" + (" (a header only)" if path.stat().st_size else ""))


def read_recording(path: str | Path, duration_us: float | None = None) -> np.ndarray:
    """Events (N,) EVENT_DTYPE of one recording of any supported format, sorted by time; with
    ``duration_us``, only its first ``duration_us`` microseconds are decoded. More than
    :data:`MAX_READ_EVENTS` are refused in one line, as soon as they are counted (before any
    is decoded, where a format counts them cheaply)."""
    path = Path(path)
    fmt = detect_format(path)
    chunks = (c for c in iter_recording(path, duration_us) if len(c))
    if fmt.count is not None and duration_us is None:
        count = _unreadable_is_one_line(path, fmt.name, fmt.count)
        _within_read_limit(path, fmt.name, count, duration_us)
        return _filled(count, chunks)
    parts, held = [], 0
    for chunk in chunks:
        held += len(chunk)
        _within_read_limit(path, fmt.name, held, duration_us)
        parts.append(chunk)
    return joined(parts) if parts else np.zeros(0, EVENT_DTYPE)


def _within_read_limit(path: Path, format_name: str, count: int, duration_us: float | None) -> None:
    """Refuse ``count`` events beyond :data:`MAX_READ_EVENTS`, naming the limit and the remedy
    (a dense 20 MB EVT 3.0 file holds 120M events: 1.5 GB decoded, and twice that joined)."""
    if count > MAX_READ_EVENTS:
        part = "it holds" if duration_us is None else f"its first {duration_us / 1e6:g} s hold"
        raise RecordingError(
            path, format_name,
            f"{part} more than {MAX_READ_EVENTS:,} events "
            f"({MAX_READ_EVENTS * EVENT_DTYPE.itemsize >> 20} MiB decoded), the most read at "
            "once: cut it into shorter recordings (or, in a run, read fewer frames of it: "
            "task.frames)",
        )  # fmt: skip


def _filled(count: int, chunks: Iterable[np.ndarray]) -> np.ndarray:
    """The ``count`` events of ``chunks`` in one array, each chunk copied in as it comes:
    memory is the events and a chunk, not the events twice (a list of chunks and their join:
    3.4 GB for 1.5 GB of events from a dense 20 MB EVT 3.0 file)."""
    events = np.empty(count, EVENT_DTYPE)
    into = events.view(np.uint8)  # copied as bytes: numpy copies structured arrays by field
    at = 0
    for chunk in chunks:
        size = len(chunk) * EVENT_DTYPE.itemsize
        into[at : at + size] = np.ascontiguousarray(chunk).view(np.uint8)
        at += size
    assert at == len(into), f"counted {count} events, decoded {at // EVENT_DTYPE.itemsize}"
    return events


def sensor_of(path: str | Path, events: np.ndarray) -> tuple[int, int]:
    """(height, width): the sensor the file states, else the span of ``events``: all of the
    recording's (every chunk), or those that bound their x and y."""
    stated = recording_sensor_size(path)
    if stated:
        return stated
    if not len(events):
        raise RecordingError(path, detect_format(path).name, "no events, and no sensor size")
    return int(events["y"].max()) + 1, int(events["x"].max()) + 1


def streamed_sensor(path: str | Path, duration_us: float | None = None) -> tuple[int, int]:
    """(height, width): the sensor the file states, else the span of its events (of its first
    ``duration_us`` only), read a chunk at a time: memory is a chunk's, however many events."""
    path = Path(path)
    if stated := recording_sensor_size(path):
        return stated
    bounding = [  # each chunk's events of the largest x and y
        c[[int(c["x"].argmax()), int(c["y"].argmax())]]
        for c in iter_recording(path, duration_us)
        if len(c)
    ]
    return sensor_of(path, joined(bounding) if bounding else np.zeros(0, EVENT_DTYPE))


def check_writable(path: str | Path, sensor: tuple[int, int]) -> str:
    """The format a ``path``'s suffix picks, once it is known to hold a ``sensor`` = (height,
    width): what :func:`write_recording` refuses for the suffix, the sensor and what stands at
    ``path`` alone, said before any events are made (ValueError for an unknown suffix,
    RecordingError otherwise)."""
    path = Path(path)
    name = WRITE_SUFFIXES.get(path.suffix.lower())
    if name is None:
        raise ValueError(
            f"{path}: cannot write {path.suffix or 'no suffix'}; writable: "
            + ", ".join(f"{s} ({n})" for s, n in WRITE_SUFFIXES.items())
        )
    if os.path.lexists(path) and not path.is_file():  # a folder: the final rename would fail
        there = "a folder" if path.is_dir() else "something other than a regular file"
        raise RecordingError(path, name, f"cannot be written: {there} is in its place")
    try:
        height, width = (operator.index(side) for side in sensor)
    except (TypeError, ValueError):  # None, a float, one side or three
        raise RecordingError(
            path, name, f"sensor {sensor!r} is not (height, width), two integers"
        ) from None
    bounded_sensor(path, name, (height, width), FORMATS[name].max_side)
    if name == "AEDAT 2.0":
        try:
            jaer.aedat2_chip_for(path, sensor)
        except ValueError as error:
            raise RecordingError(path, name, str(error).removeprefix(f"{path}: ")) from None
    return name


def write_recording(path: str | Path, events: np.ndarray, sensor: tuple[int, int]) -> Path:
    """Events (EVENT_DTYPE) of a ``sensor`` = (height, width) into a file whose suffix picks the
    format: ``.raw`` EVT 3.0, ``.aedat4`` AEDAT 4, ``.aedat`` AEDAT 2.0, ``.npz``. What is not a
    structured array of events, a sensor that is not two integers or beyond the format's side,
    a value beyond its field (a float time, p 2) or events off the sensor are refused here,
    before the format's writer runs."""
    path = Path(path)
    name = check_writable(path, sensor)
    fmt = FORMATS[name]
    height, width = int(sensor[0]), int(sensor[1])
    events = event_array(path, name, events)
    try:  # a float time or an x beyond int16 is refused, never narrowed (wrapped)
        events = events_of(*(events[k] for k in ("t", "x", "y", "p")))
    except UnfitValue as error:
        raise RecordingError(path, name, str(error)) from None
    events = Checked(path, name, (height, width)).check(np.sort(events, order="t", kind="stable"))
    assert fmt.write is not None
    return fmt.write(path, events, (height, width))


def list_recordings(root: str | Path, classes: tuple[str, ...]) -> list[tuple[Path, int]]:
    """(file, label) for every recording under ``root/<class>/``, any supported format."""
    root = Path(root)
    if not root.is_dir():
        raise ConfigError(
            f"event recordings not found under {root}; expected <root>/<action>/<recording>"
        )
    found = []
    for label, name in enumerate(classes):
        folder = root / name
        # hidden names (.DS_Store) skipped; any other entry is a recording or refused by name:
        # a file converted to another format would leave its class silently smaller
        for f in sorted(folder.glob("*")) if folder.is_dir() else []:
            if f.name.startswith("."):
                continue
            if f.suffix.lower() not in RECORDING_SUFFIXES or not f.is_file():
                raise ConfigError(
                    f"{f}: not an event recording ({' '.join(RECORDING_SUFFIXES)}) in the "
                    "class folder; move it out, or convert it"
                )
            found.append((f, label))
    if not found:
        raise ConfigError(
            f"no event recordings ({' '.join(RECORDING_SUFFIXES)}) under {root}/<action>/ "
            f"for {classes}"
        )
    for (first, one), (second, other) in shared_files(found):
        raise ConfigError(
            f"{first} ({classes[one]}) and {second} ({classes[other]}) are the same recording "
            "filed under two classes: keep it under one"
        )
    return found
