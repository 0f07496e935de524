"""Checking a run folder before anything reads or writes it: a folder may be someone else's,
edited by hand, or still being written by a run.

:func:`open_run_folder` refuses, in one line naming the file, what is wrong and what to do, and
before any env is built or any game played: a folder a live run holds (its ``run.lock``), one it
cannot write into, a record whose status, seed or config is not what ``edr-run`` writes (the
config checked as ``edr-run`` checks its overrides, :func:`edr.checks.config.check_config`, once
:mod:`edr.tasks.rebuild` has refused targets that are not the suite's). :func:`check_weights`
refuses a checkpoint or network file whose weights are not those of the network the record
describes (a foreign file, a bare tensor, the other input's network).

Its parts serve every reader, each saying its own remedy (:class:`Reader`): edr-eval
(:func:`edr.tasks.atari.evaluate_checkpoint`) and an Atari run's ``load_network``, a
recognition run's ``load_model`` (:func:`open_record`, without the task node, whose data and
cache need not be on this machine), and edr-run resuming a run (:func:`check_record_fields`;
the task's checkpoint against its network: each task's ``check_resumable``).
"""

from __future__ import annotations

import types
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException

from edr.checks.config import (
    ConfigError,
    PositiveInt,
    Seed,
    check_config,
    mismatch,
    writable_folder_problem,
)
from edr.store.folders import LOCK, holder_alive
from edr.store.records import INTERRUPTED, RECORD_NAME, read_record
from edr.tasks.rebuild import UntrustedRecord, check_targets

STATUSES = ("running", "finished", INTERRUPTED, "failed")  # what edr-run writes
# A record's fields its readers rely on (edr-run's resume, edr-eval), each as edr-run writes it.
RECORD_FIELDS = {"seed": Seed, "attempt": PositiveInt | None}


class RefusedFolder(ConfigError):
    """A run folder that is not read or written; the message is one line naming the file (a
    :class:`ConfigError`: edr-run refuses it as it refuses a bad value)."""


@dataclass(frozen=True)
class Reader:
    """Who reads run folders, for what its refusals say: its name (a command or a function),
    the verb of what it does with a run (``score``, ``load``), the tasks whose runs it reads,
    where another task's run is read instead, and what an unreadable record's message advises.
    """

    name: str
    verb: str
    tasks: tuple[str, ...]
    elsewhere: str
    remedy: str

    @property
    def restore(self) -> str:
        """What a refused record's message advises: the record is the run's, read as it is."""
        return f"restore the value edr-run wrote, or {self.verb} a copy of the run that holds it"

    @property
    def file_remedy(self) -> str:
        """What a refused weights file's message advises."""
        return f"{self.verb} the file with the run folder that wrote it (its run.json beside it)"


@dataclass(frozen=True)
class RunFolder:
    """A checked run folder: its path, its record, and the ``task`` node of its config (the
    suite's own targets only, every value as its target declares)."""

    path: Path
    record: dict[str, Any]
    task: dict[str, Any]

    @property
    def record_path(self) -> Path:
        return self.path / RECORD_NAME


def open_run_folder(
    run_dir: Path, reader: Reader, *, trust_env_module: bool = False, writes: bool = True
) -> RunFolder:
    """``run_dir`` checked for ``reader`` (:func:`open_record`), then its record's task node
    (:func:`_task_node`) and, with ``writes``, that files can be written beside the run's.
    :class:`RefusedFolder` otherwise (:class:`UntrustedRecord` for a target or a module that
    is not the suite's; an unreadable record :class:`UnreadableRecord`, a missing one
    :class:`FileNotFoundError`)."""
    record = open_record(run_dir, reader)
    node = _task_node(run_dir / RECORD_NAME, record, trust_env_module, reader)
    if writes and (problem := writable_folder_problem(run_dir)):
        raise RefusedFolder(
            f"{run_dir}: expected {problem}; nothing was scored: {reader.verb} a copy of the "
            "folder in a place this process can write"
        )
    return RunFolder(run_dir, record, node)


def open_record(run_dir: Path, reader: Reader) -> dict[str, Any]:
    """The record of ``run_dir``, once no live run holds the folder (its ``run.lock``), for
    ``reader``: a run of one of its tasks, its fields as edr-run writes them
    (:func:`check_record_fields`). :class:`RefusedFolder` otherwise, naming the file."""
    if holder_alive(run_dir):
        raise RefusedFolder(
            f"{run_dir / LOCK}: a live run holds this folder and writes into it: {reader.verb} "
            f"it once that run has stopped, or {reader.verb} a copy of the folder"
        )
    path = run_dir / RECORD_NAME
    record = read_record(path, reader.remedy)
    if record.get("task", reader.tasks[0]) not in reader.tasks:
        raise RefusedFolder(
            f"{path} is a {record['task']} run: {reader.name} reads {' or '.join(reader.tasks)} "
            f"runs only ({reader.elsewhere})"
        )
    check_record_fields(path, record, reader.restore)
    return record


