"""Hostile records, inputs and sweeps for the tables (issue 71): a record that cannot count is
listed with its path and reason, never half-counted (counted as a run, left out of the mean);
missing inputs are named in one line; what a table reads is bounded; a sweep counts each job once."""

from __future__ import annotations

import io
import json
import logging
import os
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path
from typing import Any

import pytest

from edr import tables
from edr.report import runs as runs_module
from edr.report.recognition import table2_ucf101, table4_kth
from edr.report.render import to_markdown
from edr.report.runs import load_runs
from edr.store import folders
from test_adversarial_records import _write  # a folder holding one run.json


def _record(seed: int = 0, accuracy: Any = 0.5, **fields: Any) -> dict[str, Any]:
    """A finished KTH record as ``edr-run`` writes one, small."""
    record = {
        "status": "finished", "task": "kth", "fingerprint": f"kth-{seed}", "cell": "kth-cell",
        "seed": seed, "scale": "tiny", "git": "abc", "ended_at": f"2026-12-02T10:00:0{seed}+0000",
        "machine": {"cpu": "test CPU", "cpu_count": 2, "gpu": None},
        "data": {"source": "generated", "fingerprint": "d1"},
        "choices": {"backbone": "lenet_ftrcn", "representation": "edr", "ablation": "None"},
        "config": {"seed": seed},
        "metrics": {"eval/accuracy": accuracy, "eval/chance": 1 / 6},
    }  # fmt: skip
    return {**record, **fields}


def _without(key: str) -> dict[str, Any]:
    record = _record(2)
    del record[key]
    return record


def _fifo(folder: Path) -> None:
    folder.mkdir(parents=True)
    os.mkfifo(folder / "run.json")


def _big_history(folder: Path, monkeypatch) -> None:
    monkeypatch.setattr(runs_module, "MAX_OTHER_BYTES", 1 << 10)
    _write(folder, _record(2))
    (folder / "history.json").write_text(json.dumps([{"epoch": i} for i in range(200)]))


# (how the third record is made, its status, what its listing says): two good ones beside it
HOSTILE_RECORDS: dict[str, tuple[Any, str, str]] = {
    "accuracy NaN": (_record(2, float("nan")), "not counted", "eval/accuracy is nan"),
    "accuracy inf": (_record(2, float("inf")), "not counted", "eval/accuracy is inf"),
    "accuracy -inf": (_record(2, float("-inf")), "not counted", "eval/accuracy is -inf"),
    "accuracy 1e999 as written": (
        json.dumps(_record(2, 0.25)).replace("0.25", "1e999"),
        "not counted",
        "is inf",
    ),
    "chance NaN": (
        _record(2, metrics={"eval/accuracy": 0.5, "eval/chance": float("nan")}),
        "not counted",
        "eval/chance is nan",
    ),
    "an infinite training metric": (
        _record(2, metrics={"eval/accuracy": 0.5, "train/loss": float("inf")}),
        "not counted",
        "train/loss is inf",
    ),
    "no fingerprint": (_without("fingerprint"), "not counted", "has no fingerprint"),
    "an empty fingerprint": (_record(2, fingerprint=""), "not counted", "has no fingerprint"),
    "no cell": (_without("cell"), "not counted", "has no cell"),
    "accuracy as text": (_record(2, "0.9"), "unreadable", "not numbers: ['eval/accuracy']"),
    "accuracy a list": (_record(2, [0.9]), "unreadable", "not scalars: ['eval/accuracy']"),
    "accuracy a mapping": (_record(2, {"mean": 0.9}), "unreadable", "not scalars"),
    "accuracy an integer past float": (_record(2, 10**400), "unreadable", "not numbers"),
    "metrics a list": (_record(2, metrics=[0.5]), "unreadable", "`metrics` is a list"),
    "seed a float": ({**_record(2), "seed": 0.5}, "unreadable", "seed 0.5 is not an integer"),
    "seed text": ({**_record(2), "seed": "zero"}, "unreadable", "seed 'zero' is not an integer"),
    "status a number": (_record(2, status=1), "unreadable", "`status` is a int"),
    "a record of 20,000 metrics": (
        _record(2, metrics={f"eval/m{i}": 0.5 for i in range(20_000)}),
        "unreadable",
        "values, more than the 10,000 a record holds",
    ),
    "a record of 5 MiB": (
        json.dumps(_record(2)) + " " * (5 << 20),
        "unreadable",
        "run.json is 5.0 MiB, more than",
    ),
    "bytes that are not UTF-8": (b"\xff\xfe{}", "unreadable", "is not UTF-8"),
    "a record cut short": (json.dumps(_record(2))[:40], "unreadable", "is not JSON"),
    "a named pipe": (_fifo, "unreadable", "a named pipe"),
    "a history past its bound": (_big_history, "unreadable", "history.json is 0.0 MiB, more than"),
}


