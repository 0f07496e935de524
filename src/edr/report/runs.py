"""Every run record under one or more folders, as a pandas DataFrame, and its cells.

One row per record. Columns: ``record`` (path), ``run_dir``, ``task``, ``status``, ``error``,
``fingerprint``, ``cell``, ``seed``, ``scale``, ``git``, ``machine`` (CPU, cores, GPU in one
string), ``data.<key>`` (source, fingerprint, ...), ``choices.<group>``, ``config.<dotted.key>``
and ``metrics.<name>``.

A table cell aggregates only finished runs that share everything but the seed: the same
``cell`` fingerprint, data fingerprint, data source and scale. Failed, running and pre-store
records are listed, never averaged.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from edr.identity import flatten
from edr.records import RECORD_NAME
from edr.store import holder_alive

# What must match for runs to be averaged into one number.
CELL_KEYS = ["cell", "data.fingerprint", "data.source", "scale"]
# Columns every frame has, even with no records (or only records from before the store).
BASE_COLUMNS = ["record", "run_dir", "task", "status", "error", "fingerprint", "seed", "git",
                "machine", "ended_at", *CELL_KEYS]  # fmt: skip


def _machine(record: dict[str, Any]) -> str:
    m = record.get("machine", {})
    return f"{m.get('cpu', '?')} ({m.get('cpu_count', '?')} cores), GPU: {m.get('gpu') or 'none'}"


def _shown(path: Path) -> str:
    """``path`` relative to the working directory where it lies under it (tables name records
    that way, so that a committed table does not carry one machine's absolute paths)."""
    return str(path.relative_to(Path.cwd())) if path.is_relative_to(Path.cwd()) else str(path)


def _status(path: Path, record: dict[str, Any]) -> str:
    """The record's status; ``running`` only while a live process holds its folder (a run
    killed by the OOM killer or a full disk leaves ``running`` behind: it is ``interrupted``)."""
    status = record.get("status", "legacy")  # legacy: records from before the results store
    if status == "running" and not holder_alive(path.parent):
        return "interrupted"
    return status


def _row(path: Path, record: dict[str, Any]) -> dict[str, Any]:
    row: dict[str, Any] = {
        "record": _shown(path),
        "run_dir": _shown(path.parent),
        "task": record.get("task"),
        "status": _status(path, record),
        "error": record.get("error"),
        "fingerprint": record.get("fingerprint"),
        "cell": record.get("cell"),
        "seed": record.get("seed", record.get("config", {}).get("seed")),
        "scale": record.get("scale"),
        "git": record.get("git"),
        "machine": _machine(record),
        "ended_at": record.get("ended_at"),
    }
    for section in ("data", "choices", "metrics"):
        row.update({f"{section}.{k}": v for k, v in record.get(section, {}).items()})
    row.update({f"config.{k}": v for k, v in flatten(record.get("config", {})).items()})
    return row


def load_runs(roots: Iterable[str | Path]) -> pd.DataFrame:
    """Every ``run.json`` under ``roots`` (searched recursively), one row each, oldest first."""
    paths = sorted(
        {p.resolve() for root in roots for p in Path(root).rglob(RECORD_NAME)},
        key=lambda p: p.stat().st_mtime,
    )
    rows = []
    for path in paths:
        try:
            rows.append(_row(path, json.loads(path.read_text())))
        except (OSError, json.JSONDecodeError) as error:
            rows.append({"record": _shown(path), "status": "unreadable", "error": str(error)})
    frame = pd.DataFrame(rows)
    return frame.reindex(columns=[*BASE_COLUMNS, *(c for c in frame if c not in BASE_COLUMNS)])


def finished(
    runs: pd.DataFrame,
    task: str,
    select: Callable[[pd.DataFrame], pd.DataFrame] | None = None,
) -> pd.DataFrame:
    """The finished runs of ``task`` that a table asked for (``select``: the records its sweep
    defines); then, of several records of one fingerprint (the same run in two folders, or
    asked for by two sweeps), the newest only, so that no run is counted twice in one table.
    Selecting before that keeps a run shared by two tables in both."""
    if runs.empty:
        return runs
    done = runs[(runs["task"] == task) & (runs["status"] == "finished")]
    if select is not None:
        done = select(done)
    return done.drop_duplicates("fingerprint", keep="last")


def unfinished(runs: pd.DataFrame, task: str) -> pd.DataFrame:
    """The runs of ``task`` that are not finished (failed, running, legacy), and every record
    that could not be read (whose task nobody knows): to list under a table, not average."""
    if runs.empty:
        return runs
    mine = (runs["task"] == task) & (runs["status"] != "finished")
    return runs[mine | (runs["status"] == "unreadable")]


def cells(runs: pd.DataFrame, metrics: Sequence[str], labels: Sequence[str]) -> pd.DataFrame:
    """One row per cell: ``labels`` (taken from its runs), each metric's mean, std and the runs
    behind it (``runs``, ``seeds``, ``records``, ``machines``, ``gits``)."""
    columns = [*labels, *CELL_KEYS]
    out = []
    for _, group in runs.groupby(CELL_KEYS, dropna=False, sort=False):
        row = {label: group[label].iloc[0] for label in labels}
        row.update({key: group[key].iloc[0] for key in CELL_KEYS})
        for metric in metrics:
            values = pd.to_numeric(group.get(metric), errors="coerce")
            row[f"{metric}:mean"] = values.mean()
            row[f"{metric}:std"] = values.std(ddof=1) if len(values) > 1 else float("nan")
        row["runs"] = len(group)
        row["seeds"] = sorted(group["seed"].dropna().astype(int).tolist())
        row["records"] = group["record"].tolist()
        row["machines"] = sorted(set(group["machine"]))
        row["gits"] = sorted(set(group["git"].dropna()))
        out.append(row)
    frame = pd.DataFrame(out)
    if frame.empty:
        return frame.reindex(columns=columns)
    return frame.sort_values(list(labels), key=lambda c: c.astype(str), kind="stable")


def run_history(record: str) -> list[dict[str, Any]]:
    """The rows of a run's ``history.json`` (beside its record); none if it has none."""
    file = Path(record).parent / "history.json"
    return json.loads(file.read_text()) if file.is_file() else []
