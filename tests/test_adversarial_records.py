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

import edr
from edr import tables
from edr.report.runs import load_runs
from edr.tasks.atari import evaluate_checkpoint
from edr.tasks.rebuild import UntrustedRecord

ROOT = Path(__file__).resolve().parents[1]
SRC = str(Path(edr.__file__).resolve().parents[1])  # the edr these tests import, for subprocesses


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
    "predictions.json without its videos": (
        "kth", "predictions.json", '{"videos": [{"video": "v"}]}', "has no list of videos"),
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
@pytest.mark.parametrize(
    "name", ["pixel_response.png", "history.json", "confusion.json", "predictions.json"]
)
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


def test_a_record_or_bench_record_linked_from_outside_is_not_read(tmp_path) -> None:
    secret = tmp_path / "secret.json"
    secret.write_text(json.dumps(_record(seed=7, metrics={"eval/accuracy": 0.987654,
                                                         "eval/chance": 1 / 6})))  # fmt: skip
    runs = tmp_path / "runs"
    _write(runs / "good", _record())
    (runs / "linked").mkdir()
    (runs / "linked" / "run.json").symlink_to(secret)
    bench = tmp_path / "bench"
    bench.mkdir()
    (bench / "speed_zz_linked.json").symlink_to(secret)
    printed = _render(runs, tmp_path / "out", "--bench", str(bench))
    assert "98.8" not in (tmp_path / "out" / "table4_kth.md").read_text()
    assert "linked/run.json" in printed and "a symbolic link" in printed
    assert "speed_zz_linked.json" in printed and "links outside" in printed


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
    "EDR rows not settings": ("edr_rows:\n  settings: {edr: 3.8}\n", "edr_rows.settings is not"),
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
        "status": "finished", "seed": 0,
        "config": {"task": {
            "_target_": "edr.tasks.atari.train_paac", "_partial_": True,
            "env": {"_target_": "edr.rl.settings.EnvSettings", "preset": "none", **env},
            "network": {"_target_": "edr.rl.settings.NetworkSettings"},
            "evaluation": {"_target_": "edr.rl.settings.EvalSettings", "plays": 1},
        }},  # complete: without the check, evaluating it would make the env
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
        [sys.executable, "-m", "edr.evaluate", str(run_dir)], cwd=tmp_path,
        capture_output=True, text=True, timeout=120,
        env={**os.environ, "PYTHONPATH": SRC},
    )  # fmt: skip
    assert not (tmp_path / "PWNED").exists()  # the module's code did not run
    assert result.returncode == 2, result.stderr[-2000:]
    assert "pwn_mod" in result.stderr and "--trust-env-module" in result.stderr
    assert result.stderr.count("\n") == 1


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
        # issue 57: --out paper with --runs, a folder that is not there, one empty among good ones
        (["--runs", "{tmp}/nowhere", "--out", "{tmp}/out"], "--runs {tmp}/nowhere: no such folder"),
        (
            ["--runs", "{tmp}/runs", "--runs", "{tmp}/empty", "--out", "{tmp}/out"],
            "no records found under {tmp}/empty",
        ),
    ],
)
def test_explicit_folders_refuse_in_one_line(args, message, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # paper/, if anything wrote there, is this test's
    _write(tmp_path / "runs" / "good", _record())
    (tmp_path / "empty").mkdir()
    with pytest.raises(SystemExit) as exit_:
        tables.main([a.format(tmp=tmp_path) for a in args])
    error = capsys.readouterr().err
    assert exit_.value.code == 2 and message.format(tmp=tmp_path) in error
    assert error.count("\n") == 1 and not (tmp_path / "out").exists()
    assert not (tmp_path / "paper").exists()


@pytest.mark.parametrize(
    ("out", "cwd"),
    [("paper", "."), ("paper/sub", "."), ("{tmp}/paper", "."), ("{tmp}/paper", "elsewhere"),
     ("../paper", "src")],
)  # fmt: skip
def test_your_runs_never_go_into_the_projects_paper_folder(out, cwd, tmp_path, monkeypatch, capsys):
    """issue 57: `edr-tables --runs X --out paper` exited 0 and rewrote the committed tables; the
    refusal held only when run from the project's own folder."""
    (tmp_path / "src" / "edr").mkdir(parents=True)  # a checkout: paper/ beside the package
    (tmp_path / cwd).mkdir(exist_ok=True)
    monkeypatch.chdir(tmp_path / cwd)
    _write(tmp_path / "runs" / "good", _record())
    (tmp_path / "paper").mkdir()
    (tmp_path / "paper" / "README.md").write_text("the committed tables")
    (tmp_path / "paper" / "table4_kth.md").write_text("committed")
    with pytest.raises(SystemExit) as exit_:
        tables.main(["--runs", str(tmp_path / "runs"), "--out", out.format(tmp=tmp_path)])
    error = capsys.readouterr().err
    assert exit_.value.code == 2 and "paper holds the committed scope only" in error
    assert sorted(p.name for p in (tmp_path / "paper").iterdir()) == ["README.md", "table4_kth.md"]
    assert (tmp_path / "paper" / "table4_kth.md").read_text() == "committed"


def test_a_users_own_folder_named_paper_takes_the_tables(tmp_path, monkeypatch) -> None:
    """Only the project's paper/ is guarded: a README there, but no package beside it."""
    monkeypatch.chdir(tmp_path)
    _write(tmp_path / "runs" / "good", _record())
    (tmp_path / "paper").mkdir()
    (tmp_path / "paper" / "README.md").write_text("my notes")
    _render(tmp_path / "runs", tmp_path / "paper")
    assert (tmp_path / "paper" / "table4_kth.md").is_file()


@pytest.mark.parametrize(
    ("args", "message"),
    [(["--out", ""], "--out: an empty path"), (["--published", "{tmp}"], "is not a file of published")],
)  # fmt: skip
def test_an_empty_out_or_a_folder_as_published_numbers_is_refused(args, message, tmp_path, capsys):
    """issue 57, fresh battery: --out '' wrote every table into the current folder; --published
    naming a folder rendered tables without the paper's numbers, without a word."""
    _write(tmp_path / "runs" / "good", _record())
    argv = ["--runs", str(tmp_path / "runs"), "--out", str(tmp_path / "out")]
    with pytest.raises(SystemExit) as exit_:
        tables.main([*argv, *(a.format(tmp=tmp_path) for a in args)])
    error = capsys.readouterr().err
    assert exit_.value.code == 2 and message in error, error
    assert not (tmp_path / "out").exists()


def test_a_run_found_in_two_folders_says_which_record_the_tables_take(tmp_path) -> None:
    """issue 57: `edr-tables --runs results` after `make demo` took the user's copy of a
    committed run without a word."""
    _write(tmp_path / "runs" / "committed" / "one", _record(fingerprint="same"))
    _write(tmp_path / "runs" / "mine" / "one", _record(fingerprint="same"))
    printed = _render(tmp_path / "runs", tmp_path / "out")
    (line,) = [line for line in printed.splitlines() if "has 2 records" in line]
    assert "the tables take the newest" in line and "left out:" in line


def test_a_folder_named_run_json_is_listed_as_unreadable(tmp_path) -> None:
    """issue 57 (older battery): it was skipped without a word."""
    _write(tmp_path / "runs" / "good", _record())
    (tmp_path / "runs" / "odd" / "run.json").mkdir(parents=True)
    printed = _render(tmp_path / "runs", tmp_path / "out")
    assert "odd/run.json: a folder named run.json: a run's record is a file" in printed


def test_an_out_folder_that_cannot_be_written_is_one_line(tmp_path, monkeypatch, capsys) -> None:
    _write(tmp_path / "runs" / "good", _record())
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    if os.access(locked / "x", os.W_OK) or os.geteuid() == 0:  # root writes anyway: make a file
        locked.chmod(0o700)
        locked.rmdir()
        locked.write_text("a file, not a folder")
    with pytest.raises(SystemExit) as exit_:
        tables.main(["--runs", str(tmp_path / "runs"), "--out", str(locked)])
    error = capsys.readouterr().err
    assert exit_.value.code == 2 and error.count("\n") == 1
    assert f"cannot write the tables into {locked}" in error


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


# ---- case 5: the store's messages --------------------------------------------------------------
def _can_mount() -> bool:
    """Whether this process may mount a tmpfs in its own mount namespace (root, unshare)."""
    probe = "mount -t tmpfs -o size=64k tmpfs /mnt && umount /mnt"
    return subprocess.run(["unshare", "-m", "sh", "-c", probe], capture_output=True).returncode == 0


needs_mount = pytest.mark.skipif(not _can_mount(), reason="needs unshare -m and mount (root)")


def _edr_run(
    *args: str, cwd: Path, mount: str = "", after: str = "true", env: dict[str, str] | None = None
) -> subprocess.CompletedProcess:
    """``edr-run args`` (in a private mount namespace with ``mount`` done first, if given, and
    the shell command ``after`` run while it is mounted); its exit status is edr-run's."""
    command = " ".join([sys.executable, "-m", "edr.run", *(f"'{a}'" for a in args)])
    command = f"{command}; rc=$?; {after}; exit $rc"
    if mount:
        command = f"{mount} && {{ {command}; }}"
    return subprocess.run(
        ["unshare", "-m", "sh", "-c", command] if mount else ["sh", "-c", command],
        cwd=cwd, capture_output=True, text=True, timeout=600,
        env={**os.environ, "PYTHONPATH": SRC, **(env or {})},
    )  # fmt: skip


@needs_mount
def test_a_read_only_results_folder_is_one_line_before_any_work(tmp_path) -> None:
    disk = tmp_path / "ro"
    disk.mkdir()
    result = _edr_run("task=representation_demo", "debug=tiny", cwd=tmp_path,
                      mount=f"mount -t tmpfs -o ro,size=64k tmpfs {disk}",
                      env={"EDR_RESULTS": str(disk / "results")})  # fmt: skip
    assert result.returncode == 2, result.stderr[-3000:]
    assert result.stderr.count("\n") == 0 or result.stderr.strip().count("\n") == 0
    assert "cannot create the run folder" in result.stderr and "Read-only" in result.stderr
    assert "Traceback" not in result.stderr


def _long_folder(root: Path, length: int) -> Path:
    """A folder path of about ``length`` bytes under ``root``, in names of 200 bytes."""
    return Path(str(root / "/".join(["d" * 200] * 25))[:length].rstrip("/"))


@pytest.mark.parametrize("kind", ["run", "sweep"])
@pytest.mark.parametrize("length", [3700, 4090, 4200], ids=["no room", "at PATH_MAX", "past it"])
def test_a_folder_with_no_room_for_a_runs_files_is_one_line_before_hydra(
    kind, length, tmp_path, capsys
) -> None:
    """A run folder Hydra could make, but not its ``.hydra/config.yaml`` or ``run.log`` in it,
    once failed inside Hydra with a traceback."""
    from hydra import compose, initialize_config_dir

    from edr.run import CONF_DIR
    from edr.store.folders import RunFolder

    folder = _long_folder(tmp_path, length)
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        config = compose("config", overrides=[f"hydra.{kind}.dir={folder}"],
                         return_hydra_config=True)  # fmt: skip
    with pytest.raises(SystemExit) as exit_:
        getattr(RunFolder(), f"on_{'multi' if kind == 'sweep' else ''}run_start")(config)
    error = capsys.readouterr().err
    assert exit_.value.code == 2 and error.count("\n") == 1, error
    assert f"hydra.{kind}.dir=" in error and "levels of names under it" in error
    assert not list(tmp_path.iterdir())  # nothing made


@pytest.mark.slow
@needs_mount
def test_a_full_disk_says_which_checkpoint_is_whole_in_one_line_and_records_the_failure(tmp_path):
    disk = tmp_path / "disk"
    disk.mkdir()
    result = _edr_run("task=kth", "debug=tiny", f"task.cache_dir={tmp_path / 'cache'}",
                      "task.logger=", f"out_dir={disk / 'run'}", cwd=tmp_path,
                      mount=f"mount -t tmpfs -o size=1500k tmpfs {disk}",
                      after=f"cp {disk / 'run' / 'run.json'} {tmp_path}")  # fmt: skip
    said = result.stdout + result.stderr
    assert result.returncode == 1, said[-3000:]
    (line,) = [line for line in said.splitlines() if "could not write" in line]
    assert "checkpoint.pt" in line and "is the previous one, whole" in line
    assert "Traceback" not in said and "During handling" not in said
    record = json.loads((tmp_path / "run.json").read_text())
    assert record["status"] == "failed" and "checkpoint.pt" in record["error"]


@needs_mount
def test_the_last_record_is_written_on_a_disk_that_stays_full(tmp_path) -> None:
    disk = tmp_path / "disk"
    disk.mkdir()
    script = (
        "import json, pathlib, sys\n"
        "from edr.store.records import write_last_record, write_record\n"
        f"out = pathlib.Path('{disk}')\n"
        "record = {'status': 'running', 'config': {'x': 'y' * 3000}}\n"
        "write_record(out, record)\n"
        "with open(out / 'filler', 'wb', buffering=0) as f:\n"
        "    try:\n"
        "        while True: f.write(b'0' * 4096)\n"
        "    except OSError: pass\n"
        "record.update(status='failed', error='OSError: No space left on device')\n"
        "assert write_last_record(out, record) is None\n"
        "print(json.loads((out / 'run.json').read_text())['status'])\n"
    )
    result = subprocess.run(
        ["unshare", "-m", "sh", "-c",
         f"mount -t tmpfs -o size=256k tmpfs {disk} && exec {sys.executable} -c \"$0\"", script],
        capture_output=True, text=True, timeout=120,
        env={**os.environ, "PYTHONPATH": SRC},
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-3000:]
    assert result.stdout.strip() == "failed"


@pytest.mark.parametrize("checkpoint", [False, True])
@pytest.mark.parametrize("resume", ["auto", "false"])
def test_a_folder_of_runs_is_refused_as_a_run_folder(checkpoint, resume, compose_config, tmp_path):
    from edr.checks.config import ConfigError
    from edr.run import run

    runs = tmp_path / "runs"
    nested = _write(runs / "kth" / "one", _record())
    if checkpoint:
        (nested / "checkpoint.pt").write_bytes(b"not for this run")
    cfg = compose_config("task=kth", "debug=tiny", f"out_dir={runs}", f"resume={resume}",
                         f"task.cache_dir={tmp_path / 'cache'}")  # fmt: skip
    with pytest.raises(ConfigError, match=r"holds other runs .*one/run\.json.*choose another"):
        run(cfg)
    assert not (runs / "run.json").exists() and not (tmp_path / "cache").exists()


def test_a_finished_record_without_metrics_is_one_line(compose_config, tmp_path) -> None:
    from edr.checks.config import ConfigError
    from edr.run import run
    from edr.store.identity import run_identity

    cfg = compose_config("task=kth", "debug=tiny", f"out_dir={tmp_path / 'run'}",
                         f"task.cache_dir={tmp_path / 'cache'}")  # fmt: skip
    _, fingerprint, cell = run_identity(cfg)
    _write(tmp_path / "run", {"status": "finished", "fingerprint": fingerprint, "cell": cell})
    with pytest.raises(ConfigError, match="says finished but holds no metrics: pass resume=false"):
        run(cfg)


@pytest.mark.parametrize("variable", ["EDR_RESULTS", "EDR_CACHE"])
def test_an_empty_results_variable_is_not_the_current_folder(variable, monkeypatch, tmp_path):
    from conftest import _compose

    monkeypatch.setenv(variable, "")
    monkeypatch.chdir(tmp_path)
    cfg = _compose("task=kth", "debug=tiny")
    assert Path(cfg.paths.results) == tmp_path / "results"
    assert Path(cfg.paths.cache) == tmp_path / "results" / "cache"


@pytest.mark.slow
def test_a_sweep_with_a_refused_cell_ends_with_its_summary_line(tmp_path) -> None:
    result = _edr_run("-m", "task=event_camera", "debug=tiny", "seed=0,-1",
                      f"hydra.sweep.dir={tmp_path / 'sweep'}", cwd=tmp_path)  # fmt: skip
    output = result.stdout + result.stderr
    assert result.returncode == 1, output[-3000:]
    assert "Traceback" not in output
    assert "seed=-1: expected a number >= 0" in output
    last = result.stdout.strip().splitlines()[-1]  # the log's last line
    assert "1 ran, 0 failed, 0 interrupted, 1 refused" in last, last


# A sweep whose cells do no work: the second one breaks (or gets a signal) as a task would.
SWEEP_DRIVER = """
import os, signal, sys, time
from pathlib import Path
import edr.run
from edr.store.folders import log_attempt

def cell(cfg):
    out = Path(cfg.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    outcome = "ran"
    try:
        if cfg.seed == 1:
            outcome = "{outcome}"
            {action}
    finally:
        log_attempt(out, outcome, "fingerprint")  # as edr.run.run logs each attempt
    return {{}}

edr.run.run = cell
sys.argv = ["edr-run", *sys.argv[1:]]
edr.run.cli()
"""
CELL_ENDS = {
    "a failing cell": ("failed", "raise RuntimeError('a cell that breaks')", 1),
    "Ctrl-C": ("interrupted", "os.kill(os.getpid(), signal.SIGINT); time.sleep(60)", 130),
    "SIGTERM": ("interrupted", "os.kill(os.getpid(), signal.SIGTERM); time.sleep(60)", 143),
}


@pytest.mark.parametrize(
    "end", [pytest.param(e, marks=pytest.mark.slow) if e == "SIGTERM" else e for e in CELL_ENDS]
)  # SIGTERM takes Ctrl-C's path: checked with the slow tests
def test_a_sweep_ends_with_its_summary_line_whatever_its_cells_did(end, tmp_path) -> None:
    outcome, action, status = CELL_ENDS[end]
    sweep = tmp_path / "sweep"
    result = subprocess.run(
        [sys.executable, "-c", SWEEP_DRIVER.format(outcome=outcome, action=action), "-m",
         "seed=0,1,2", f"hydra.sweep.dir={sweep}"],
        cwd=tmp_path, capture_output=True, text=True, timeout=300,
        env={**os.environ, "PYTHONPATH": SRC, "PYTHONUNBUFFERED": "1"},
    )  # fmt: skip
    said = result.stdout + result.stderr
    assert result.returncode == status, said[-3000:]
    assert "Traceback" not in said
    (summary,) = [line for line in result.stdout.splitlines() if f"sweep {sweep}:" in line]
    if outcome == "failed":  # the sweep goes on to its third cell, then says what happened
        assert summary.endswith("0 skipped, 0 resumed, 2 ran, 1 failed, 0 interrupted"), summary
        assert result.stdout.rstrip().splitlines()[-1] == summary
        assert "failed: RuntimeError: a cell that breaks" in said
    else:  # it stops at the second cell, says what it did, then how to resume
        assert summary.endswith("0 skipped, 0 resumed, 1 ran, 0 failed, 1 interrupted"), summary
        assert said.rstrip().splitlines()[-1].startswith("interrupted: run the same command")


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[1, 2]", "holds list, not a run record"),
        ('{"seed": 0}', "status=None: expected one of running, finished, interrupted"),
        ('{"status": "finished", "seed": 0}', "has no config.task to rebuild the run from"),
        ('{"status": "finished", "seed": 0, "config": {"task": "edr.tasks.atari.train_paac"}}',
         "has no config.task"),
        ('{"status": "finished", "seed": 0, "config": [1]}', "has no config.task"),
    ],
)  # fmt: skip
def test_a_checkpoint_evaluation_of_a_malformed_record_is_one_line(text, message, tmp_path):
    from edr.store.records import UnreadableRecord
    from edr.tasks.run_folder import RefusedFolder

    run_dir = _write(tmp_path / "run", None, text)
    (run_dir / "checkpoint.pt").write_bytes(b"")
    with pytest.raises((UnreadableRecord, RefusedFolder), match=message) as caught:
        evaluate_checkpoint(run_dir)
    assert "\n" not in str(caught.value)