@pytest.mark.parametrize("case", HOSTILE_RECORDS)
def test_a_record_that_cannot_count_is_listed_never_half_counted(tmp_path, monkeypatch, case):
    """issue 71: a NaN accuracy was counted as a run but left out of the mean; inf printed as
    the cell; a record without fingerprint dropped silently; 24 MB of metrics took 4 GB."""
    make, status, reason = HOSTILE_RECORDS[case]
    _write(tmp_path / "a", _record(0, 0.4))
    _write(tmp_path / "b", _record(1, 0.6))
    bad = tmp_path / "c"
    if callable(make) and not isinstance(make, dict):
        make(bad, monkeypatch) if make is _big_history else make(bad)
    elif isinstance(make, str | bytes):
        _write(bad, None, text=make)
    else:
        _write(bad, make)
    found = load_runs([tmp_path])
    (row,) = found[found["record"].str.contains("/c/")].itertuples()
    assert row.status == status and reason in row.error, row.error
    assert "\n" not in row.error
    table = table4_kth(found, {})
    assert table.runs["seed"].tolist() == [0, 1]  # the two good runs, the whole mean
    assert table.frame["Runs (seeds)"].tolist() == ["2 (0, 1)"]
    assert table.frame["Accuracy (%)"].tolist() == ["50.0 ± 14.1"]
    markdown = to_markdown(table)
    assert f"c/run.json`: {status} (" in markdown and "inf" not in table.frame.to_string()


def test_a_run_that_records_its_divergence_keeps_its_nan_accuracy(tmp_path) -> None:
    """By design (the learnable-EDR block counts diverged runs apart): not refused."""
    record = _record(0, float("nan"))
    record["metrics"].update(
        {"train/diverged_step": 12, "train/diverged_reason": "the loss is nan"}
    )
    _write(tmp_path / "a", record)  # its reason, text, was read as a number: 'unreadable'
    assert load_runs([tmp_path])["status"].tolist() == ["finished"]


@pytest.mark.parametrize("task", ["kth", "ucf101"])
def test_a_diverged_run_is_listed_under_tables_2_and_4_not_counted_as_a_run(tmp_path, task):
    """issue 71: Tables 2 and 4 counted a run that diverged (accuracy NaN by design) in their
    runs but left it out of the mean; it is listed below the table with its step instead."""
    backbone = {"choices": {"backbone": "ltc", "representation": "edr", "ablation": "None"}}
    fields = {"task": task, **(backbone if task == "ucf101" else {})}
    diverged = _record(2, float("nan"), **fields)
    diverged["metrics"].update(
        {"train/diverged_step": 12, "train/diverged_reason": "the loss is nan"}
    )
    for name, record in (("a", _record(0, 0.4, **fields)), ("b", _record(1, 0.6, **fields)),
                         ("c", diverged)):  # fmt: skip
        _write(tmp_path / name, record)
    found = load_runs([tmp_path])
    table = table4_kth(found, {}) if task == "kth" else table2_ucf101(found, {}, None)
    assert table.frame["Runs (seeds)"].tolist() == ["2 (0, 1)"]
    assert table.frame["Accuracy (%)"].tolist() == ["50.0 ± 14.1"]
    assert table.runs["seed"].tolist() == [0, 1]
    (line,) = [line for line in to_markdown(table).splitlines() if "c/run.json" in line]
    assert line.endswith("c/run.json`: not counted (diverged at step 12, the loss is nan: no "
                         "eval/accuracy to average, so not counted as a run)")  # fmt: skip


def test_two_folders_of_one_run_count_it_once(tmp_path) -> None:
    """The same fingerprint and seed in two folders (a copy of a sweep): one run, the other
    named as left out."""
    _write(tmp_path / "sweep" / "a", _record(0, 0.4))
    _write(tmp_path / "copy" / "a", _record(0, 0.4))
    _write(tmp_path / "sweep" / "b", _record(1, 0.6))
    found = load_runs([tmp_path])
    table = table4_kth(found, {})
    assert table.frame["Runs (seeds)"].tolist() == ["2 (0, 1)"]
    (line,) = runs_module.displaced(found)
    assert "has 2 records" in line and "left out" in line


def test_a_linked_run_folder_is_listed_not_followed(tmp_path) -> None:
    _write(tmp_path / "elsewhere" / "a", _record(0))
    scope = tmp_path / "scope"
    _write(scope / "b", _record(1))
    (scope / "linked").symlink_to(tmp_path / "elsewhere")
    found = load_runs([scope])
    assert sorted(found["status"]) == ["finished", "unreadable"]
    assert "a symbolic link" in found.loc[found["status"] == "unreadable", "error"].iloc[0]


