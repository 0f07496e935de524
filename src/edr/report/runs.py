"""Every run record under one or more folders, as a pandas DataFrame, and its cells.

One row per record. Columns: ``record`` (path), ``run_dir``, ``task``, ``status``, ``error``,
``fingerprint``, ``cell``, ``seed``, ``scale``, ``git``, ``machine`` (CPU, cores, GPU in one
string), ``data.<key>`` (source, fingerprint, ...), ``choices.<group>``, ``config.<dotted.key>``
and ``metrics.<name>``.

A table cell aggregates only finished runs that share everything but the seed: the same
``cell`` fingerprint, data fingerprint, data source and scale. Failed, running and pre-store
records are listed, never averaged; so is every record that cannot be read (not JSON, not a
record, a wrong-typed field, larger than a record is, a file it names that is broken or lies
outside its run folder), every run folder reached through a symbolic link, and every finished
record that cannot count (:func:`uncountable`: no fingerprint or cell, a metric that is no
finite measurement; in a table that averages a metric, a run that diverged and so has none,
:func:`placeable`), each with the reason: a run is counted whole or listed, never half-counted.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import sys
import zlib
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from edr.store.checkpoints import progress_text
from edr.store.folders import holder_alive
from edr.store.identity import flatten
from edr.store.records import INTERRUPTED, RECORD_NAME, regular_file_bytes, run_status

# What must match for runs to be averaged into one number.
CELL_KEYS = ["cell", "data.fingerprint", "data.source", "scale"]
# Columns every frame has, even with no records (or only records from before the store).
BASE_COLUMNS = ["record", "run_dir", "task", "status", "error", "fingerprint", "seed", "git",
                "machine", "ended_at", *CELL_KEYS]  # fmt: skip


# The files beside a record that a table or figure reads, and the tasks whose finished runs must
# have them; each is read only if it lies inside its run folder.
PREDICTIONS = "predictions.json"  # per-video test predictions (edr.tasks.predictions)
CONFUSION, PIXEL_RESPONSE = "confusion.json", "pixel_response.png"
# A run's history, a row per log: new Atari runs store it gzip-compressed, older runs and the
# recognition tasks as plain JSON; the first of these a run has is read.
HISTORIES = ("history.json.gz", "history.json")
REQUIRED_FILES = {"dvs_transfer": (CONFUSION,), "representation_demo": (PIXEL_RESPONSE,)}
MAPPINGS = ("data", "choices", "metrics", "machine", "config", "semantic_config")
# The most bytes a file the tables read may hold (a record, else a history or confusion): memory
# stays bounded by what they read (a 24 MB record of 10^6 metrics took 4 GB and a minute)
MAX_BYTES = {RECORD_NAME: 4 << 20}
MAX_OTHER_BYTES = 64 << 20  # a 5M-step Atari run's history is 2 MB
MAX_FIELDS = 10_000  # the values a record's mappings may hold (a run writes a few hundred)
# Where a finished run records that its training diverged: its accuracy is NaN by design
DIVERGED_AT = "train/diverged_step"
STRINGS = ("task", "status", "error", "fingerprint", "cell", "scale", "git", "ended_at")


class BadRecord(ValueError):
    """A record, or a file it names, that a table cannot use; the message says why."""


def run_file(run_dir: Path, name: str) -> Path | None:
    """``run_dir/name`` if it is a file inside ``run_dir`` (a link may not leave the folder);
    None if there is none; :class:`BadRecord` otherwise."""
    path = run_dir / name
    if not path.is_symlink() and not path.exists():
        return None
    try:
        real = path.resolve(strict=True)
    except (OSError, RuntimeError) as error:  # a dangling link or a loop
        raise BadRecord(f"{name}: {error}") from None
    if not real.is_relative_to(run_dir.resolve()):
        raise BadRecord(f"{name} links outside its run folder (to {real}): not read")
    if not real.is_file():
        raise BadRecord(f"{name} is not a file")
    return real


def read_json(path: Path) -> Any:
    """The JSON in ``path`` (gzip-compressed where its name ends in ``.gz``); :class:`BadRecord`
    naming the file for bytes that are not UTF-8 or not gzip, text that is not JSON, JSON nested
    past Python's recursion limit, or more bytes than a file of its name holds (:data:`MAX_BYTES`:
    refused before it is read, and a compressed file's text past it is never inflated)."""
    limit = MAX_BYTES.get(path.name, MAX_OTHER_BYTES)
    try:
        if (size := path.stat().st_size) > limit:
            raise BadRecord(
                f"{path.name} is {size / 2**20:.1f} MiB, more than the {limit >> 20} MiB such a "
                "file holds: not read"
            )
        raw = regular_file_bytes(path)
        if path.name.endswith(".gz"):
            inflater = zlib.decompressobj(wbits=31)  # gzip's header and trailer
            raw = inflater.decompress(raw, limit + 1)
            if len(raw) > limit:
                raise BadRecord(f"{path.name} inflates to more than {limit >> 20} MiB: not read")
            if not inflater.eof:
                raise BadRecord(f"{path.name} is not gzip-compressed whole")
        return json.loads(raw.decode())
    except (EOFError, zlib.error):
        raise BadRecord(f"{path.name} is not gzip-compressed whole") from None
    except UnicodeDecodeError:
        raise BadRecord(f"{path.name} is not UTF-8 text") from None
    except RecursionError:
        raise BadRecord(f"{path.name} is nested too deeply") from None
    except OSError as error:  # a folder, a pipe, a link loop
        raise BadRecord(f"{path.name} cannot be read ({error.strerror})") from None
    except ValueError as error:
        raise BadRecord(f"{path.name} is not JSON ({error})") from None


