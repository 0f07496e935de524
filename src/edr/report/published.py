"""The paper's published numbers (``paper/published.yaml``), to print beside ours."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

PUBLISHED = Path(__file__).resolve().with_name("published.yaml")  # ships in the package


# Where the file holds numbers: every value under these keys is a number or null.
NUMBERS = {
    "speed": ("fps",),
    "table1_atari": ("games", "avg_gain_percent", "env_steps"),
    "table2_ucf101": ("accuracy",),
    "table4_kth": ("accuracy",),
    "appendix_a_dvs": ("finetuned_accuracy", "zero_shot_accuracy"),
    "atari_reference_scores": (),
}
SECTIONS = {*NUMBERS, "paper", "table3_event_camera"}  # each, where present, a mapping


class BadPublished(ValueError):
    """A published-numbers file whose shape the tables cannot read; the message names the key."""


def _check_numbers(node: Any, where: str) -> None:
    if isinstance(node, dict):
        for key, value in node.items():
            _check_numbers(value, f"{where}.{key}")
    elif node is not None and (not isinstance(node, int | float) or isinstance(node, bool)):
        raise BadPublished(f"{where} is {node!r}, not a number (write numbers without quotes)")


def check_published(published: Any, path: Path) -> dict[str, Any]:
    """``published`` if every section is a mapping, every note a string and every number a
    number; :class:`BadPublished` naming the file and the first key that is not."""
    if not isinstance(published, dict):
        raise BadPublished(f"{path} holds a {type(published).__name__}, not a mapping of tables")
    try:
        for section in SECTIONS & published.keys():
            node = published[section]
            if not isinstance(node, dict):
                raise BadPublished(f"{section} is a {type(node).__name__}, not a mapping")
            notes = node.get("notes", [])
            if not isinstance(notes, list) or not all(isinstance(n, str) for n in notes):
                raise BadPublished(f"{section}.notes is not a list of strings")
            keys = NUMBERS.get(section)
            for key in () if keys is None else keys or node:
                _check_numbers(node.get(key), f"{section}.{key}")
    except BadPublished as error:
        raise BadPublished(f"{path}: {error}") from None
    return published


def load_published(path: Path = PUBLISHED) -> dict[str, Any]:
    """The published numbers; an absent file gives no published numbers at all, a file the
    tables cannot read :class:`BadPublished`."""
    if not path.is_file():
        return {}
    try:
        published = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as error:
        raise BadPublished(f"{path} is not YAML: {' '.join(str(error).split())}") from None
    return check_published({} if published is None else published, path)


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