def _tables(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    code = 0
    with redirect_stdout(out), redirect_stderr(err):
        try:
            tables.main(list(argv))
        except SystemExit as stop:
            code = int(stop.code or 0)
    return code, out.getvalue(), err.getvalue()


@pytest.mark.parametrize(
    ("option", "make", "said"),
    [
        ("--bench", None, "--bench {}: no such folder; name an existing folder of edr-bench"),
        ("--bench", "file", "--bench {}: no such folder"),
        ("--published", None, "--published {}: no such file; name an existing file of published"),
    ],
)
def test_an_input_named_but_absent_is_refused_in_one_line(tmp_path, option, make, said) -> None:
    """issue 71: a missing --bench folder or published-numbers file was skipped without a word."""
    _write(tmp_path / "runs" / "a", _record(0))
    missing = tmp_path / "absent"
    if make == "file":
        missing.write_text("{}")
    code, _, err = _tables("--runs", str(tmp_path / "runs"), "--out", str(tmp_path / "out"),
                             option, str(missing))  # fmt: skip
    assert code == 2 and err.startswith(f"edr-tables: {said.format(missing)}"), err
    assert err.count("\n") == 1
    assert not (tmp_path / "out").exists()


def test_an_absent_default_input_is_one_line_and_the_tables_render(tmp_path, monkeypatch) -> None:
    _write(tmp_path / "runs" / "a", _record(0))
    _write(tmp_path / "runs" / "c", _record(2, float("nan")))
    monkeypatch.chdir(tmp_path)  # results/bench, the default, is not there
    monkeypatch.setattr(tables, "render_runs", lambda *args: {})  # what it says, not the tables
    code, out, _ = _tables("--runs", "runs", "--out", "out")
    assert code == 0
    assert "edr-tables: --bench results/bench (the default) is absent: rendered without" in out
    assert "runs/c/run.json: metrics eval/accuracy is nan, not a measurement" in out


# ---- a sweep's summary counts every job once --------------------------------------------------
def test_a_sweep_counts_a_cell_refused_after_its_attempt_once(tmp_path, monkeypatch, caplog):
    """issue 71: a cell whose task refused its data (crop=1) after its record was written was
    counted failed (its attempt) and refused (its one line): twice."""
    summary = folders.SweepSummary()
    summary.started, summary.sweep_dir, summary.sweep_id = 0.0, tmp_path, "s1"
    monkeypatch.setenv(folders.SWEEP_ID, "s1")
    for name, outcome in (("ran", "ran"), ("crop=1", "failed")):
        (tmp_path / name).mkdir()
        folders.log_attempt(tmp_path / name, outcome, "f")
    monkeypatch.setattr(folders, "refused_cells", [tmp_path / "crop=1", tmp_path / "seed=-1",
                                                   None])  # fmt: skip
    with caplog.at_level(logging.INFO, logger=folders.__name__):
        assert summary._say()
    assert caplog.messages[-1] == (
        f"sweep {tmp_path}: 0 skipped, 0 resumed, 1 ran, 1 failed, 0 interrupted, 2 refused"
    )


def test_a_runs_attempts_are_read_bounded_and_a_pipe_not_at_all(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(runs_module, "MAX_OTHER_BYTES", 200)
    record = _write(tmp_path / "a", _record(0)) / "run.json"
    lines = [json.dumps({"unix": i, "outcome": "ran", "fingerprint": "f"}) for i in range(50)]
    (tmp_path / "a" / "attempts.jsonl").write_text("\n".join(lines) + "\n")
    found = runs_module.run_attempts(str(record))
    assert 0 < len(found) < 5 and found[-1]["unix"] == 49
    os.mkfifo(tmp_path / "b.jsonl")
    (tmp_path / "a" / "attempts.jsonl").unlink()
    (tmp_path / "a" / "attempts.jsonl").symlink_to(tmp_path / "b.jsonl")
    assert runs_module.run_attempts(str(record)) == []


def test_a_refused_cell_is_known_by_its_folder_or_counted_alone(monkeypatch) -> None:
    from omegaconf import OmegaConf

    from edr.run import _folder_of

    monkeypatch.delenv("EDR_UNSET_FOR_TEST", raising=False)
    assert _folder_of(OmegaConf.create({"out_dir": "sweep/crop=1"})) == Path("sweep/crop=1")
    assert _folder_of(OmegaConf.create({"out_dir": "${oc.env:EDR_UNSET_FOR_TEST}"})) is None
    assert _folder_of(OmegaConf.create({})) is None
