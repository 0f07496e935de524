"""The scalar logger a training task writes to (torchrl's), rewound when a run resumes."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from edr.atomic import write_text_atomic

if TYPE_CHECKING:
    from torchrl.record.loggers import Logger

LOG_DIR = "logs"  # under the run directory


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