def check_record_fields(path: Path, record: dict[str, Any], remedy: str) -> None:
    """:class:`RefusedFolder` naming ``path`` and ``remedy`` where the record's status or one of
    :data:`RECORD_FIELDS` is not what edr-run writes (a record edited by hand, or another's)."""
    if record.get("status") not in STATUSES:
        raise RefusedFolder(
            f"{path}: status={record.get('status')!r}: expected one of {', '.join(STATUSES)} "
            f"(what edr-run writes); {remedy}"
        )
    for key, hint in RECORD_FIELDS.items():
        if expected := mismatch(record.get(key), hint):
            raise RefusedFolder(f"{path}: {key}={record.get(key)!r}: expected {expected}; {remedy}")


def config_node(path: Path, record: dict[str, Any], key: str, reader: Reader) -> dict[str, Any]:
    """The record's ``config.<key>`` (what rebuilds the run's parts); :class:`RefusedFolder`
    where it holds none."""
    config = record.get("config")
    node = config.get(key) if isinstance(config, dict) else None
    if not isinstance(node, dict):
        raise RefusedFolder(f"{path} has no config.{key} to rebuild the run from; {reader.restore}")
    return node


def _task_node(
    path: Path, record: dict[str, Any], trust_env_module: bool, reader: Reader
) -> dict[str, Any]:
    """The record's ``config.task``, checked in this order: the targets it names (nothing
    imported that is not the suite's), the modules making its env would import (only with
    ``trust_env_module``), then every value as ``edr-run`` checks its overrides."""
    node = config_node(path, record, "task", reader)
    try:
        check_targets(node, "config.task")
    except UntrustedRecord as error:
        raise UntrustedRecord(f"{path}: {error}; {reader.restore}") from None
    env = node.get("env") if isinstance(node.get("env"), dict) else {}
    named = {key: env.get(key) for key in ("env_id", "game", "env_module")}
    from edr.rl.settings import EnvSettings  # ale-py, gymnasium: only for an Atari record

    modules = EnvSettings.modules.fget(types.SimpleNamespace(**named))  # as the envs would
    if modules and not trust_env_module:
        raise UntrustedRecord(
            f"{path} names the module {', '.join(modules)} (task.env: env_module="
            f"{named['env_module']}, env_id={named['env_id']}, game={named['game']}): making its "
            "env imports it, which runs its code; pass --trust-env-module (trust_env_module=True) "
            "if you trust it"
        )
    try:
        cfg = OmegaConf.create({"seed": record["seed"], "task": node})
        check_config(cfg, entry={"seed": Seed})
    except ConfigError as error:
        raise RefusedFolder(f"{path}: config.{error}; {reader.restore}") from None
    except OmegaConfBaseException as error:  # an interpolation, a key OmegaConf cannot hold
        reason = " ".join(str(error).split())[:200]
        raise RefusedFolder(
            f"{path}: config.task is not a resolved config ({reason}); {reader.restore}"
        ) from None
    return node


def check_weights(
    path: Path, weights: Any, expected: Mapping[str, torch.Tensor], remedy: str
) -> None:
    """:class:`RefusedFolder` ending in ``remedy`` unless ``weights`` (what ``path`` holds as a
    network's state dict) has the keys of ``expected`` (the state dict of the network the run's
    record describes), each a tensor of the same shape."""
    if not isinstance(weights, Mapping):
        raise RefusedFolder(
            f"{path} holds {type(weights).__name__}, not a network's weights: {remedy}"
        )
    missing = [key for key in expected if key not in weights]
    extra = [key for key in weights if key not in expected]
    if missing or extra:
        said = "; ".join(
            f"{what} {', '.join(map(str, keys[:3]))}{' ...' if len(keys) > 3 else ''}"
            for what, keys in (("lacks", missing), ("has", extra)) if keys
        )  # fmt: skip
        raise RefusedFolder(
            f"{path} holds the weights of another network than its run.json describes ({said}): "
            f"{remedy}"
        )
    for key, tensor in expected.items():
        found = weights[key]
        if not isinstance(found, torch.Tensor) or found.shape != tensor.shape:
            shape = tuple(found.shape) if isinstance(found, torch.Tensor) else type(found).__name__
            raise RefusedFolder(
                f"{path}: {key} is {shape}, where the network its run.json describes takes "
                f"{tuple(tensor.shape)} (another input, game or network?): {remedy}"
            )


def payload_part(path: Path, payload: Any, key: str, kind: type, remedy: str) -> Any:
    """``payload[key]`` (what ``path`` holds: a checkpoint's or a network file's dict), which must
    be a ``kind``; :class:`RefusedFolder` naming what the file holds, and ``remedy``, otherwise."""
    if not isinstance(payload, dict):
        raise RefusedFolder(
            f"{path} holds {type(payload).__name__}, not what edr-run writes (a dict with "
            f"'{key}'): {remedy}"
        )
    value = payload.get(key)
    if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
        keys = ", ".join(map(str, list(payload)[:5]))
        raise RefusedFolder(
            f"{path}: '{key}' is {type(value).__name__ if key in payload else 'missing'}, "
            f"expected {kind.__name__} (the file holds {keys or 'nothing'}): not what edr-run "
            f"writes; {remedy}"
        )
    return value