def run_json(run_dir: Path, name: str) -> Any:
    """The JSON file ``name`` of a run (None if it has none), read only inside its folder."""
    path = run_file(run_dir, name)
    return None if path is None else read_json(path)


def _check_files(run_dir: Path, record: dict[str, Any]) -> None:
    """The files beside a record that tables read: present where its task needs them, inside
    its folder, and of the shape the tables read."""
    if record.get("status") == "finished":
        for name in REQUIRED_FILES.get(str(record.get("task")), ()):
            if run_file(run_dir, name) is None:
                raise BadRecord(f"finished, but its {name} is missing")
    run_file(run_dir, PIXEL_RESPONSE)
    name = next((n for n in HISTORIES if run_file(run_dir, n) is not None), None)
    history = run_json(run_dir, name) if name else None
    if history is not None and not (
        isinstance(history, list) and all(isinstance(row, dict) for row in history)
    ):
        raise BadRecord(f"{name} is not a list of rows")
    confusion = run_json(run_dir, CONFUSION)
    if confusion is not None and not (
        isinstance(confusion, dict) and {"matrix", "classes"} <= confusion.keys()
    ):
        raise BadRecord(f"{CONFUSION} has no matrix and classes")
    predictions = run_json(run_dir, PREDICTIONS)
    entry = {"video", "person", "scenario", "true", "predicted", "items"}
    if predictions is not None and not (
        isinstance(predictions, dict)
        and isinstance(predictions.get("videos"), list)
        and all(isinstance(v, dict) and entry <= v.keys() for v in predictions["videos"])
    ):
        raise BadRecord(
            f"{PREDICTIONS} has no list of videos, each with {', '.join(sorted(entry))}"
        )


def check_record(record: Any) -> dict[str, Any]:
    """``record`` if its fields have the types tables read; :class:`BadRecord` naming the first
    that does not."""
    if not isinstance(record, dict):
        raise BadRecord(f"holds a JSON {type(record).__name__}, not a run record")
    for key in MAPPINGS:
        if not isinstance(record.get(key, {}), dict):
            raise BadRecord(f"`{key}` is a {type(record[key]).__name__}, not a mapping")
    for key in STRINGS:
        if not isinstance(record.get(key), str | None):
            raise BadRecord(f"`{key}` is a {type(record[key]).__name__}, not a string")
    for key in ("data", "choices", "metrics"):
        nested = [k for k, v in record.get(key, {}).items() if not isinstance(v, Scalar)]
        if nested:
            raise BadRecord(f"`{key}` holds values that are not scalars: {nested}")
    if wrong := _not_numbers(record.get("metrics", {})):
        raise BadRecord(f"`metrics` holds values that are not numbers: {wrong}")
    seed = record.get("seed", record.get("config", {}).get("seed"))
    if seed is not None and (not isinstance(seed, int) or isinstance(seed, bool)):
        raise BadRecord(f"seed {seed!r} is not an integer")
    if record.get("status") == "finished" and "metrics" not in record:
        raise BadRecord("finished, but has no metrics")
    fields = sum(len(flatten(record.get(key, {}))) for key in MAPPINGS)
    if fields > MAX_FIELDS:
        raise BadRecord(f"holds {fields:,} values, more than the {MAX_FIELDS:,} a record holds")
    return record