def test_a_finished_record_without_its_data_part_is_listed_as_unreadable(tmp_path) -> None:
    """issue 57: such a record drew a figure of no panels, a matplotlib trace."""
    record = _record()
    record.pop("data", None)
    _write(tmp_path / "runs" / "nodata", record)
    _write(tmp_path / "runs" / "good", _record(fingerprint="other"))
    printed = _render(tmp_path / "runs", tmp_path / "out")
    assert "nodata/run.json: finished, but without its data part" in printed


@pytest.mark.parametrize(
    ("make", "reason"),
    [
        (lambda f: _write(f, _record(metrics={"eval/accuracy": "high"})), "not numbers"),
        (lambda f: _write(f, None, text='{"status": "finished", "task": "kth", "metrics": '
                                        '{"eval/accuracy": 1' + "0" * 400 + "}}"), "not numbers"),
        (lambda f: (f.mkdir(parents=True), os.mkfifo(f / "run.json")), "named pipe"),
    ],
    ids=["text-accuracy", "int-past-float", "named-pipe"],
)  # fmt: skip
def test_records_a_table_cannot_use_are_listed_not_rendered_or_hung_on(make, reason, tmp_path):
    """issue 57, fresh battery: a text accuracy rendered as '—' unlisted; an integer past float's
    range was pandas' OverflowError; a named pipe called run.json hung edr-tables forever."""
    _write(tmp_path / "runs" / "good", _record())
    make(tmp_path / "runs" / "bad")
    printed = _render(tmp_path / "runs", tmp_path / "out")
    (line,) = [line for line in printed.splitlines() if "bad" in line and "run.json" in line]
    assert reason in line
    assert (tmp_path / "out" / "table4_kth.md").is_file()


@pytest.mark.parametrize("beside_a_good_one", [True, False])
def test_a_finished_record_without_choices_is_not_placed_not_a_traceback(
    beside_a_good_one, tmp_path
):
    """issue 57, fresh battery: `"choices": {}` was a KeyError in Table 4, and, alone, in the
    figures' labels."""
    if beside_a_good_one:
        _write(tmp_path / "runs" / "good", _record())
    _write(tmp_path / "runs" / "bare", _record(seed=1, choices={}))
    printed = _render(tmp_path / "runs", tmp_path / "out")
    table = tmp_path / "out" / "table4_kth.md"
    assert "lacks" in (table.read_text() if table.exists() else "") + printed
