"""Adversarial records, stores and tables (issue 36, cases 1, 2, 3, 5 and 7's records side; issue
38's plain ``edr-tables``): nothing a record names is imported without trust, no file a record
points at is read outside its run folder, every record ``edr-tables`` cannot use is listed with
the reason while the rest render, and each way a run or a sweep ends says so in one place."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
from contextlib import redirect_stdout
from pathlib import Path
from typing import Any

import pytest

from edr import tables
from edr.rebuild import UntrustedRecord
from edr.report.runs import load_runs
from edr.tasks.atari import evaluate_checkpoint

ROOT = Path(__file__).resolve().parents[1]


# ---- tiny records -------------------------------------------------------------------------------
def _record(task: str = "kth", seed: Any = 0, **fields: Any) -> dict[str, Any]:
    """A finished record of ``task`` as ``edr-run`` writes one, small."""
    record = {
        "status": "finished", "task": task, "fingerprint": f"{task}-{seed}", "cell": f"{task}-cell",
        "seed": seed, "scale": "tiny", "git": "abc", "ended_at": "2026-12-02T10:00:00+0000",
        "machine": {"cpu": "test CPU", "cpu_count": 2, "gpu": None},
        "data": {"source": "generated", "fingerprint": "d1"},
        "choices": {"backbone": "lenet_ftrcn", "representation": "edr", "ablation": "None"},
        "config": {"seed": seed},
        "metrics": {"eval/accuracy": 0.5, "eval/chance": 1 / 6},
    }  # fmt: skip
    return {**record, **fields}


def _write(folder: Path, record: Any, text: str | bytes | None = None) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "run.json"
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text if text is not None else json.dumps(record))
    return folder


def _render(runs: Path, out: Path, *extra: str) -> str:
    """``edr-tables --runs runs --out out`` (it must not exit); what it printed."""
    printed = io.StringIO()
    with redirect_stdout(printed):
        tables.main(["--runs", str(runs), "--out", str(out), *extra])
    return printed.getvalue()


# ---- case 7 and case 2: every record edr-tables cannot use is listed, the rest render ----------
def _nested(depth: int) -> str:
    return "[" * depth + "]" * depth


BAD_RECORDS = {
    "a JSON list": (None, "[1, 2]", "holds a JSON list"),
    "data a string": (_record(data="oops"), None, "`data` is a str"),
    "machine a list": (_record(machine=[1]), None, "`machine` is a list"),
    "metrics a number": (_record(metrics=3), None, "`metrics` is a int"),
    "metrics nested": (_record(metrics={"a": {"b": 1}}), None, "not scalars"),
    "invalid UTF-8": (None, b'{"status": "fini\xff\xfe"}', "not UTF-8"),
    "deeply nested": (None, _nested(100_000), "nested too deeply"),
    "seed abc": (_record(seed="abc"), None, "seed 'abc' is not an integer"),
    "finished without metrics": (
        {k: v for k, v in _record().items() if k != "metrics"}, None, "has no metrics"),
}  # fmt: skip


@pytest.mark.parametrize("case", list(BAD_RECORDS))
def test_an_unusable_record_is_listed_with_the_reason_and_the_rest_render(case, tmp_path) -> None:
    record, text, reason = BAD_RECORDS[case]
    runs = tmp_path / "runs"
    _write(runs / "good", _record())
    _write(runs / "bad", record, text)
    printed = _render(runs, tmp_path / "out")
    table = (tmp_path / "out" / "table4_kth.md").read_text()
    assert "| lenet_ftrcn" in table and "good/run.json" in table  # the good record renders
    (line,) = [line for line in table.splitlines() if "bad/run.json" in line]
    assert "unreadable" in line and reason in line, line
    assert reason in printed


SIDE_FILES = {
    "truncated history.json": ("kth", "history.json", '[{"epoch": 1', "history.json is not JSON"),
    "history.json a mapping": ("kth", "history.json", '{"a": 1}', "not a list of rows"),
    "missing confusion.json": ("dvs_transfer", None, None, "confusion.json is missing"),
    "missing pixel_response.png": (
        "representation_demo", None, None, "pixel_response.png is missing"),
    "confusion.json without a matrix": (
        "dvs_transfer", "confusion.json", '{"classes": []}', "no matrix and classes"),
}  # fmt: skip


@pytest.mark.parametrize("case", list(SIDE_FILES))
def test_a_broken_or_missing_file_beside_a_record_is_listed(case, tmp_path) -> None:
    task, name, content, reason = SIDE_FILES[case]
    runs = tmp_path / "runs"
    _write(runs / "good", _record())
    bad = _write(runs / "bad", _record(task, data={"source": "generated", "fingerprint": "d",
                                                   "events": "x"}))  # fmt: skip
    if name:
        (bad / name).write_text(content)
    printed = _render(runs, tmp_path / "out")
    assert reason in printed
    (row,) = load_runs([runs]).query("status == 'unreadable'").itertuples()
    assert reason in row.error


# ---- case 3: no file a record points at is read outside its run folder -------------------------
@pytest.mark.parametrize("name", ["pixel_response.png", "history.json", "confusion.json"])
def test_a_file_linked_outside_its_run_folder_is_not_read(name, tmp_path) -> None:
    secret = tmp_path / "secret.txt"
    secret.write_text('[{"epoch": 1, "secret": "leaked"}]')
    runs = tmp_path / "runs"
    demo = _write(runs / "demo", _record("representation_demo"))
    (demo / "pixel_response.png").write_bytes(b"\x89PNG")
    (demo / name).unlink(missing_ok=True)
    (demo / name).symlink_to(secret)
    printed = _render(runs, tmp_path / "out")
    assert f"{name} links outside its run folder" in printed
    figures = tmp_path / "out" / "figures"
    copied = [p for p in figures.glob("*")] if figures.exists() else []
    assert not any(b"leaked" in p.read_bytes() for p in copied)


# ---- case 2: run folders reached through a link are said, not silently skipped -----------------
def test_a_linked_run_folder_is_listed_not_silently_skipped(tmp_path) -> None:
    elsewhere = _write(tmp_path / "elsewhere" / "one", _record(seed=1)).parent
    runs = tmp_path / "runs"
    _write(runs / "good", _record())
    (runs / "linked").symlink_to(elsewhere, target_is_directory=True)
    printed = _render(runs, tmp_path / "out")
    assert "linked: a symbolic link" in printed
    assert (
        "linked`: unreadable (a symbolic link" in (tmp_path / "out" / "table4_kth.md").read_text()
    )


# ---- case 2 and 7: published.yaml of the wrong shape is refused in one line ---------------------
BAD_PUBLISHED = {
    "a list": ("- 1\n- 2\n", "holds a list, not a mapping"),
    "a number as a string": (
        "table4_kth:\n  accuracy:\n    lenet_ftrcn: {edr: '88.9'}\n", "'88.9', not a number"),
    "a section that is a list": ("table2_ucf101: [1, 2]\n", "table2_ucf101 is a list"),
    "notes not strings": ("table1_atari:\n  notes: [1]\n", "notes is not a list of strings"),
}  # fmt: skip


@pytest.mark.parametrize("case", list(BAD_PUBLISHED))
def test_a_published_file_of_the_wrong_shape_is_refused_in_one_line(case, tmp_path, capsys):
    text, message = BAD_PUBLISHED[case]
    (tmp_path / "published.yaml").write_text(text)
    _write(tmp_path / "runs" / "good", _record())
    with pytest.raises(SystemExit) as exit_:
        tables.main(["--runs", str(tmp_path / "runs"), "--out", str(tmp_path / "out"),
                     "--published", str(tmp_path / "published.yaml")])  # fmt: skip
    error = capsys.readouterr().err
    assert exit_.value.code == 2 and message in error and error.count("\n") == 1, error
    assert not (tmp_path / "out").exists()  # refused before anything is written


# ---- case 7: a bad bench record is listed, the newest good one renders ----------------------------
@pytest.mark.parametrize("text", ["[1]", '{"kind": "speed", "rows": 3}', "{trunc", '{"rows": []}'])
def test_a_bad_bench_record_is_listed_and_an_older_good_one_renders(text, tmp_path) -> None:
    bench = tmp_path / "bench"
    bench.mkdir()
    good = sorted((ROOT / "results" / "bench").glob("speed_*.json"))[-1]
    (bench / good.name).write_text(good.read_text())
    (bench / "speed_zz_bad.json").write_text(text)
    _write(tmp_path / "runs" / "good", _record())
    printed = _render(tmp_path / "runs", tmp_path / "out", "--bench", str(bench))
    assert "speed_zz_bad.json" in printed
    assert good.name in (tmp_path / "out" / "table2_speed.md").read_text()


# ---- case 1: no module a record names is imported without trust --------------------------------
ENV_FORMS = {
    "gymnasium's module:env id": {"env_id": "pwn_mod:Catch-v0", "env_module": None},
    "env_module": {"env_id": "Catch-v0", "env_module": "pwn_mod"},
    "module:env in the game": {"game": "pwn_mod:Catch"},
}


def _atari_record(tmp_path: Path, env: dict[str, Any]) -> Path:
    run_dir = tmp_path / "downloaded"
    record = {
        "seed": 0,
        "config": {"task": {
            "_target_": "edr.tasks.atari.train_paac", "_partial_": True,
            "env": {"_target_": "edr.rl.settings.EnvSettings", "preset": "none", **env},
        }},
    }  # fmt: skip
    _write(run_dir, record)
    (run_dir / "checkpoint.pt").write_bytes(b"")
    (tmp_path / "pwn_mod.py").write_text(
        "import pathlib\npathlib.Path(__file__).with_name('PWNED').write_text('ran')\n"
    )
    return run_dir


@pytest.mark.parametrize("form", list(ENV_FORMS))
def test_no_module_a_record_names_is_imported_without_trust(form, tmp_path) -> None:
    run_dir = _atari_record(tmp_path, ENV_FORMS[form])
    result = subprocess.run(
        [sys.executable, "-m", "edr.tasks.atari", str(run_dir)], cwd=tmp_path,
        capture_output=True, text=True, timeout=120,
        env={**os.environ, "PYTHONPATH": str(ROOT / "src")},
    )  # fmt: skip
    assert result.returncode == 2, result.stderr[-2000:]
    assert "pwn_mod" in result.stderr and "--trust-env-module" in result.stderr
    assert result.stderr.count("\n") == 1
    assert not (tmp_path / "PWNED").exists()


def test_the_trust_check_comes_before_any_env_is_made(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    run_dir = _atari_record(tmp_path, ENV_FORMS["gymnasium's module:env id"])
    with pytest.raises(UntrustedRecord, match="pwn_mod"):
        evaluate_checkpoint(run_dir)
    assert "pwn_mod" not in sys.modules and not (tmp_path / "PWNED").exists()


# ---- issue 38: plain edr-tables renders the committed scope or an explicit folder, never a mix ---
def test_plain_edr_tables_where_there_are_no_records_says_so_and_exits_2(
    tmp_path, monkeypatch, capsys
) -> None:
    monkeypatch.chdir(tmp_path)
    _write(tmp_path / "results" / "runs" / "kth" / "mine", _record())  # a user's run: not paper/'s
    with pytest.raises(SystemExit) as exit_:
        tables.main([])
    error = capsys.readouterr().err
    assert exit_.value.code == 2 and "no records found under results/learning/" in error
    assert error.count("\n") == 1 and not (tmp_path / "paper").exists()


def test_plain_edr_tables_with_part_of_the_committed_scope_refuses(
    tmp_path, monkeypatch, capsys
) -> None:
    monkeypatch.chdir(tmp_path)
    for folder in tables.COMMITTED_SCOPE[:-1]:
        _write(folder / "one", _record())
    with pytest.raises(SystemExit) as exit_:
        tables.main([])
    error = capsys.readouterr().err
    assert exit_.value.code == 2 and "results/sweeps/tiny/demo not found: `make paper`" in error
    assert not (tmp_path / "paper").exists()


def test_the_committed_scope_renders_into_paper_and_nothing_else(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    for folder in tables.COMMITTED_SCOPE:
        _write(folder / "one", _record(fingerprint=str(folder)))
    _write(tmp_path / "results" / "runs" / "kth" / "mine", _record(seed=5))  # not in the scope
    tables.main([])
    table = (tmp_path / "paper" / "table4_kth.md").read_text()
    assert "results/learning/table1_pong/one/run.json" in table
    assert "results/runs" not in table  # no mix


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--runs", "{tmp}/runs"], "--runs needs --out"),
        (["--runs", "{tmp}/empty", "--out", "{tmp}/out"], "no records found under {tmp}/empty"),
    ],
)
def test_explicit_folders_refuse_in_one_line(args, message, tmp_path, capsys) -> None:
    _write(tmp_path / "runs" / "good", _record())
    (tmp_path / "empty").mkdir()
    with pytest.raises(SystemExit) as exit_:
        tables.main([a.format(tmp=tmp_path) for a in args])
    error = capsys.readouterr().err
    assert exit_.value.code == 2 and message.format(tmp=tmp_path) in error
    assert error.count("\n") == 1 and not (tmp_path / "out").exists()


def test_a_record_lacking_the_fields_a_table_groups_by_is_listed_not_a_nan_row(tmp_path) -> None:
    env = {"game": "Pong", "inputs": "fdr"}
    runs = tmp_path / "runs"
    metrics = {"eval/mean": 1.0, "eval/max": 2.0, "eval/min": 0.0, "eval/plays": 2}
    for name, config_env in (("new", env), ("old", {})):
        _write(runs / name, _record("atari", fingerprint=name, metrics=metrics,
                                    data={"source": "emulator"},
                                    config={"seed": 0, "task": {"env": config_env}}))  # fmt: skip
    _render(runs, tmp_path / "out")
    table = (tmp_path / "out" / "table1_atari.md").read_text()
    assert "nan" not in table
    (line,) = [line for line in table.splitlines() if "old/run.json`:" in line]
    assert "not placed (finished, but lacks game, input" in line