def uncountable(record: dict[str, Any]) -> str | None:
    """Why a finished ``record`` cannot count in a table, or None: no fingerprint or cell (no
    table could tell it from another run), an infinite metric, or a NaN ``eval/`` metric of a
    run that records no divergence (``train/diverged_step``); averaging it would count it as a
    run and leave it out of the mean. A run that records one is a result (the learnable-EDR
    block counts it apart); a table that averages its NaN metric lists it (:func:`placeable`)."""
    for key in ("fingerprint", "cell"):
        if not record.get(key):
            return f"finished, but has no {key}: no table can tell it from another run"
    metrics = record.get("metrics", {})
    for name, value in metrics.items():
        if not isinstance(value, float) or math.isfinite(value):
            continue
        if math.isinf(value) or (name.startswith("eval/") and DIVERGED_AT not in metrics):
            return f"metrics {name} is {value}, not a measurement"
    return None


Scalar = int | float | bool | str | None
# The metrics that are words (the run's settings as it ran them, the files of a figure, why a
# run or its pre-training diverged); every other metric is a number a table reads, and a float's
# range holds it.
TEXT_METRICS = ("train/precision", "eval/network_mode", "eval/policy", "figure/",
                "train/diverged_reason", "pretrain/train/diverged_reason")  # fmt: skip


def _not_numbers(metrics: dict[str, Any]) -> list[str]:
    """The metrics of ``metrics`` that should be numbers and are not (text, or an integer past
    float's range)."""

    def number(value: Any) -> bool:
        if isinstance(value, int) and not isinstance(value, bool):
            return abs(value) <= sys.float_info.max
        return value is None or isinstance(value, float | bool)

    return [k for k, v in metrics.items() if not k.startswith(TEXT_METRICS) and not number(v)]


def _machine(record: dict[str, Any]) -> str:
    m = record.get("machine", {})
    return f"{m.get('cpu', '?')} ({m.get('cpu_count', '?')} cores), GPU: {m.get('gpu') or 'none'}"


def _shown(path: Path) -> str:
    """``path`` relative to the working directory where it lies under it (tables name records
    that way, so that a committed table does not carry one machine's absolute paths)."""
    return str(path.relative_to(Path.cwd())) if path.is_relative_to(Path.cwd()) else str(path)


def _status(path: Path, record: dict[str, Any]) -> str:
    """The record's status (:func:`run_status`: a record of a run Ctrl-C or SIGTERM stopped,
    old or new, is ``interrupted``: it did not fail, it resumes); ``running`` only while a live
    process holds its folder (a run killed by the OOM killer or a full disk leaves ``running``
    behind: it is ``interrupted``)."""
    status = run_status(record)
    return INTERRUPTED if status == "running" and not holder_alive(path.parent) else status


def _error(record: dict[str, Any]) -> Any:
    """The record's error; for a run that Ctrl-C or SIGTERM stopped, where running it again
    resumes from (its checkpoint's counters, ``env_steps 65,600``), or that it starts over."""
    if run_status(record) != INTERRUPTED:
        return record.get("error")
    resumes = record.get("resumes_from")
    if not isinstance(resumes, dict):
        return "stopped by Ctrl-C or SIGTERM, no checkpoint: running it again starts over"
    counters = progress_text(resumes) or "its checkpoint"
    return f"stopped by Ctrl-C or SIGTERM: running it again resumes from {counters}"


