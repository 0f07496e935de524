"""Checkpoints the training tasks write after every epoch or every few updates, and read back."""

from __future__ import annotations

import os
import random
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import torch

CHECKPOINT = "checkpoint.pt"


def save_atomic(payload: object, path: Path) -> None:
    """``torch.save`` so that ``path`` holds the old file or the whole new one, never half."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".partial")
    os.close(fd)
    try:
        torch.save(payload, tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def save_checkpoint(path: Path, parts: dict[str, Any], **extra: Any) -> None:
    """The state dicts of ``parts`` (model, optimizer, schedule...), the RNG states, ``extra``."""
    payload = {name: part.state_dict() for name, part in parts.items()}
    payload["rng"] = {
        "torch": torch.get_rng_state(),
        "numpy": np.random.get_state(),
        "python": random.getstate(),
    }
    save_atomic({**payload, **extra}, path)


def load_checkpoint(path: Path, parts: dict[str, Any]) -> dict[str, Any]:
    """Restore ``parts`` and the RNG states from ``path``; returns the whole payload."""
    state = torch.load(path, weights_only=False)
    for name, part in parts.items():
        part.load_state_dict(state[name])
    torch.set_rng_state(state["rng"]["torch"])
    np.random.set_state(state["rng"]["numpy"])
    random.setstate(state["rng"]["python"])
    print(f"resuming {path}")
    return state
