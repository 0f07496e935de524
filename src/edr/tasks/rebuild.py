"""Rebuilding a run's parts from its record, safely: a run folder may come from someone else.

A record's config names what to build (``_target_``); instantiating it as it stands would let a
crafted ``run.json`` call anything importable (``torch.load`` of a pickle, ``builtins.open``).
:func:`instantiate_from_record` builds only the suite's own parts — representations, networks,
optimizers, settings — and refuses any other target with one line naming the key and the target,
before importing anything it names.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import torch
from hydra.utils import get_object, instantiate
from torch import nn

from edr.representations.base import Representation

# Where a buildable target may live (checked on the name, before any import).
TRUSTED_MODULES = ("edr.", "torch.optim.")
# Functions a record may name, as partials only (the task entry points: nothing runs).
TRUSTED_PARTIALS = frozenset({"edr.tasks.atari.train_paac"})


class UntrustedRecord(ValueError):
    """A record asks to build something the suite does not build from records."""


def _buildable(target: object) -> bool:
    """A class the suite builds from configs: a representation, a network, an optimizer, or a
    settings dataclass of ``edr``."""
    if not isinstance(target, type):
        return False
    if issubclass(target, Representation | nn.Module | torch.optim.Optimizer):
        return True
    return dataclasses.is_dataclass(target) and target.__module__.startswith("edr.")


def check_targets(node: Any, where: str) -> None:
    """Raise :class:`UntrustedRecord` for the first ``_target_`` under ``node`` that is not one
    of the suite's buildable parts (``where``: the node's key, for the message)."""
    if isinstance(node, Mapping):
        name = node.get("_target_")
        if name is not None:
            problem = _target_problem(str(name), bool(node.get("_partial_", False)))
            if problem:
                raise UntrustedRecord(
                    f"{where}._target_={name}: {problem}; the record was not loaded "
                    "(a run folder's config builds only the suite's own parts)"
                )
        for key, value in node.items():
            check_targets(value, f"{where}.{key}")
    elif isinstance(node, list | tuple):
        for i, value in enumerate(node):
            check_targets(value, f"{where}[{i}]")


def _target_problem(name: str, partial: bool) -> str | None:
    if not name.startswith(TRUSTED_MODULES):
        return f"not a part of the suite (only {', '.join(TRUSTED_MODULES)} targets are built)"
    if name in TRUSTED_PARTIALS:
        return None if partial else "a task entry point is rebuilt only as a partial"
    try:
        target = get_object(name)
    except Exception:
        return "no such class in the suite"
    return None if _buildable(target) else "not a representation, network, optimizer or settings"


def instantiate_from_record(node: Mapping[str, Any], where: str) -> Any:
    """``hydra.utils.instantiate(node)`` after :func:`check_targets`."""
    check_targets(node, where)
    return instantiate(node)
