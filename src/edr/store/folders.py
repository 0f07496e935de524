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

import errno
import json
import logging
import os
import socket
import sys
import time
import uuid
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from hydra.core.hydra_config import HydraConfig
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, read_write

from edr.checks.config import ConfigError, path_problem
from edr.store.checkpoints import CHECKPOINT, NETWORK
from edr.store.identity import (
    IDENTITY_KEYS,
    config_diff,
    flatten,
    ignored_overrides,
    is_semantic_override,
    warn_ignored,
    with_root_symbols,
    without_added_defaults,
)
from edr.store.records import RECORD_NAME, now, read_record

ATTEMPTS = "attempts.jsonl"
SWEEP_ID = "EDR_SWEEP_ID"  # the environment variable naming the sweep a run belongs to
LOCK = "run.lock"  # held while a process writes the folder: {"host", "pid", "since"}
Resume = Literal["auto", True, False]
# Levels of names a run writes under its folder (.hydra/config.yaml, pretrain/checkpoint.pt),
# and a sweep under its own (a cell's folder, then those).
FOLDER_ROOM = {"run": 2, "sweep": 3}
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
    record = read_record(record_path) if os.path.lexists(record_path) else None  # a folder too
    nested = next(_nested_records(out_dir), None)
    if nested is not None:
        raise ConfigError(
            f"{out_dir} holds other runs ({nested}): a run writes into its own folder, never "
            "over a folder of runs; choose another folder (hydra.run.dir or out_dir)"
        )
    # A task may checkpoint a stage in a subfolder (DVS transfer: pretrain/checkpoint.pt).
    checkpoint = next(out_dir.rglob(CHECKPOINT), None) if out_dir.is_dir() else None
    if resume is False:
        return Plan("run", record)
    if record is not None and record.get("fingerprint") != fingerprint:
        # what can change a result (a record from before the fingerprint kept only these keys
        # holds the whole config, one from before the roots had symbols holds its machine's
        # folders, and one from before an ADDED_DEFAULTS entry holds that key at its old value:
        # the same run if these agree)
        old = {k: v for k, v in record.get("semantic_config", {}).items() if k in IDENTITY_KEYS}
        old = without_added_defaults(with_root_symbols(old, _roots(record)))
        if old == semantic:
            return _plan_for_this_config({**record, "fingerprint": fingerprint}, checkpoint,
                                         resume, out_dir)  # fmt: skip
        extended = _raised_budgets(old, semantic)
        if extended and checkpoint is not None:
            return Plan("resume", record, extended)
        if extended and record.get("status") == "finished":
            raise ConfigError(
                f"{out_dir} finished and kept its {NETWORK}, not the {CHECKPOINT} a larger budget "
                f"({'; '.join(extended)}) would continue from: choose another folder for the "
                "longer run, or pass resume=false to start over"
            )
        changed = config_diff(old, semantic) if old else ["(the record predates fingerprints)"]
        raise ConfigError(
            f"{out_dir} holds a run of another config ({'; '.join(changed)}): "
            "restore those values, choose another folder, or pass resume=false to start over"
        )
    return _plan_for_this_config(record, checkpoint, resume, out_dir)


def _roots(record: dict[str, Any]) -> dict[str, Any]:
    """The suite's roots a record's run had (its ``config.paths``); none where it names none."""
    config = record.get("config")
    paths = config.get("paths") if isinstance(config, dict) else None
    return paths if isinstance(paths, dict) else {}


def _nested_records(out_dir: Path) -> Iterator[Path]:
    """The run records in the folders below ``out_dir``: other runs, not this one's stages."""
    return (p for p in out_dir.rglob(f"*/{RECORD_NAME}")) if out_dir.is_dir() else iter(())


def _plan_for_this_config(
    record: dict[str, Any] | None, checkpoint: Path | None, resume: Resume, out_dir: Path
) -> Plan:
    """The plan once ``record`` (if any) is known to be of this config."""
    if record is not None and record.get("status") == "finished":
        if not isinstance(record.get("metrics"), dict):
            raise ConfigError(
                f"{out_dir / RECORD_NAME} says finished but holds no metrics: pass "
                "resume=false to run it again, or move its folder away"
            )
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


class FolderHeld(ConfigError):
    """Another live process writes this run folder."""


def _holder(lock: Path) -> dict[str, Any] | None:
    try:
        return json.loads(lock.read_text())
    except (OSError, ValueError):
        return None  # gone, or half-written by a process that died while writing it


