"""The scalar logger a training task writes to (torchrl's), rewound when a run resumes, and
the names a config may give it."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

from edr.checks.config import Check
from edr.store.atomic import write_text_atomic

if TYPE_CHECKING:
    from torchrl.record.loggers import Logger

LOG_DIR = "logs"  # under the run directory
# The torchrl loggers a task can write to, and the package each needs.
LOGGER_PACKAGES = {"csv": None, "tensorboard": "tensorboard", "mlflow": "mlflow", "wandb": "wandb"}


def _logger_problem(name: Any) -> str | None:
    if name in ("", None):
        return None
    if name not in LOGGER_PACKAGES:
        return f"one of {', '.join(LOGGER_PACKAGES)} or '' (no logger)"
    package = LOGGER_PACKAGES[name]
    if package and importlib.util.find_spec(package) is None:
        return f"the {package} package installed for logger={name} (pip install '.[loggers]')"
    return None


LoggerName = Annotated[str, Check(_logger_problem)]  # a logger above, or '' for none


def rewind_csv_logs(log_dir: Path, step: int) -> None:
    """Drop every row after ``step`` from torchrl's CSV scalar files (``step,value`` lines), so a
    resumed run does not log the steps it repeats twice; ``step=0`` empties them."""
    for file in sorted(Path(log_dir).rglob("*.csv")):
        lines = file.read_text(errors="replace").splitlines()
        kept = [line for line in lines if (logged := _step(line)) is not None and logged <= step]
        if len(kept) != len(lines):  # a garbled line (a crash mid-write) goes too
            write_text_atomic(file, "".join(f"{line}\n" for line in kept))


def _step(line: str) -> float | None:
    """The step of a ``step,value`` line; None for a line that is not one."""
    try:
        return float(line.split(",", 1)[0])
    except ValueError:
        return None


def open_logger(kind: str, out_dir: Path, step: int) -> Logger | None:
    """torchrl's ``kind`` logger writing under ``out_dir/logs``, continuing at ``step``; None for
    ``kind=''``. CSV files are rewound to ``step`` first (other loggers key scalars by step)."""
    if not kind:
        return None
    from torchrl.record.loggers import get_logger  # heavy import, only where it is used

    rewind_csv_logs(Path(out_dir) / LOG_DIR, step)
    return get_logger(kind, logger_name=str(out_dir), experiment_name=LOG_DIR)
