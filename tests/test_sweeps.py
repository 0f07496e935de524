"""Sweeps as users run them: ``edr-run -m`` in a subprocess, killed and re-run, in parallel
through joblib, and as submitit jobs."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

EDR_RUN = str(Path(sys.executable).parent / "edr-run")
# Two cells of KTH at debug=tiny, long enough (6 epochs of 10 batches) to be killed inside one.
SWEEP = ("-m", "task=kth", "debug=tiny", "representation=edr,fdr", "task.epochs=6",
         "task.clips_per_epoch=60")  # fmt: skip
# The cells' folders: named from each job's overrides, sorted.
FIRST, SECOND = (
    f"debug=tiny,representation={r},task=kth,task.clips_per_epoch=60,task.epochs=6"
    for r in ("edr", "fdr")
)


def _start(*args: str, cwd: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "EDR_CACHE": str(cwd / "cache")}
    return subprocess.Popen(
        [EDR_RUN, *args], cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        text=True, start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # as in a terminal
    )  # fmt: skip


def _wait_for(path: Path, process: subprocess.Popen, timeout: float = 300) -> None:
    deadline = time.monotonic() + timeout
    while not path.exists():
        assert process.poll() is None, process.communicate()[0][-3000:]
        assert time.monotonic() < deadline, f"{path} never appeared"
        time.sleep(0.02)


@pytest.mark.slow
def test_a_killed_sweep_resumes_where_it_stopped(tmp_path) -> None:
    sweep = tmp_path / "sweep"
    process = _start(*SWEEP, f"hydra.sweep.dir={sweep}", cwd=tmp_path)
    _wait_for(sweep / SECOND / "checkpoint.pt", process)
    os.killpg(process.pid, signal.SIGKILL)  # as a cluster's time limit or an OOM kill would
    process.wait()
    first_record = sweep / FIRST / "run.json"
    assert json.loads(first_record.read_text())["status"] == "finished"
    assert json.loads((sweep / SECOND / "run.json").read_text())["status"] == "running"
    finished_at = first_record.stat().st_mtime_ns

    again = _start(*SWEEP, f"hydra.sweep.dir={sweep}", cwd=tmp_path)
    output = again.communicate(timeout=600)[0]
    assert again.returncode == 0, output[-3000:]
    assert "1 skipped, 1 resumed, 0 ran, 0 failed" in output
    assert first_record.stat().st_mtime_ns == finished_at  # the finished cell was not re-run
    assert sorted(p.parent.name for p in sweep.glob("*/run.json")) == [FIRST, SECOND]
    second = json.loads((sweep / SECOND / "run.json").read_text())
    assert second["status"] == "finished" and second["resumed"] and second["attempt"] == 2
    assert [row["epoch"] for row in json.loads((sweep / SECOND / "history.json").read_text())] == [
        1, 2, 3, 4, 5, 6,
    ]  # fmt: skip
    steps = (sweep / SECOND / "logs/scalars/train/loss.csv").read_text().split()
    assert [s.split(",")[0] for s in steps] == ["1", "2", "3", "4", "5", "6"]  # no step twice
    assert not [p for p in tmp_path.rglob("*") if "partial" in p.name]


@pytest.mark.slow
@pytest.mark.parametrize(("sent", "status"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_ctrl_c_or_sigterm_ends_with_one_line_saying_how_to_resume(sent, status, tmp_path) -> None:
    """Ctrl-C, or SIGTERM as ``kill`` and a cluster's preemption send it."""
    sweep = tmp_path / "sweep"
    process = _start(*SWEEP, f"hydra.sweep.dir={sweep}", cwd=tmp_path)
    _wait_for(sweep / FIRST / "checkpoint.pt", process)
    process.send_signal(sent)
    output = process.communicate(timeout=120)[0]
    assert process.returncode == status
    assert "Traceback" not in output
    assert output.rstrip().splitlines()[-1].startswith("interrupted: run the same command again")
    assert f"sweep {sweep}: 0 skipped, 0 resumed, 0 ran, 0 failed, 1 interrupted" in output
    record = json.loads((sweep / FIRST / "run.json").read_text())
    assert record["status"] == "interrupted" and "error" not in record


