"""The one way this suite writes a durable file: a temporary file in the same folder, flushed to
disk, then renamed over the target. A reader sees the old file or the whole new one, never half;
an interrupted writer leaves no partial file behind. Files get the usual permissions (0666 less
the umask), so a group can read what a sweep wrote.
"""

from __future__ import annotations

import gzip
import json
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on a clean exit it becomes ``path``, else vanishes.

    The temporary name keeps ``path``'s suffix, so writers that pick a format from it (OpenCV,
    matplotlib, numpy) write the right one.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(
        dir=path.parent, prefix=f".{path.stem}.", suffix=f".partial{path.suffix}"
    )
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~_umask())
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def remove_partial_files(folder: str | Path) -> list[Path]:
    """Delete the temporary files and folders (``.<name>.*partial*``) that writers killed
    mid-write (SIGKILL, a power cut) left under ``folder``; only for a folder this process holds,
    where no other writer is at work. Returns what was deleted."""
    found = [p for p in Path(folder).rglob(".*partial*") if p.name.startswith(".")]
    for path in found:
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
    return found


def write_text_atomic(path: str | Path, text: str) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def write_json_atomic(path: str | Path, payload: Any) -> Path:
    """``payload`` as indented JSON (non-JSON values as their ``str``); where ``path`` ends in
    ``.gz``, compact JSON gzip-compressed (a run's long history: about a tenth of the bytes),
    without a time stamp, so the same payload gives the same bytes."""
    if Path(path).suffix != ".gz":
        return write_text_atomic(path, json.dumps(payload, indent=2, default=str) + "\n")
    text = json.dumps(payload, separators=(",", ":"), default=str)
    with atomic_path(path) as tmp:
        tmp.write_bytes(gzip.compress(text.encode(), mtime=0))
    return Path(path)


def publish_dir(root: str | Path, write: Callable[[Path], None]) -> Path:
    """Fill a new folder with ``write(tmp)`` and rename it to ``root``, unless ``root`` exists.

    Safe when several processes publish the same folder at once: each writes its own temporary
    folder; the first rename wins and the others discard theirs and use the winner's.
    """
    root = Path(root)
    if root.exists():
        return root
    root.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=root.parent, prefix=f".{root.name}.", suffix=".partial"))
    try:
        write(tmp)
        os.chmod(tmp, 0o777 & ~_umask())
        try:
            tmp.rename(root)
        except OSError:
            if not root.is_dir():
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return root


def save_figure(fig: Any, path: str | Path, dpi: int = 100) -> Path:
    """Write a matplotlib figure to ``path`` atomically (PNG, PDF: by the suffix), then close it."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi)
    import matplotlib.pyplot as plt  # only the callers that draw need matplotlib

    plt.close(fig)
    return Path(path)