def _row(path: Path, record: dict[str, Any]) -> dict[str, Any]:
    row: dict[str, Any] = {
        "record": _shown(path),
        "run_dir": _shown(path.parent),
        "task": record.get("task"),
        "status": _status(path, record),
        "error": _error(record),
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


def _holds_records(link: Path) -> bool:
    """Whether ``link`` is a symbolic link to a folder with a run record in it."""
    try:
        return link.is_symlink() and next(link.rglob(RECORD_NAME), None) is not None
    except OSError:  # a link loop
        return False


def _find(root: Path) -> tuple[list[Path], list[dict[str, Any]]]:
    """(every ``run.json`` under ``root`` that is a file, no link; a row for each link among
    them and each linked folder that holds records: those are not followed, and said so)."""
    records, links, folders = [], [], []
    for folder, dirs, files in os.walk(root):
        here = Path(folder)
        links += [here / name for name in dirs if _holds_records(here / name)]
        folders += [here / name for name in dirs if name == RECORD_NAME]
        if RECORD_NAME in files:
            (links if (here / RECORD_NAME).is_symlink() else records).append(here / RECORD_NAME)
    skipped = [
        {"record": _shown(link), "status": "unreadable",
         "error": f"a symbolic link (to {os.path.realpath(link)}): not followed; pass its "
                  "target with --runs to read it"}
        for link in links
    ] + [
        {"record": _shown(folder), "status": "unreadable",
         "error": "a folder named run.json: a run's record is a file"}
        for folder in folders
    ]  # fmt: skip
    return records, skipped


def _read(path: Path) -> dict[str, Any]:
    """The table row of the record at ``path``; a row saying why for one that cannot be used."""
    try:
        record = check_record(read_json(path))
        if record.get("status") == "finished" and not isinstance(record.get("data"), dict):
            raise BadRecord("finished, but without its data part: no table can say what it ran on")
        _check_files(path.parent, record)
        row = _row(path, record)
        if row["status"] == "finished" and (reason := uncountable(record)):
            row.update(status="not counted", error=reason)
        return row
    except BadRecord as error:
        return {"record": _shown(path), "status": "unreadable", "error": str(error)}
    except RecursionError:
        return {"record": _shown(path), "status": "unreadable", "error": "nested too deeply"}


def load_runs(roots: Iterable[str | Path]) -> pd.DataFrame:
    """Every ``run.json`` under ``roots`` (searched recursively, links not followed), one row
    each, oldest first; a record that cannot be used is a row of status ``unreadable`` with the
    reason in ``error``."""
    found = [_find(Path(root)) for root in roots]
    paths = sorted({p.resolve() for records, _ in found for p in records})
    rows = [_read(path) for path in paths] + [row for _, links in found for row in links]
    # oldest first by the record's own end time, not the file's (a clone resets mtimes), so the
    # same records render the same tables on any checkout
    frame = pd.DataFrame(rows)
    if "ended_at" in frame:
        frame = frame.sort_values(["ended_at", "record"], na_position="first", kind="stable")
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


def displaced(runs: pd.DataFrame) -> list[str]:
    """One line per run found in several records (one fingerprint, several folders: a sweep's
    copy and a committed one, say): which record the tables take (the newest, as
    :func:`finished` does) and which they leave out."""
    if runs.empty:
        return []
    done = runs[runs["status"] == "finished"]
    lines = []
    for fingerprint, group in done.groupby("fingerprint", sort=False):
        if len(group) > 1:
            kept, *left = reversed(group["record"].tolist())
            lines.append(
                f"run {str(fingerprint)[:12]} has {len(group)} records: the tables take the "
                f"newest, {kept}; left out: {', '.join(left)}"
            )
    return lines


def _diverged_reasons(done: pd.DataFrame, averaged: str) -> pd.Series:
    """Per run of ``done``, why it cannot count in a mean of ``averaged`` (a ``metrics.``
    column): it diverged (``train/diverged_step``), so it has no number for it by design; None
    for the others."""
    absent = pd.Series(float("nan"), index=done.index)
    value = pd.to_numeric(done.get(averaged, absent), errors="coerce")
    step = pd.to_numeric(done.get(f"metrics.{DIVERGED_AT}", absent), errors="coerce")
    why = done.get("metrics.train/diverged_reason", absent)
    name = averaged.removeprefix("metrics.")
    return pd.Series(
        [
            f"diverged at step {s:,.0f}" + (f", {w}" if isinstance(w, str) else "")
            + f": no {name} to average, so not counted as a run"
            if pd.notna(s) and pd.isna(v) else None
            for v, s, w in zip(value, step, why, strict=True)
        ],
        index=done.index,
        dtype=object,
    )  # fmt: skip


def placeable(
    done: pd.DataFrame, labels: Sequence[str], averaged: str | None = None
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(the runs that have every one of a table's ``labels`` and, where the table names the
    metric its rows average (``averaged``), a number for it; the others as rows to list: ``not
    placed`` naming what they lack (a record from before a field existed gets no ``nan`` row),
    ``not counted`` for a run that diverged (counted as a run, it would be left out of the
    mean: :func:`_diverged_reasons`))."""
    if done.empty:
        return done, done
    missing = done.reindex(columns=list(labels)).isna()
    lacking = missing.any(axis=1)
    unplaced = done[lacking].assign(
        status="not placed",
        error=[
            "finished, but lacks " + ", ".join(c for c in labels if row[c]) + ", which the "
            "table's rows are by"
            for _, row in missing[lacking].iterrows()
        ],
    )
    placed = done[~lacking]
    if averaged is None or placed.empty:
        return placed, unplaced
    reasons = _diverged_reasons(placed, averaged)
    apart = reasons.notna()
    uncounted = placed[apart].assign(status="not counted", error=reasons[apart])
    listed = [part for part in (unplaced, uncounted) if not part.empty]
    return placed[~apart], pd.concat(listed) if listed else unplaced


def unfinished(runs: pd.DataFrame, task: str, unplaced: pd.DataFrame | None = None) -> pd.DataFrame:
    """The runs of ``task`` that are not finished (failed, running, legacy), those a table
    could not place (:func:`placeable`), and every record that could not be read (whose task
    nobody knows): to list under a table, not average."""
    if runs.empty:
        return runs
    mine = (runs["task"] == task) & (runs["status"] != "finished")
    listed = runs[mine | (runs["status"] == "unreadable")]
    return listed if unplaced is None or unplaced.empty else pd.concat([unplaced, listed])


def cells(runs: pd.DataFrame, metrics: Sequence[str], labels: Sequence[str]) -> pd.DataFrame:
    """One row per cell: ``labels`` (taken from its runs), each metric's mean, std and the runs
    behind it (``runs``, ``seeds``, ``records``, ``machines``, ``gits``)."""
    columns = [*labels, *CELL_KEYS]
    out = []
    for _, group in runs.groupby(CELL_KEYS, dropna=False, sort=False):
        row = {label: group[label].iloc[0] for label in labels}
        row.update({key: group[key].iloc[0] for key in CELL_KEYS})
        for metric in metrics:
            values = pd.to_numeric(group.get(metric, pd.Series(index=group.index)), errors="coerce")
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


def run_attempts(record: str) -> list[dict[str, Any]]:
    """The lines of a run's ``attempts.jsonl`` (beside its record): each attempt's outcome and
    the fingerprint it ran under; none where it has no such file or a line does not read. Of
    a file past :data:`MAX_OTHER_BYTES`, its last attempts only (it is appended to)."""
    path = Path(record).parent / "attempts.jsonl"
    if not path.is_file():  # none, or a named pipe, whose read would block
        return []
    try:
        with path.open("rb") as f:
            size = f.seek(0, os.SEEK_END)
            f.seek(max(size - MAX_OTHER_BYTES, 0))
            text = f.read().decode(errors="replace")
    except OSError:
        return []
    lines = text.splitlines()[1 if size > MAX_OTHER_BYTES else 0 :]  # the first may be cut
    found = []
    for line in lines:
        with contextlib.suppress(json.JSONDecodeError):
            entry = json.loads(line)
            if isinstance(entry, dict):
                found.append(entry)
    return found


def read_history(run_dir: Path) -> list[dict[str, Any]]:
    """The rows of the run's history in ``run_dir`` (:data:`HISTORIES`); none if it has none."""
    name = next((n for n in HISTORIES if run_file(run_dir, n) is not None), None)
    return (run_json(run_dir, name) if name else None) or []


def run_history(record: str) -> list[dict[str, Any]]:
    """The rows of a run's history (beside its record); none if it has none."""
    return read_history(Path(record).parent)
