"""Sweeps through a real Slurm (``hydra/launcher=slurm``, each cell an sbatch job): records,
skipping, resuming a cancelled job, a failing job, and a paper table as one job array.

Marked ``cluster``; they need a Slurm cluster whose ``sinfo`` answers: CI starts a one-node one
on this machine (``eval "$(sweeps/slurm-local.sh start)"``) around ``make test``; elsewhere they
skip. Without Slurm accounting (the local cluster), submitit counts a job done only when its
result file appears, so a job killed before writing one is never seen to end: every command
here has its own timeout, and a test that cancels a job stops the waiting ``edr-run`` itself.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from cluster import NO_CLUSTER, slurm_environment

pytestmark = [pytest.mark.cluster, pytest.mark.slow,  # minutes of jobs, when a cluster is up
              pytest.mark.xdist_group("slurm")]  # one test at a time on its one node  # fmt: skip
SLURM_ENV = slurm_environment()
if SLURM_ENV is None:
    pytest.skip(NO_CLUSTER, allow_module_level=True)  # one line for the module

EDR_RUN = str(Path(sys.executable).parent / "edr-run")
# One KTH cell at debug=tiny, long enough (4 epochs of 200 batches, about 3 s each here) to be
# cancelled inside: at 5 batches an epoch the whole run ended before scancel landed.
LONG_KTH = ("task=kth", "debug=tiny", "task.epochs=4", "task.clips_per_epoch=1200")
LONG_CELL = "debug=tiny,task=kth,task.clips_per_epoch=1200,task.epochs=4"


class Slurm:
    """``edr-run -m hydra/launcher=slurm`` in one folder, its jobs named for this test alone
    (cancelled at the end, whatever happened)."""

    def __init__(self, env: dict[str, str], folder: Path) -> None:
        self.name = f"edr-test-{uuid.uuid4().hex[:8]}"
        self.folder = folder
        self.env = {**env, "PYTHONUNBUFFERED": "1", "EDR_RESULTS": str(folder / "results"),
                    "EDR_CACHE": str(folder / "cache")}  # fmt: skip

    def args(self, *overrides: str) -> list[str]:
        return [EDR_RUN, "-m", "hydra/launcher=slurm", "hydra.launcher.timeout_min=15",
                f"hydra.launcher.name={self.name}", *overrides]  # fmt: skip

    def run(self, *overrides: str, timeout: float = 600) -> tuple[int, str]:
        """Run the sweep to its end: (exit status, stdout and stderr together)."""
        done = subprocess.run(self.args(*overrides), cwd=self.folder, env=self.env, text=True,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, timeout=timeout)  # fmt: skip
        return done.returncode, done.stdout

    def start(self, *overrides: str) -> subprocess.Popen:
        return subprocess.Popen(self.args(*overrides), cwd=self.folder, env=self.env, text=True,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                start_new_session=True)  # fmt: skip

    def jobs(self) -> list[str]:
        """Job ids of this test's jobs in the queue, arrays expanded (``12_0``, ``12_1``...)."""
        out = subprocess.run(["squeue", "-h", "-r", "--name", self.name, "-o", "%i"],
                             env=self.env, capture_output=True, text=True, timeout=30)  # fmt: skip
        return out.stdout.split()

    def cancel(self) -> None:
        subprocess.run(["scancel", "--name", self.name], env=self.env, timeout=30)


@pytest.fixture
def slurm(tmp_path) -> Slurm:
    cluster = Slurm(SLURM_ENV, tmp_path)
    yield cluster
    cluster.cancel()


def _wait_for(condition, what: str, timeout: float = 300) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"{what}: not after {timeout} s"
        time.sleep(0.5)


def _stop(process: subprocess.Popen) -> str:
    """Stop an edr-run that waits for a job it will never see end (no accounting); its output."""
    if process.poll() is None:
        os.killpg(process.pid, signal.SIGTERM)
    return process.communicate(timeout=60)[0]