def process_identity(pid: int) -> str | None:
    """What tells process ``pid`` from a later one that reuses its number: this boot's id and
    the process's start time (Linux's /proc); None where the system does not say."""
    try:
        boot = Path("/proc/sys/kernel/random/boot_id").read_text().strip()
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat.rsplit(")", 1)[-1].split()  # after the command's name, which may hold spaces
    return f"{boot}:{fields[19]}" if len(fields) > 19 else None  # field 22: starttime


def holder_alive(out_dir: Path) -> bool:
    """Whether a live process holds ``out_dir`` (on another host: assumed alive): its pid runs,
    and, where the lock names it, is still the process that took the lock (a pid the system
    gave to another process since is no holder)."""
    holder = _holder(Path(out_dir) / LOCK)
    if holder is None:
        return False
    if holder.get("host") != socket.gethostname():
        return True
    try:
        pid = int(holder.get("pid", -1))
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, ValueError, OverflowError, TypeError):
        return True
    started = holder.get("process")
    return started is None or process_identity(pid) in (None, started)


@contextmanager
def hold_folder(out_dir: Path) -> Iterator[None]:
    """Hold ``out_dir`` for this process while the body runs: one writer per run folder. A lock
    left by a process that died is taken over; a live holder is :class:`FolderHeld`."""
    lock = Path(out_dir) / LOCK
    me = {"host": socket.gethostname(), "pid": os.getpid(), "since": now(),
          "process": process_identity(os.getpid())}  # fmt: skip
    for _ in range(2):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            if holder_alive(out_dir):
                holder = _holder(lock) or {}
                raise FolderHeld(
                    f"{out_dir} is held by process {holder.get('pid')} on "
                    f"{holder.get('host')} since {holder.get('since')} ({lock}): wait for it, "
                    "or choose another folder"
                ) from None
            log.warning("%s: taking over the lock of a process that is gone", out_dir)
            lock.unlink(missing_ok=True)
            continue
        with os.fdopen(fd, "w") as f:
            f.write(json.dumps(me))
        break
    else:
        raise FolderHeld(f"{lock}: could not take the folder's lock")
    try:
        yield
    finally:
        if (_holder(lock) or {}).get("pid") == me["pid"]:
            lock.unlink(missing_ok=True)


def log_attempt(out_dir: Path, outcome: str, fingerprint: str, **details: Any) -> None:
    """Append one line (time, outcome, fingerprint, details) to ``out_dir/attempts.jsonl``."""
    sweep = os.environ.get(SWEEP_ID)  # the sweep this attempt belongs to, if a sweep ran it
    line = json.dumps(
        {
            "at": now(),
            "unix": time.time(),
            "outcome": outcome,
            "fingerprint": fingerprint,
            **({"sweep": sweep} if sweep else {}),
            **details,
        }
    )
    path = out_dir / ATTEMPTS
    with open(path, "a+b") as f:  # appends go to the end, wherever the reads were
        size = f.seek(0, os.SEEK_END)
        if size:
            f.seek(size - 1)
            if f.read(1) != b"\n":  # a line a crash cut short ends before this one starts
                f.write(b"\n")
        f.write(line.encode() + b"\n")


def _attempt(line: str) -> dict[str, Any] | None:
    """One line of ``attempts.jsonl``; None for a line a crash cut short."""
    try:
        attempt = json.loads(line)
    except ValueError:
        return None
    return attempt if isinstance(attempt, dict) and {"unix", "outcome"} <= attempt.keys() else None


def last_outcomes(sweep_dir: Path, since: float, sweep: str | None = None) -> dict[Path, str]:
    """The last outcome of every job folder under ``sweep_dir`` attempted after ``since`` (by
    the sweep ``sweep`` only, when given: another sweep sharing the folder counts its own),
    by folder."""
    found: dict[Path, str] = {}
    for file in sorted(Path(sweep_dir).glob(f"*/{ATTEMPTS}")):
        attempts = [a for line in file.read_text(errors="replace").splitlines()
                    if (a := _attempt(line)) is not None]  # fmt: skip
        mine = [a for a in attempts if sweep is None or a.get("sweep") == sweep]
        if mine and mine[-1]["unix"] >= since:
            found[file.parent.resolve()] = mine[-1]["outcome"]
    return found


def outcomes_since(sweep_dir: Path, since: float, sweep: str | None = None) -> Counter[str]:
    """How many job folders under ``sweep_dir`` ended each way (:func:`last_outcomes`)."""
    return Counter(last_outcomes(sweep_dir, since, sweep).values())


