"""The results store: one folder per run (a sweep's cell), and what a run does when it meets its
folder again.

- a ``finished`` record with the same fingerprint: nothing to do (skipped);
- a checkpoint left by a run of the same fingerprint: continue from it (resumed);
- a checkpoint left by a run whose config differs only in a budget raised (``EXTENDABLE``):
  continue from it to the new budget (resumed, the record saying ``extended``);
- a record of another config: refused, naming the keys that differ;
- otherwise: run.

Every attempt appends one line to ``attempts.jsonl`` in the folder; at the end of a multirun,
:class:`SweepSummary` counts what this sweep skipped, resumed, ran and lost.
"""

from __future__ import annotations

import json
import logging
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from edr.identity import config_diff, flatten, warn_ignored
from edr.records import RECORD_NAME, now, read_record
from edr.tasks.checkpoints import CHECKPOINT
from edr.validate import ConfigError

ATTEMPTS = "attempts.jsonl"
Resume = Literal["auto", True, False]
# Budgets a run may be raised to and continued: the training up to the old budget does not
# depend on them (Atari's learning rate follows task.optim.lr_decay_env_steps, not
# task.env_steps).
EXTENDABLE = frozenset({"task.env_steps"})
log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Plan:
    """What a run does in its folder: ``skip`` (finished), ``resume`` (checkpoint) or ``run``."""

    action: Literal["skip", "resume", "run"]
    record: dict[str, Any] | None  # the record found there, if any
    extended: tuple[str, ...] = ()  # the budgets a resume raises, as ``key: old -> new``


def _raised_budgets(old: dict[str, Any], new: dict[str, Any]) -> tuple[str, ...]:
    """The differences of ``new`` from ``old`` when every one is an ``EXTENDABLE`` budget raised;
    () when any other key differs or a budget is lowered."""
    a, b = flatten(old), flatten(new)
    changed = {key for key in a.keys() | b.keys() if a.get(key) != b.get(key)}
    if not changed or not changed <= EXTENDABLE:
        return ()
    if not all(isinstance(a.get(k), int) and b.get(k, 0) > a[k] for k in changed):
        return ()
    return tuple(config_diff(old, new))


def plan_attempt(out_dir: Path, fingerprint: str, semantic: dict[str, Any], resume: Resume) -> Plan:
    """Decide from ``out_dir``'s record and checkpoint; ``resume=False`` always starts over,
    ``True`` requires something to continue, ``auto`` takes what is there."""
    record_path = out_dir / RECORD_NAME
    record = read_record(record_path) if record_path.is_file() else None
    # A task may checkpoint a stage in a subfolder (DVS transfer: pretrain/checkpoint.pt).
    checkpoint = next(out_dir.rglob(CHECKPOINT), None) if out_dir.is_dir() else None
    if resume is False:
        return Plan("run", record)
    if record is not None and record.get("fingerprint") != fingerprint:
        old = record.get("semantic_config", {})
        extended = _raised_budgets(old, semantic) if checkpoint is not None else ()
        if extended:
            return Plan("resume", record, extended)
        changed = config_diff(old, semantic) if old else ["(the record predates fingerprints)"]
        raise ConfigError(
            f"{out_dir} holds a run of another config ({'; '.join(changed)}): "
            "restore those values, choose another folder, or pass resume=false to start over"
        )
    if record is not None and record.get("status") == "finished":
        return Plan("skip", record)
    if checkpoint is not None:
        if record is None:
            raise ConfigError(
                f"{checkpoint} has no run.json beside it, so its config cannot be checked: "
                "pass resume=false to start over"
            )
        return Plan("resume", record)
    if resume is True:
        raise ConfigError(
            f"resume=true but {out_dir} holds no checkpoint to resume "
            f"({'no such folder' if not out_dir.exists() else 'no ' + CHECKPOINT})"
        )
    return Plan("run", record)


def log_attempt(out_dir: Path, outcome: str, fingerprint: str, **details: Any) -> None:
    """Append one line (time, outcome, fingerprint, details) to ``out_dir/attempts.jsonl``."""
    line = json.dumps(
        {
            "at": now(),
            "unix": time.time(),
            "outcome": outcome,
            "fingerprint": fingerprint,
            **details,
        }
    )
    with open(out_dir / ATTEMPTS, "a") as f:
        f.write(line + "\n")


def outcomes_since(sweep_dir: Path, since: float) -> Counter[str]:
    """The last outcome of every job folder under ``sweep_dir`` attempted after ``since``."""
    counts: Counter[str] = Counter()
    for file in sorted(Path(sweep_dir).glob(f"*/{ATTEMPTS}")):
        lines = file.read_text().splitlines()
        if lines and (last := json.loads(lines[-1]))["unix"] >= since:
            counts[last["outcome"]] += 1
    return counts


class SweepSummary(Callback):
    """At the end of a multirun, one line: how many cells were skipped, resumed, run, failed."""

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        self.started = time.time()
        warn_ignored(config, config.hydra.overrides.task)

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        sweep_dir = Path(config.hydra.sweep.dir)
        counts = outcomes_since(sweep_dir, getattr(self, "started", 0.0))
        order = ("skipped", "resumed", "ran", "failed", "interrupted")
        log.info("sweep %s: %s", sweep_dir, ", ".join(f"{counts.get(k, 0)} {k}" for k in order))
