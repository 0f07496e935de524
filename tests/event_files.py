"""Small event files the event tests write: a ``.npz`` recording of two events by default."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def npz_recording(path: Path, **arrays) -> Path:
    """Two events (t 0 and 10 µs) as the suite's ``.npz``, any column replaced by ``arrays``."""
    columns = {"t": [0, 10], "x": [1, 2], "y": [3, 4], "p": [0, 1], **arrays}
    with path.open("wb") as f:
        np.savez(f, **{k: np.asarray(v) for k, v in columns.items()})
    return path
