"""Event-camera recordings on disk: ``.npz`` event lists and jAER's AEDAT 2.0 (DVS128).

A recordings folder is laid out like KTH: ``<root>/<action>/<name>.npz`` or ``.aedat``.
``.npz``: arrays ``t`` (µs), ``x``, ``y``, ``p`` (1 ON, 0 OFF) of equal length.
AEDAT 2.0: '#' header lines, then big-endian (uint32 address, uint32 timestamp µs) pairs; a
DVS128 address holds polarity in bit 0 (1 = OFF), x in bits 1-7 (mirrored), y in bits 8-14.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

RECORDING_SUFFIXES = (".npz", ".aedat")
# One event: time (µs), position, polarity (1 ON, 0 OFF); the simulator (representations/dvs.py)
# writes the same records.
EVENT_DTYPE = np.dtype([("t", np.int64), ("x", np.int16), ("y", np.int16), ("p", np.int8)])


def _events(t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray) -> np.ndarray:
    events = np.empty(len(t), EVENT_DTYPE)
    events["t"], events["x"], events["y"], events["p"] = t, x, y, p
    return events[np.argsort(events["t"], kind="stable")]


def read_npz_events(path: str | Path) -> np.ndarray:
    """An ``.npz`` with arrays t, x, y, p -> events (EVENT_DTYPE), sorted by time."""
    path = Path(path)
    try:
        with np.load(path) as data:
            missing = [k for k in ("t", "x", "y", "p") if k not in data]
            if missing:
                raise ValueError(f"{path}: missing arrays {missing}; expected t, x, y, p")
            t, x, y, p = (np.asarray(data[k]) for k in ("t", "x", "y", "p"))
    except (OSError, EOFError) as err:  # zipfile errors are OSError subclasses or BadZipFile
        raise ValueError(f"{path}: not a readable .npz event file ({err})") from err
    if not len(t) == len(x) == len(y) == len(p):
        raise ValueError(f"{path}: t, x, y, p have different lengths")
    if len(p) and not np.isin(p, (0, 1)).all():
        raise ValueError(f"{path}: polarity p must be 0 (OFF) or 1 (ON)")
    return _events(t, x, y, p)


def read_aedat2(path: str | Path, flip_x: bool = True) -> np.ndarray:
    """A DVS128 recording in AEDAT 2.0 -> events (EVENT_DTYPE) on its 128x128 sensor."""
    path = Path(path)
    raw = path.read_bytes()
    start = 0
    while raw.startswith(b"#", start):
        end = raw.find(b"\n", start)
        if end < 0:
            raise ValueError(f"{path}: AEDAT header never ends")
        start = end + 1
    if not raw.startswith(b"#!AER-DAT2", 0):
        raise ValueError(f"{path}: not AEDAT 2.0 (its first line should be '#!AER-DAT2.0')")
    body = raw[start:]
    if len(body) % 8:
        raise ValueError(f"{path}: truncated event data ({len(body)} bytes is not a multiple of 8)")
    words = np.frombuffer(body, dtype=">u4").reshape(-1, 2)
    address, t = words[:, 0], words[:, 1].astype(np.int64)
    x = (address >> 1) & 0x7F
    return _events(t, 127 - x if flip_x else x, (address >> 8) & 0x7F, 1 - (address & 1))


def write_aedat2(path: str | Path, events: np.ndarray, flip_x: bool = True) -> Path:
    """Write events of a 128x128 sensor as a DVS128 AEDAT 2.0 file (for tests and exports)."""
    path = Path(path)
    x = events["x"].astype(np.uint32)
    address = (
        ((127 - x if flip_x else x) << 1)
        | (events["y"].astype(np.uint32) << 8)
        | (1 - events["p"].astype(np.uint32))
    )
    words = np.stack([address, events["t"].astype(np.uint32)], axis=1).astype(">u4")
    path.write_bytes(
        b"#!AER-DAT2.0\r\n# This is a raw AE data file created by edr\r\n" + words.tobytes()
    )
    return path


def read_recording(path: str | Path) -> np.ndarray:
    """Events of one recording, by its suffix."""
    path = Path(path)
    if path.suffix == ".npz":
        return read_npz_events(path)
    if path.suffix == ".aedat":
        return read_aedat2(path)
    raise ValueError(f"{path}: unknown recording type; expected one of {RECORDING_SUFFIXES}")


def list_recordings(root: str | Path, classes: tuple[str, ...]) -> list[tuple[Path, int]]:
    """(file, label) for every recording under ``root/<class>/``."""
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(
            f"event recordings not found under {root}; expected <root>/<action>/*.npz|*.aedat"
        )
    found = [
        (f, label)
        for label, name in enumerate(classes)
        for f in sorted((root / name).glob("*"))
        if f.suffix in RECORDING_SUFFIXES
    ]
    if not found:
        raise FileNotFoundError(
            f"no .npz or .aedat recordings under {root}/<action>/ for {classes}"
        )
    return found
