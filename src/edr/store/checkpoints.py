"""Checkpoints the training tasks write after every epoch or every few updates, and read back.

A checkpoint holds state dicts, RNG states as tensors and plain values only, so it loads with
``torch.load(..., weights_only=True)``; models are saved the same way, as their ``state_dict``
beside the arguments that rebuild them.
"""

from __future__ import annotations

import logging
import pickle
import random
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import torch

from edr.checks.config import ConfigError
from edr.store.atomic import atomic_path

CHECKPOINT = "checkpoint.pt"
NETWORK = "network.pt"  # a finished run's trained network: its state_dict and the arguments that rebuild it
DATA_FINGERPRINT = "data_fingerprint"  # the content fingerprint of the data it trained on
log = logging.getLogger(__name__)


class WriteStopped(OSError):
    """A write the OS refused part-way; the message names the file, the free space, and that
    the file there is the previous one, whole."""


def drop_checkpoint(out_dir: Path, metrics: dict[str, Any]) -> bool:
    """Remove a finished run's ``checkpoint.pt`` (optimizer state and the history again, several
    times the network's size) once its finished record is written, where the run left its
    ``network.pt``, all a finished run needs; kept for a run that diverged (its checkpoint holds
    the last network that was numbers, its ``network.pt`` may hold NaN). Returns whether it
    removed one."""
    checkpoint, network = out_dir / CHECKPOINT, out_dir / NETWORK
    if "train/diverged_step" in metrics or not network.is_file() or not checkpoint.is_file():
        return False
    checkpoint.unlink()
    log.info("%s: finished, %s kept: %s removed", out_dir, NETWORK, CHECKPOINT)
    return True


def save_atomic(payload: object, path: Path) -> None:
    """``torch.save`` so that ``path`` holds the old file or the whole new one, never half.

    A write the OS refuses part-way (a full disk, a quota, a file-size limit) is an ``OSError``
    that names the file and the free space: torch itself says only "unexpected pos"."""
    try:
        with atomic_path(path) as tmp:
            torch.save(payload, tmp)
    except (OSError, RuntimeError) as err:
        if isinstance(err, RuntimeError) and "inline_container" not in str(err):
            raise  # not a failed write
        free = shutil.disk_usage(path.parent).free / 2**30
        raise WriteStopped(
            f"could not write {path}: the write stopped part-way ({str(err).strip()[:120]}); "
            f"{free:.1f} GiB free on its disk. A full disk, a quota or a file-size limit? "
            f"The file there, if any, is the previous one, whole"
        ) from err


def _rng_state() -> dict[str, Any]:
    kind, keys, pos, has_gauss, cached = np.random.get_state()
    return {
        "torch": torch.get_rng_state(),
        "numpy": {"kind": kind, "keys": torch.from_numpy(keys.copy()), "pos": pos,
                  "has_gauss": has_gauss, "cached": cached},
        "python": random.getstate(),
    }  # fmt: skip


def _set_rng_state(state: dict[str, Any]) -> None:
    torch.set_rng_state(state["torch"])
    n = state["numpy"]
    np.random.set_state((n["kind"], n["keys"].numpy(), n["pos"], n["has_gauss"], n["cached"]))
    random.setstate(state["python"])


def save_checkpoint(path: Path, parts: dict[str, Any], **extra: Any) -> None:
    """The state dicts of ``parts`` (model, optimizer, schedule...), the RNG states, ``extra``."""
    payload = {name: part.state_dict() for name, part in parts.items()}
    save_atomic({**payload, "rng": _rng_state(), **extra}, path)


class UnreadableCheckpoint(ValueError):
    """A checkpoint that is empty, truncated or not one; the message names it and the remedy."""


# What an unreadable checkpoint's message advises: edr-run's remedy, unless the reader says its own.
START_OVER = "pass resume=false to start the run over, or move the folder away"


def load_checkpoint(path: Path, remedy: str = START_OVER) -> dict[str, Any]:
    """The payload ``save_checkpoint`` wrote (tensors and plain values only);
    :class:`UnreadableCheckpoint` naming the file and ``remedy`` if it cannot be read."""
    log.info("loading %s", path)
    try:
        return torch.load(path, weights_only=True)
    except Exception as error:  # what a damaged file raises varies (pickle, index, ...): unreadable
        raise UnreadableCheckpoint(f"{path} cannot be read ({_why(error)}): {remedy}") from None


def _why(error: Exception) -> str:
    """Why ``torch.load`` refused a file, in a few words. Its ``weights_only`` refusal is a page
    on how to load the file anyway, by running the code it holds: never repeated."""
    if isinstance(error, pickle.UnpicklingError) and "weights_only" in str(error):
        return "it holds Python objects, not only tensors and plain values; it was not loaded"
    reason = " ".join(str(error).split()) or type(error).__name__
    return reason[:200]


def restore(state: dict[str, Any], parts: dict[str, Any]) -> None:
    """Load ``parts``' state dicts and the RNG states from a loaded checkpoint."""
    for name, part in parts.items():
        part.load_state_dict(state[name])
    _set_rng_state(state["rng"])


class ChangedData(ConfigError):
    """A checkpoint trained on other data than the run would now continue on."""


def check_same_data(state: dict[str, Any], fingerprint: str, path: Path) -> None:
    """Refuse to continue ``state`` (loaded from ``path``) on data whose content fingerprint
    differs from the one it was trained on (a video replaced, two classes swapped)."""
    seen = state.get(DATA_FINGERPRINT)
    if seen is not None and seen != fingerprint:
        raise ChangedData(
            f"{path} was trained on other data (data fingerprint {seen}, now {fingerprint}): "
            "restore the data it was trained on, or pass resume=false to start over"
        )


def progress(run_dir: Path) -> dict[str, Any] | None:
    """How far the last checkpoint under ``run_dir`` got: its path there and its counters
    (``{"checkpoint": "checkpoint.pt", "epoch": 3}``); None when there is none, or it cannot be
    read. What an interrupted run's record says the next attempt resumes from."""
    path = next(Path(run_dir).rglob(CHECKPOINT), None)
    if path is None:
        return None
    try:
        state = torch.load(path, weights_only=True, mmap=True)  # mmap: reads only what is used
    except (EOFError, RuntimeError, OSError, ValueError):
        return None
    return {"checkpoint": str(path.relative_to(run_dir)), **_counters(state)}


def _counters(values: dict[str, Any]) -> dict[str, int]:
    """The entries of ``values`` that are counts (ints, not bools)."""
    return {k: v for k, v in values.items() if isinstance(v, int) and not isinstance(v, bool)}


def progress_text(resumes_from: dict[str, Any]) -> str:
    """:func:`progress`'s counters for a line (``env_steps 65,600, updates 410``); its other
    keys, and any value a hand-edited record holds that is no count, left out."""
    return ", ".join(f"{k} {v:,}" for k, v in _counters(resumes_from).items())