def _record(path: Path) -> dict:
    return json.loads(path.read_text()) if path.is_file() else {}


def test_a_sweep_writes_a_finished_record_per_cell_and_skips_them_when_run_again(slurm) -> None:
    status, output = slurm.run("task=kth", "debug=tiny", "seed=0,1")
    assert status == 0, output[-3000:]
    assert "0 skipped, 0 resumed, 2 ran, 0 failed" in output
    sweep = slurm.folder / "results" / "sweeps" / "kth"
    records = sorted(sweep.glob("*/run.json"))
    assert [r.parent.name for r in records] == ["debug=tiny,seed=0,task=kth",
                                                "debug=tiny,seed=1,task=kth"]  # fmt: skip
    for index, path in enumerate(records):
        assert _record(path)["status"] == "finished"
        log = (path.parent / "run.log").read_text()
        assert re.search(rf"kth #{index} finished: accuracy [\d.]+ % \(chance", log), log
    (script,) = sweep.glob(".submitit/*/*_submission.sh")  # one sbatch for both cells
    assert "#SBATCH --array=0-1" in script.read_text()
    assert not re.search(r"--gpus|--gres|--mem|--partition", script.read_text())  # a CPU node
    finished_at = [p.stat().st_mtime_ns for p in records]

    status, output = slurm.run("task=kth", "debug=tiny", "seed=0,1")
    assert status == 0, output[-3000:]
    assert "2 skipped, 0 resumed, 0 ran, 0 failed" in output
    assert [p.stat().st_mtime_ns for p in records] == finished_at


def test_a_cancelled_job_resumes_from_its_checkpoint_when_the_sweep_is_run_again(slurm) -> None:
    cell = slurm.folder / "results" / "sweeps" / "kth" / LONG_CELL
    waiting = slurm.start(*LONG_KTH)
    try:
        _wait_for((cell / "checkpoint.pt").exists, "a checkpoint")
        slurm.cancel()  # scancel: SIGTERM to the job, which ends the run as kill does
        _wait_for(lambda: _record(cell / "run.json").get("status") == "interrupted", "the record")
    finally:
        _stop(waiting)
    assert _record(cell / "run.json")["status"] == "interrupted"

    status, output = slurm.run(*LONG_KTH)
    assert status == 0, output[-3000:]
    assert "0 skipped, 1 resumed, 0 ran, 0 failed" in output
    record = _record(cell / "run.json")
    assert record["status"] == "finished" and record["resumed"] and record["attempt"] == 2
    epochs = [row["epoch"] for row in json.loads((cell / "history.json").read_text())]
    assert epochs == [1, 2, 3, 4]


def test_a_job_failing_on_a_bad_value_reports_it_and_records_failed(slurm) -> None:
    """``task.crop`` larger than the frames passes the config checks; the task refuses it."""
    status, output = slurm.run("task=kth", "debug=tiny", "task.crop=100")
    assert status != 0
    assert "task.crop=100: expected at most the frames' short side" in output, output[-3000:]
    assert "Traceback" not in output
    (path,) = (slurm.folder / "results" / "sweeps" / "kth").glob("*/run.json")
    record = _record(path)
    assert record["status"] == "failed" and record["error"].startswith("ConfigError: task.crop=100")


def test_table_1_is_one_job_array_of_its_cells(slurm) -> None:
    """All 36 cells (6 games x 2 inputs x 3 seeds) as one sbatch array; cancelled once queued
    (running them all is minutes of CPU)."""
    waiting = slurm.start("experiment=table1_atari", "debug=tiny")
    try:
        _wait_for(lambda: len(slurm.jobs()) == 36, "36 queued jobs", timeout=120)
        jobs = slurm.jobs()
    finally:
        slurm.cancel()
        _stop(waiting)
    assert len({job.split("_")[0] for job in jobs}) == 1  # one array job
    assert sorted(int(job.split("_")[1]) for job in jobs) == list(range(36))
