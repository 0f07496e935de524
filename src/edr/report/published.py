"""The paper's published numbers (``paper/published.yaml``), to print beside ours."""

from __future__ import annotations

import math
from collections.abc import Mapping
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
    "figure5_atari": ("pong_env_steps_to_18", "centipede_reward_ratio", "centipede_best_reward"),
    "atari_reference_scores": (),
}
SECTIONS = {*NUMBERS, "paper", "table3_event_camera", "edr_rows"}  # each, where present, a mapping
# A recognition task -> the paper's table of its accuracies (by backbone, then representation)
ACCURACY_TABLES = {"kth": "table4_kth", "ucf101": "table2_ucf101"}


class BadPublished(ValueError):
    """A published-numbers file whose shape the tables cannot read; the message names the key."""


def _check_numbers(node: Any, where: str) -> None:
    if isinstance(node, dict):
        for key, value in node.items():
            _check_numbers(value, f"{where}.{key}")
    elif node is not None and (not isinstance(node, int | float) or isinstance(node, bool)):
        raise BadPublished(f"{where} is {node!r}, not a number (write numbers without quotes)")


def _check_edr_rows(node: dict[str, Any]) -> None:
    """``edr_rows.settings``, where present: a mapping of each EDR row's name to its settings."""
    settings = node.get("settings", {})
    if not isinstance(settings, dict) or not all(isinstance(s, dict) for s in settings.values()):
        raise BadPublished("edr_rows.settings is not a mapping of names to settings")


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
        _check_edr_rows(published.get("edr_rows", {}))
    except BadPublished as error:
        raise BadPublished(f"{path}: {error}") from None
    return published


def load_published(path: Path = PUBLISHED) -> dict[str, Any]:
    """The published numbers; an absent file gives no published numbers at all, a file the
    tables cannot read, or a path that is not a file, :class:`BadPublished`."""
    if not path.exists():
        return {}
    if not path.is_file():
        raise BadPublished(f"{path} is not a file of published numbers (a YAML file)")
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


def _same(ours: Any, paper: Any) -> bool:
    """Whether a run's setting is the paper's: a one-element list is its element; a setting the
    record lacks (None, NaN: it predates the key, when only the paper's way existed) counts."""
    if ours is None or (isinstance(ours, float) and math.isnan(ours)):
        return True

    def one(value: Any) -> Any:
        if isinstance(value, list | tuple):
            return value[0] if len(value) == 1 else list(value)
        return value

    return bool(one(ours) == one(paper))


def paper_name(
    published: dict[str, Any], representation: str, settings: Mapping[str, Any]
) -> str | None:
    """The name published.yaml gives a run's representation: its config name, except EDR's,
    which is the paper's row whose settings (``edr_rows.settings``) all match the run's
    ``settings`` (its ``representation`` config: half-lives, threshold, ...), or None (an EDR
    the paper did not run). Without ``edr_rows`` (another published file), EDR is ``edr``."""
    rows = lookup(published, "edr_rows", "settings")
    if representation != "edr" or not isinstance(rows, dict):
        return representation
    return next(
        (
            name
            for name, wanted in rows.items()
            if all(_same(settings.get(key), value) for key, value in wanted.items())
        ),
        None,
    )


def paper_accuracy(
    published: dict[str, Any], task: str, backbone: str, name: str | None
) -> float | None:
    """The paper's accuracy (%) for a run of ``task`` (kth: Table 4, ucf101: Table 2) with
    ``backbone`` on the representation published.yaml calls ``name`` (:func:`paper_name`);
    None where the paper reports none (a backbone or representation it did not run)."""
    if name is None or task not in ACCURACY_TABLES:
        return None
    return lookup(published, ACCURACY_TABLES[task], "accuracy", backbone, name)
