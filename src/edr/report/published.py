"""The paper's published numbers (``paper/published.yaml``), to print beside ours."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

PUBLISHED = Path(__file__).resolve().with_name("published.yaml")  # ships in the package


def load_published(path: Path = PUBLISHED) -> dict[str, Any]:
    """The published numbers; an absent file gives no published numbers at all."""
    return yaml.safe_load(path.read_text()) if path.is_file() else {}


def lookup(published: dict[str, Any], *keys: str) -> Any:
    """``published[k1][k2]...``, or None where any level is missing."""
    node: Any = published
    for key in keys:
        if not isinstance(node, dict) or key not in node:
            return None
        node = node[key]
    return node


def cite(value: Any, fmt: str = ".1f") -> str:
    """A published number for a table cell; '—' where the paper's value is not transcribed."""
    if value is None:
        return "—"
    return format(value, fmt) if isinstance(value, int | float) else str(value)
