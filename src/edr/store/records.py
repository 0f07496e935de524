"""Run records: one JSON file per run, with everything needed to trust and regenerate a number.

``run.json`` holds the run's ``status`` (``running``, ``finished``, ``interrupted`` by Ctrl-C or
SIGTERM, resumable, or ``failed`` with its ``error``; :func:`run_status` reads records from before
``interrupted`` was a status, which say ``failed`` with error ``interrupted``), its ``fingerprint`` and ``cell`` (see ``edr.store.identity``), the ``scale`` (``tiny``,
``full`` or a named preset), the ``data`` it read (source, root, content fingerprint), flat
scalar ``metrics``, the resolved config, the command-line overrides, git revision (``+dirty``
for uncommitted changes), machine and times. Curves, histories and confusion matrices are files
beside it.

No machine's folder is written for the results root: a path under it is written from it
(``<paths.results>/cache/write_synthetic_kth_3f44a9a7a8``, also ``config.out_dir`` and
``config.paths.results`` itself), a file of the run from its folder (``figure/pixel:
pixel_response.png``); paths elsewhere stay as they were given. Records from before hold
absolute paths; whatever reads a record takes both.
"""

from __future__ import annotations

import errno
import json
import os
import platform
import re
import socket
import stat
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from omegaconf import DictConfig, OmegaConf

from edr.store.atomic import write_json_atomic

RECORD_NAME = "run.json"
INTERRUPTED = "interrupted"  # the status of a run Ctrl-C or SIGTERM stopped: it resumes
# What an unreadable record's message advises: edr-run's remedy, unless the reader says its own.
RERUN = "pass resume=false to start the run over, or move its folder away"


OUTPUT_DIRS = ("results", "paper")  # what runs and edr-tables write: no change to the code
DIRTY = "+dirty"  # a revision with changes to tracked files that no commit holds


def git_revision(repo: Path | None = None) -> str:
    """The checked-out commit, with ``+dirty`` when tracked files outside the output folders
    (:data:`OUTPUT_DIRS`) have changes; ``unknown`` outside git."""
    cwd = repo or Path(__file__).resolve().parent
    excluded = [f":(top,exclude){folder}" for folder in OUTPUT_DIRS]
    try:
        rev = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=cwd, capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no", "--", ":(top)", *excluded],
            cwd=cwd,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return rev + (DIRTY if dirty else "")


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine_info() -> dict[str, Any]:
    """Where a number was measured: host, CPU, cores and threads, library versions, GPU."""
    info: dict[str, Any] = {
        "hostname": socket.gethostname(),
        "platform": platform.platform(),
        "cpu": cpu_model(),
        "cpu_count": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
    }
    return info


def write_record(out_dir: Path, record: dict[str, Any]) -> Path:
    """Write ``out_dir/run.json`` whole (a reader never sees half a record)."""
    return write_json_atomic(Path(out_dir) / RECORD_NAME, record)


def write_last_record(out_dir: Path, record: dict[str, Any]) -> str | None:
    """Write a run's last record (failed, interrupted) even on a full disk: atomically where the
    disk takes a new file, else over the record that is there, in place (its blocks are the
    disk's last free space); None, or the reason it could not be written."""
    try:
        write_record(out_dir, record)
        return None
    except OSError as error:
        text = (json.dumps(record, indent=2, default=str) + "\n").encode()
        try:
            with open(Path(out_dir) / RECORD_NAME, "r+b") as f:
                f.write(text)
                f.truncate()
            return None
        except OSError:
            return f"{error.strerror or error}"


class UnreadableRecord(ValueError):
    """A record that is empty, truncated or not JSON; the message names the file and the remedy."""


def regular_file_bytes(path: Path) -> bytes:
    """The bytes of ``path``, which must be a regular file (links followed): a folder, a named
    pipe (which would block its reader forever) or a link loop is an :class:`OSError` saying
    what it is; a missing file :class:`FileNotFoundError`, as ``open`` says."""
    mode = os.stat(path).st_mode  # a link loop: ELOOP
    if not stat.S_ISREG(mode):
        kind = (
            "a folder"
            if stat.S_ISDIR(mode)
            else "a named pipe"
            if stat.S_ISFIFO(mode)
            else "not a regular file"
        )
        raise OSError(errno.EINVAL, f"{kind}, not a file", str(path))
    return Path(path).read_bytes()


def read_record(path: Path, remedy: str = RERUN) -> dict[str, Any]:
    """The record at ``path``; :class:`UnreadableRecord` naming it and ``remedy`` if it cannot
    be read or parsed (a folder, a pipe, not JSON); :class:`FileNotFoundError` if there is none."""
    try:
        record = json.loads(regular_file_bytes(path).decode())
    except FileNotFoundError:
        raise
    except (OSError, ValueError, RecursionError) as error:  # ValueError: JSON's, UTF-8's
        reason = error.strerror if isinstance(error, OSError) else error
        raise UnreadableRecord(
            f"{path} is not a readable run record ({reason}): {remedy}"
        ) from None
    if not isinstance(record, dict):
        raise UnreadableRecord(f"{path} holds {type(record).__name__}, not a run record: {remedy}")
    return record


def run_status(record: dict[str, Any]) -> str:
    """The record's status (``legacy`` where it has none: records from before the results
    store); a record written before ``interrupted`` was a status, ``failed`` with error
    ``interrupted``, is :data:`INTERRUPTED`."""
    status = record.get("status", "legacy")
    return INTERRUPTED if status == "failed" and record.get("error") == INTERRUPTED else status


def record_config(cfg: DictConfig) -> dict[str, Any]:
    """What a record stores as its ``config``: ``cfg`` resolved, without the top-level parts (a
    node with ``_target_``: ``backbone``, ``optimizer``) that its task's node does not
    interpolate, which the run never built (an Atari run's LeNet and SGD). The fingerprint is
    computed from ``seed`` and ``task`` alone (:mod:`edr.store.identity`): it does not change."""
    task = json.dumps(OmegaConf.to_container(cfg.task, resolve=False))
    used = set(re.findall(r"\$\{(\w+)", task))
    return {
        key: value
        for key, value in OmegaConf.to_container(cfg, resolve=True).items()
        if key == "task" or key in used or not (isinstance(value, dict) and "_target_" in value)
    }


def check_flat(metrics: dict[str, Any]) -> dict[str, Any]:
    """``metrics`` if every value is a scalar (number, bool, string, None); curves, histories and
    matrices belong in files beside the record."""
    nested = [k for k, v in metrics.items() if not isinstance(v, int | float | bool | str | None)]
    if nested:
        raise TypeError(f"metrics must be flat scalars; write these as files instead: {nested}")
    return metrics


def now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")


@dataclass
class BenchRow:
    """One measured line of a bench record (``edr-bench``, ``edr-bench --atari``)."""

    name: str  # the representation, as Table 2 names it, or the Atari config
    implementation: str  # what ran: fused kernel, torch ops, OpenCV, EnvPool, ...
    frames: int  # input frames per timed call
    frame_size: str  # "320x240" or "32 x 84x84"
    median_s: float  # median seconds per call
    fps: float  # input frames per second (all batch rows counted)


def bench_dir() -> Path:
    """Where the benchmarks (edr-bench, edr.studies.flows, edr.studies.edr_stability) write their records
    by default: ``results/runs/bench/`` (under ``EDR_RESULTS`` when it is set), which git ignores.
    The committed records in ``results/bench/``, which ``edr-tables`` reads, are written there
    with ``--out-dir results/bench``."""
    return Path(os.environ.get("EDR_RESULTS") or "results") / "runs" / "bench"
