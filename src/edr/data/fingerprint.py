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
