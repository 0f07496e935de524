"""A content fingerprint of the files a run read, so that a table never averages runs over
different data: small sets are hashed, large ones (real UCF-101, KTH) fingerprinted by size and
modification time, which a copy with ``cp -p`` or ``rsync -a`` keeps.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from edr.store.identity import digest

HASH_UP_TO_BYTES = 64 * 2**20  # sets up to this size are hashed byte by byte
SAMPLE_BYTES = 1 << 16  # a file's first and last bytes, compared where two share a size


def relative_name(path: Path, root: Path) -> str:
    """``path`` relative to ``root`` where it lies under it, else its file name."""
    return str(path.relative_to(root)) if path.is_relative_to(root) else path.name


def files_fingerprint(files: Sequence[Path], root: Path, extra: Any = None) -> str:
    """``content:<digest>`` or ``stat:<digest>`` of ``files`` (named relative to ``root``) and
    of ``extra`` (e.g. each file's label)."""
    files = sorted(Path(f) for f in files)
    stats = [f.stat() for f in files]
    names = [relative_name(f, root) for f in files]
    if sum(s.st_size for s in stats) <= HASH_UP_TO_BYTES:
        h = hashlib.sha256()
        for name, f in zip(names, files, strict=True):
            h.update(name.encode() + b"\0" + f.read_bytes())
        return f"content:{digest([h.hexdigest(), extra])}"
    listing = [(n, s.st_size, s.st_mtime_ns) for n, s in zip(names, stats, strict=True)]
    return f"stat:{digest([listing, extra])}"


def _sample(path: Path, size: int) -> bytes:
    """A file's first and last :data:`SAMPLE_BYTES` (all of it, where it is smaller)."""
    with path.open("rb") as f:
        head = f.read(SAMPLE_BYTES)
        f.seek(max(size - SAMPLE_BYTES, len(head)))
        return hashlib.sha256(head + f.read()).digest()


def shared_files(
    labelled: Sequence[tuple[Path, int]],
) -> list[tuple[tuple[Path, int], tuple[Path, int]]]:
    """Pairs of ``labelled`` files (path, label) of two labels that are one file (a hard or
    symbolic link) or copies of it (the same size, first and last bytes: only files of one
    size are read, 128 KiB each)."""
    by_size: dict[int, list[tuple[Path, int, tuple[int, int]]]] = {}
    for path, label in labelled:
        stat = path.stat()
        by_size.setdefault(stat.st_size, []).append((path, label, (stat.st_dev, stat.st_ino)))
    pairs = []
    for size, group in by_size.items():
        if len({label for _, label, _ in group}) < 2:
            continue
        seen: dict[Any, tuple[Path, int]] = {}
        for path, label, node in group:
            for key in (node, _sample(path, size)):
                first = seen.setdefault(key, (path, label))
                if first[1] != label:
                    pairs.append((first, (path, label)))
                    break
    return pairs