def _run_each_folder_once(config: DictConfig) -> None:
    """A swept key that cannot change a result (``threads=1,2``, or a group the task does not
    read: ``representation=edr,edr_k3`` for the demo) would give cells of one fingerprint, each
    run again: sweep its first value only, and say so."""
    overrides = list(config.hydra.overrides.task)
    same = set(ignored_overrides(config, overrides))
    kept = [
        o.split(",")[0] if "," in o and (o in same or not is_semantic_override(o)) else o
        for o in overrides
    ]
    if kept != overrides:
        dropped = [o for o, k in zip(overrides, kept, strict=True) if o != k]
        log.warning(
            "warning: %s: these values do not change a result (the same fingerprint for "
            "each), so the sweep runs each cell once, with %s",
            " ".join(dropped),
            " ".join(k for o, k in zip(overrides, kept, strict=True) if o != k),
        )
        with read_write(config.hydra.overrides):
            config.hydra.overrides.task = kept


class RunFolder(Callback):
    """Before Hydra makes a run's (or a sweep's) folder: one that cannot be made (a read-only
    disk, a file in its way) or whose path leaves no room for the files a run writes in it is
    refused in one line, exit 2, instead of Hydra's traceback."""

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        self._make(config, "run")

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        self._make(config, "sweep")

    @staticmethod
    def _make(config: DictConfig, kind: Literal["run", "sweep"]) -> None:
        HydraConfig.instance().set_config(config)  # the folder's name reads hydra:runtime
        given = str(config.hydra[kind].dir)  # as given: Path("") is ".", the current folder
        folder = Path(given)
        if problem := path_problem(given, below=FOLDER_ROOM[kind]):
            shown = given if len(given) < 120 else f"{given[:100]}..."
            print(f"edr-run: hydra.{kind}.dir={shown}: expected {problem}", file=sys.stderr)
            raise SystemExit(2)
        try:
            folder.mkdir(parents=True, exist_ok=True)
            if not os.access(folder, os.W_OK):  # there, but not this user's to write
                raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(folder))
        except OSError as error:
            print(
                f"edr-run: cannot create the {kind} folder {folder}: {error.strerror} "
                f"({error.filename}): make the results folder writable, or move results with "
                "EDR_RESULTS=<folder> (or paths.results=...)",
                file=sys.stderr,
            )
            raise SystemExit(2) from None


# The folders of this process's sweep's cells refused in one line (a ConfigError): those that
# logged no attempt (refused before their run began) count as refused; the others count once,
# as their attempt says (a task that refused its data after the record was written: failed).
# (None: a cell whose folder could not be resolved, counted alone)
refused_cells: list[Path | None] = []


class SweepSummary(Callback):
    """At the end of a multirun, one line: how many cells were skipped, resumed, run, failed,
    interrupted or refused; exit status 1 when any failed or was refused. A sweep that Ctrl-C
    or SIGTERM stops gets its line too (:meth:`interrupted`), from the entry point."""

    under_way: SweepSummary | None = None  # the sweep this process runs, until its line is said
    started = 0.0  # when it started: the attempts it counts are the later ones

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        self.started, self.sweep_dir = time.time(), Path(config.hydra.sweep.dir)
        # the sweep's own id, which every job's attempt carries (launchers' workers and Slurm
        # jobs inherit the environment): a second sweep in the same folder counts apart
        self.sweep_id = os.environ[SWEEP_ID] = uuid.uuid4().hex[:12]
        SweepSummary.under_way = self
        warn_ignored(config, config.hydra.overrides.task)
        _run_each_folder_once(config)

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        self.sweep_dir = Path(config.hydra.sweep.dir)
        if self._say():
            raise SystemExit(1)

    @classmethod
    def interrupted(cls) -> None:
        """The summary line of the sweep a signal stopped, if one was under way."""
        if cls.under_way is not None:
            cls.under_way._say()

    def _say(self) -> bool:
        """Log the summary line (once); whether a cell failed or was refused."""
        SweepSummary.under_way = None
        os.environ.pop(SWEEP_ID, None)  # later runs of this process belong to no sweep
        outcomes = last_outcomes(self.sweep_dir, self.started, getattr(self, "sweep_id", None))
        unplaced = [folder for folder in refused_cells if folder is None]
        for folder in refused_cells:  # every job once: by its folder
            if folder is not None:
                outcomes.setdefault(folder.resolve(), "refused")
        counts = Counter(outcomes.values())
        counts["refused"] += len(unplaced)
        order = ("skipped", "resumed", "ran", "failed", "interrupted", "refused")
        shown = [k for k in order if k != "refused" or counts[k]]
        log.info("sweep %s: %s", self.sweep_dir, ", ".join(f"{counts[k]} {k}" for k in shown))
        return bool(counts["failed"] or counts["refused"])