@pytest.mark.slow
@pytest.mark.parametrize("group", [True, False], ids=["ctrl-c", "sigterm-to-the-sweep"])
def test_a_stopped_parallel_sweep_writes_every_jobs_record(group, tmp_path) -> None:
    """issue 57: joblib killed its workers on Ctrl-C, leaving records ``running`` and the summary
    short. Ctrl-C reaches every process of the group; a SIGTERM to the sweep only the sweep's."""
    sweep = tmp_path / "sweep"
    process = _start(*SWEEP[:3], "representation=edr,fdr,graydiff", *SWEEP[4:],
                     "hydra/launcher=parallel", f"hydra.sweep.dir={sweep}", cwd=tmp_path)  # fmt: skip
    for cell in (FIRST, SECOND):  # the two jobs under way; graydiff's waits for a free worker
        _wait_for(sweep / cell / "checkpoint.pt", process)
    if group:
        os.killpg(process.pid, signal.SIGINT)
    else:
        process.send_signal(signal.SIGTERM)
    output = process.communicate(timeout=120)[0]
    assert process.returncode == (130 if group else 143), output[-3000:]
    assert "Traceback" not in output
    assert f"sweep {sweep}: 0 skipped, 0 resumed, 0 ran, 0 failed, 2 interrupted" in output
    for cell in (FIRST, SECOND):
        record = json.loads((sweep / cell / "run.json").read_text())
        assert record["status"] == "interrupted" and "error" not in record
        assert json.loads((sweep / cell / "attempts.jsonl").read_text())["outcome"] == "interrupted"
    assert len(list(sweep.glob("*/run.json"))) == 2  # the third cell did not start


@pytest.mark.slow
def test_two_parallel_joblib_jobs_write_complete_records(cli, tmp_path) -> None:
    """No hydra.sweep.dir: the default folder resolves under joblib's launcher too."""
    result = cli(
        "edr-run", "-m", "hydra/launcher=parallel", "task=kth", "debug=tiny",
        "representation=edr,fdr", cwd=tmp_path, env={"EDR_CACHE": str(tmp_path / "cache")},
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-3000:]
    sweep = tmp_path / "results" / "sweeps" / "kth"
    records = [json.loads(p.read_text()) for p in sorted(sweep.glob("*/run.json"))]
    assert [r["choices"]["representation"] for r in records] == ["edr", "fdr"]
    assert all(r["status"] == "finished" and r["metrics"]["train/epochs"] == 2 for r in records)
    assert records[0]["data"]["fingerprint"] == records[1]["data"]["fingerprint"]
    assert "0 failed" in result.stdout + result.stderr


@pytest.mark.slow
def test_submitit_local_runs_a_job_end_to_end(cli, tmp_path) -> None:
    """An experiment's sweep with no hydra.sweep.dir, through submitit's executor."""
    result = cli(
        "edr-run", "-m", "hydra/launcher=local_jobs", "hydra.launcher.timeout_min=10",
        "experiment=table4_kth", "debug=tiny", "representation=edr", "backbone=lenet_ftrcn",
        "seed=0", cwd=tmp_path, env={"EDR_CACHE": str(tmp_path / "cache")},
    )  # fmt: skip
    if result.returncode != 0 and "submitit" in result.stderr and "No such file" in result.stderr:
        pytest.skip(f"submitit cannot start a local job here: {result.stderr[-500:]}")
    assert result.returncode == 0, result.stderr[-3000:]
    sweep = tmp_path / "results" / "sweeps" / "table4_kth"
    (record,) = sweep.glob("*/run.json")
    assert json.loads(record.read_text())["status"] == "finished"
    assert (sweep / ".submitit").is_dir()  # it went through submitit's executor


@pytest.mark.slow
def test_a_config_error_inside_a_submitit_job_comes_back_as_one_line(cli, tmp_path) -> None:
    """The job raises it for the sweep that waits for its result (an exit would leave none:
    without Slurm accounting, that sweep would wait forever). edr-run checks a sweep's first
    values before it starts (a lone task.epochs=-1 is refused there, exit 2): the bad value is
    the second."""
    result = cli(
        "edr-run", "-m", "hydra/launcher=local_jobs", "hydra.launcher.timeout_min=10",
        "task=kth", "debug=tiny", "task.epochs=1,-1", cwd=tmp_path,
        env={"EDR_CACHE": str(tmp_path / "cache")},
    )  # fmt: skip
    assert result.returncode == 1, result.stderr[-3000:]
    assert "task.epochs=-1: expected a number >= 1" in result.stderr
    assert "Traceback" not in result.stderr and "UncompletedJobError" not in result.stderr
