"""Event files of data sets and of this suite: N-MNIST binary, HDF5 (DSEC, MVSEC), ``.npz``.

- N-MNIST (ATIS, 34x34): 5 bytes an event: x, y, then polarity in bit 7 (1 = ON) and a 23-bit
  timestamp (µs) in the remaining bits, big-endian.
- DSEC: datasets ``events/{x,y,t,p}`` (t µs as stored: its ``t_offset`` is not added; p 0/1;
  blosc-compressed, hence hdf5plugin),
  Prophesee Gen3.1 640x480.
- MVSEC: dataset ``davis/left/events`` (N, 4) float64 rows (x, y, t seconds, p -1/1), DAVIS346;
  a value not finite or beyond int64 once in µs is refused before the cast
  (:func:`edr.data.events.checks.rounded`).
- ``.npz``: integer arrays ``t`` (µs), ``x``, ``y``, ``p`` (1 ON, 0 OFF) of equal length, and
  optionally ``sensor`` = (height, width). It states no time unit, so float timestamps are
  refused (:func:`edr.data.events.checks.events_of`), never truncated.

DSEC's and the ``.npz``'s columns are 1-d of one length, MVSEC's events an (N, 4) dataset; a
scalar, a group or another rank is refused by name (:func:`edr.data.events.checks.column_length`).
"""

from __future__ import annotations

import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from edr.data.events.checks import (
    CHUNK_EVENTS,
    RecordingError,
    column_length,
    events_of,
    layout_of,
    rounded,
)
from edr.store.atomic import atomic_path

NMNIST_SENSOR = (34, 34)
DSEC_SENSOR, MVSEC_SENSOR = (480, 640), (260, 346)
MVSEC_EVENTS = "davis/left/events"
MVSEC_UNITS = (("x", 1.0), ("y", 1.0), ("t", 1e6), ("p", 1.0))  # its columns, to µs


def nmnist_chunks(path: Path) -> Iterator[np.ndarray]:
    size = path.stat().st_size
    if size % 5:
        raise RecordingError(path, "N-MNIST", f"truncated: {size} bytes is not a multiple of 5")
    if not size:
        return
    raw = np.memmap(path, dtype=np.uint8, mode="r").reshape(-1, 5)  # (N, 5)
    for start in range(0, len(raw), CHUNK_EVENTS):
        b = raw[start : start + CHUNK_EVENTS].astype(np.int64)
        t = ((b[:, 2] & 0x7F) << 16) | (b[:, 3] << 8) | b[:, 4]
        yield events_of(t, b[:, 0], b[:, 1], b[:, 2] >> 7)


def _h5py(path: Path) -> Any:
    try:
        import h5py
        import hdf5plugin  # noqa: F401  (registers the blosc filter DSEC's files use)
    except ImportError:
        raise RecordingError(
            path, "HDF5", "reading it needs h5py and hdf5plugin: pip install 'edr[events]'"
        ) from None
    return h5py


def hdf5_layout(path: Path) -> str:
    """'DSEC' or 'MVSEC', by the datasets the file holds."""
    h5py = _h5py(path)
    try:
        with h5py.File(path, "r") as f:
            if all(f"events/{k}" in f for k in "xytp"):
                return "DSEC"
            if MVSEC_EVENTS in f:
                return "MVSEC"
    except OSError as error:
        raise RecordingError(path, "HDF5", f"cannot be opened ({error})") from None
    raise RecordingError(
        path, "HDF5", f"neither DSEC's events/x,y,t,p nor MVSEC's {MVSEC_EVENTS} is in it"
    )


def hdf5_sensor(path: Path) -> tuple[int, int]:
    return DSEC_SENSOR if hdf5_layout(path) == "DSEC" else MVSEC_SENSOR


def hdf5_chunks(path: Path) -> Iterator[np.ndarray]:
    layout = hdf5_layout(path)
    with _h5py(path).File(path, "r") as f:
        if layout == "DSEC":
            columns = {k: f[f"events/{k}"] for k in "txyp"}
            n = column_length(path, "HDF5 (DSEC)", {f"events/{k}": c for k, c in columns.items()})
            for start in range(0, n, CHUNK_EVENTS):
                part = slice(start, start + CHUNK_EVENTS)
                yield events_of(*(np.asarray(c[part]) for c in columns.values()))
            return
        rows = f[MVSEC_EVENTS]
        shape = getattr(rows, "shape", None)  # a group has none
        if shape is None or len(shape) != 2 or shape[1] != 4:
            raise RecordingError(
                path, "HDF5 (MVSEC)", f"{MVSEC_EVENTS} is {layout_of(rows)}, not (N, 4) rows"
            )
        for start in range(0, shape[0], CHUNK_EVENTS):
            block = np.asarray(rows[start : start + CHUNK_EVENTS])  # (n, 4): x, y, t s, p ±1
            # the layout states its units (seconds; whole pixels stored as floats)
            x, y, t, p = (rounded(k, block[:, i], s) for i, (k, s) in enumerate(MVSEC_UNITS))
            yield events_of(t, x, y, p > 0)


def _npz_arrays(path: Path) -> dict[str, np.ndarray]:
    try:
        with np.load(path) as data:
            missing = [k for k in ("t", "x", "y", "p") if k not in data]
            if missing:
                raise RecordingError(path, ".npz", f"missing arrays {missing}; expected t, x, y, p")
            return {k: np.asarray(data[k]) for k in ("t", "x", "y", "p", "sensor") if k in data}
    except (OSError, EOFError, zipfile.BadZipFile, ValueError) as error:
        if isinstance(error, RecordingError):
            raise
        raise RecordingError(path, ".npz", f"not a readable .npz ({error})") from None


def npz_sensor(path: Path) -> tuple[int, int] | None:
    sensor = _npz_arrays(path).get("sensor")
    if sensor is None:
        return None
    if sensor.shape != (2,) or not np.issubdtype(sensor.dtype, np.integer) or (sensor < 1).any():
        raise RecordingError(path, ".npz", f"sensor must be (height, width) >= 1, got {sensor}")
    return int(sensor[0]), int(sensor[1])


def npz_chunks(path: Path) -> Iterator[np.ndarray]:
    arrays = _npz_arrays(path)
    columns = {k: arrays[k] for k in ("t", "x", "y", "p")}
    if not column_length(path, ".npz", columns):
        return  # refused as "no events" by the caller
    yield events_of(*columns.values())  # integers that fit their fields (p 0 or 1), or refused


def write_npz(path: Path, events: np.ndarray, sensor: tuple[int, int]) -> Path:
    with atomic_path(path) as tmp, tmp.open("wb") as f:
        np.savez(f, t=events["t"], x=events["x"], y=events["y"], p=events["p"],
                 sensor=np.array(sensor, np.int64))  # fmt: skip
    return path
