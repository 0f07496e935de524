"""Run records: one JSON file per run, with everything needed to trust and regenerate a number."""

from __future__ import annotations

import json
import os
import platform
import socket
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import torch

RECORD_NAME = "run.json"


def git_revision(repo: Path | None = None) -> str:
    """The checked-out commit, with ``+dirty`` when the tree has changes; ``unknown`` outside git."""
    cwd = repo or Path(__file__).resolve().parent
    try:
        rev = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=cwd, capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=cwd,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return rev + ("+dirty" if dirty else "")


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


def write_json_atomic(path: Path, payload: dict[str, Any]) -> Path:
    """Write ``payload`` to ``path`` so that readers see the old file or the whole new one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(payload, f, indent=2, sort_keys=False, default=str)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def write_run_record(
    out_dir: Path,
    *,
    task: str,
    choices: dict[str, str],
    config: dict[str, Any],
    overrides: list[str],
    metrics: dict[str, Any],
    wall_time_s: float,
) -> Path:
    """Write ``out_dir/run.json``: config choices and resolved values, metrics, git, machine, time."""
    record = {
        "task": task,
        "choices": choices,
        "overrides": overrides,
        "metrics": metrics,
        "wall_time_s": round(wall_time_s, 3),
        "finished_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "git": git_revision(),
        "machine": machine_info(),
        "config": config,
    }
    return write_json_atomic(Path(out_dir) / RECORD_NAME, record)


def read_record(path: Path) -> dict[str, Any]:
    with open(path) as f:
        return json.load(f)
