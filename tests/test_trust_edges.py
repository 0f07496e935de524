"""Issue 57's cases outside the event files: a cache that survives a full disk, the command
line's one-line refusals, and the records of runs that end on a signal. Each case was a
reproducer that failed before its fix."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import pytest

from edr.data.synthetic import write_synthetic_kth


class _SilentWriter:
    """cv2.VideoWriter as it behaves on a full disk: opens, takes every frame, writes nothing."""

    def __init__(self, *args, **kwargs) -> None:
        pass

    def isOpened(self) -> bool:
        return True

    def write(self, frame) -> None:
        pass

    def release(self) -> None:
        pass


def test_a_full_disk_leaves_no_generated_data_set_behind(tmp_path, monkeypatch) -> None:
    root = tmp_path / "cache" / "kth"
    size = {"persons": 1, "scenarios": 1, "frames": 4, "height": 12, "width": 16}
    with monkeypatch.context() as patch:
        patch.setattr(cv2, "VideoWriter", _SilentWriter)
        with pytest.raises(OSError, match=r"left an empty file \(the disk holding it has .* MiB"):
            write_synthetic_kth(root, **size)
    assert not root.exists() and list((tmp_path / "cache").iterdir()) == []  # nothing half kept
    videos = sorted(write_synthetic_kth(root, **size).glob("*/*.avi"))  # space back: it works
    assert len(videos) == 6 and all(v.stat().st_size > 0 for v in videos)


def test_a_key_given_twice_is_refused_in_one_line(cli, tmp_path) -> None:
    result = cli("edr-run", "task=kth", "task=atari", "debug=tiny", cwd=tmp_path)
    assert result.returncode == 2 and result.stderr.count("\n") == 1
    assert "task is given twice (task=kth and task=atari)" in result.stderr


def test_a_file_where_a_folder_belongs_is_refused_in_one_line(cli, tmp_path) -> None:
    video = tmp_path / "person01_boxing_d1_uncomp.avi"
    video.write_bytes(b"not a folder")
    result = cli("edr-run", "task=kth", f"task.data_root={video}", "debug=tiny", cwd=tmp_path)
    assert result.returncode == 2 and f"expected a folder ({video} is a file)" in result.stderr
    result = cli("edr-run", "task=kth", "debug=tiny", cwd=tmp_path, env={"EDR_CACHE": str(video)})
    assert result.returncode == 2 and result.stderr.count("\n") == 1
    assert f"task.cache_dir='{video}': expected a folder" in result.stderr


def test_edr_eval_on_a_recognition_run_says_what_it_scores(tmp_path) -> None:
    from edr.tasks.atari import evaluate_checkpoint
    from edr.tasks.run_folder import RefusedFolder

    (tmp_path / "run.json").write_text(json.dumps({"task": "kth", "status": "finished"}))
    with pytest.raises(RefusedFolder, match="is a kth run: edr-eval reads atari runs only"):
        evaluate_checkpoint(tmp_path)


def test_a_run_stopped_before_its_first_checkpoint_says_it_starts_over(
    compose_config, tmp_path, monkeypatch, caplog
) -> None:
    """issue 57: a full-size KTH run checkpoints at its first epoch's end, yet a Ctrl-C within
    that epoch said the run would continue from its checkpoint."""
    from edr.run import run
    from edr.tasks import recognition

    def stopped(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(recognition, "_train_epoch", stopped)
    out = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        run(compose_config("task=kth", "debug=tiny", f"task.cache_dir={tmp_path / 'cache'}",
                           "task.logger=", f"out_dir={out}"))  # fmt: skip
    assert "stopped before its first checkpoint: running the same command again starts it over" in (
        caplog.text
    )


@pytest.mark.slow  # a parallel env's workers start in seconds
@pytest.mark.parametrize("sent", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_to_the_process_group_of_a_parallel_env_run_is_an_interruption(
    sent, tmp_path
) -> None:
    """issue 57: Ctrl-C (or a scheduler's SIGTERM) reaches every process of the group; the
    ParallelEnv's workers died of it and the record said failed, with torchrl's traceback."""
    out = tmp_path / "run"
    argv = ["task=atari", "task.env.preset=none", "task.env.env_id=EdrCatch-v0",
            "task.env.env_module=catch_game", "task.env.backend=parallel", "task.env.num_envs=2",
            "task.env_steps=10000000", "task.optim.lr_decay_env_steps=10000000",
            "task.checkpoint_every=5", "task.logger=", "representation.color=gray", "threads=1",
            f"hydra.run.dir={out}"]  # fmt: skip
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "PYTHONPATH": str(Path(__file__).parent)}
    process = subprocess.Popen(
        [str(Path(sys.executable).parent / "edr-run"), *argv], cwd=tmp_path, env=env,
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True,
    )  # fmt: skip
    output: list[str] = []
    threading.Thread(target=lambda: output.extend(iter(process.stdout.readline, "")),
                     daemon=True).start()  # fmt: skip
    deadline = time.monotonic() + 300
    while not (out / "checkpoint.pt").is_file():  # training under way, a checkpoint written
        assert process.poll() is None and time.monotonic() < deadline, "".join(output)[-3000:]
        time.sleep(0.2)
    os.killpg(process.pid, sent)  # the whole group, as a terminal's Ctrl-C
    process.wait(timeout=120)
    text = "".join(output)
    assert process.returncode in (130, 143), text[-3000:]
    assert "process failed" not in text and "Traceback" not in text, text[-3000:]
    record = json.loads((out / "run.json").read_text())
    assert record["status"] == "interrupted" and record["resumes_from"]["env_steps"] > 0


def test_a_clip_whose_representation_cannot_fit_is_refused_before_it_is_made(cli, tmp_path):
    """issue 57: task.height=100000 passed the memory check (the uint8 clip alone fits), then
    held 3.4 GB in a kernel call that no SIGTERM could stop."""
    result = cli("edr-run", "task=event_camera", "task.height=100000", cwd=tmp_path)
    assert result.returncode != 0 and "Traceback" not in result.stderr
    assert "its float32 copy and a 2-channel float32 representation of it would take" in (
        result.stdout + result.stderr
    )


def test_a_crop_the_backbone_cannot_take_is_refused_before_decoding(compose_config, tmp_path):
    """issue 57 (older battery): task.crop=1 was a traceback after every video was decoded."""
    from edr.checks.config import ConfigError
    from edr.run import run

    out = tmp_path / "run"
    with pytest.raises(ConfigError, match=r"task\.crop=1, task\.frames=8: the backbone cannot"):
        run(compose_config("task=kth", "debug=tiny", "task.crop=1",
                           f"task.cache_dir={tmp_path / 'cache'}", f"out_dir={out}"))  # fmt: skip
    assert not (tmp_path / "cache").exists()  # refused before any video was generated or decoded


def test_a_learnable_edr_driven_to_nan_warns_instead_of_giving_zeros_silently() -> None:
    """issue 57 (older battery): NaN parameters made every event 0, with no word."""
    import torch

    from edr.representations import EDR

    edr = EDR(learnable=True, color="gray")
    with torch.no_grad():
        next(edr.parameters()).fill_(float("nan"))
    clip = torch.randint(0, 255, (1, 4, 1, 16, 16), dtype=torch.uint8)
    with pytest.warns(RuntimeWarning, match="left its range"):
        edr(clip)


def test_a_slurm_sweep_without_a_cluster_is_one_line(cli, tmp_path) -> None:
    """issue 57: hydra/launcher=slurm with no srun, or a controller down, was submitit's trace."""
    python_only = str(Path(sys.executable).parent)
    sweep = (
        "-m",
        "hydra/launcher=slurm",
        "task=kth",
        "debug=tiny",
        f"hydra.sweep.dir={tmp_path}/s",
    )
    result = cli("edr-run", *sweep, cwd=tmp_path, env={"PATH": python_only})
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    assert "hydra/launcher=slurm: no srun, sbatch, sinfo on the PATH" in result.stderr
    fake = tmp_path / "bin"  # a cluster whose controller is down
    fake.mkdir()
    for tool, body in {"srun": "exit 0", "sbatch": "exit 0",
                       "sinfo": "echo 'slurm_load_partitions: Unable to contact slurm controller' >&2; exit 1"}.items():  # fmt: skip
        (fake / tool).write_text(f"#!/bin/sh\n{body}\n")
        (fake / tool).chmod(0o755)
    result = cli("edr-run", *sweep, cwd=tmp_path, env={"PATH": f"{fake}:{python_only}"})
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    assert (
        "sinfo failed (slurm_load_partitions: Unable to contact slurm controller)" in result.stderr
    )


def test_events_to_save_in_a_format_too_small_for_the_sensor_are_refused_before_the_run(
    compose_config, tmp_path
) -> None:
    """issue 57: save_events=.aedat at 640x480 failed only after every representation ran."""
    from edr.data.events import RecordingError
    from edr.run import run

    with pytest.raises(RecordingError, match=r"AEDAT 2\.0 holds sensors up to DAVIS346's"):
        run(compose_config("task=event_camera", "task.save_events=.aedat", "task.height=480",
                           "task.width=640", "task.frames=6", f"out_dir={tmp_path / 'run'}"))  # fmt: skip
    assert not list((tmp_path / "run").glob("*_events*"))


def test_the_backbone_check_leaves_the_runs_random_stream_as_it_was() -> None:
    import torch
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    from edr import CONF_DIR
    from edr.representations import EDR
    from edr.tasks.recognition import _check_backbone_takes

    backbone = instantiate(OmegaConf.load(Path(CONF_DIR) / "backbone" / "lenet_ftrcn.yaml"))
    torch.manual_seed(0)
    expected = torch.rand(3)
    torch.manual_seed(0)
    _check_backbone_takes(backbone, EDR(color="gray"), 1, 8, 24)
    assert torch.equal(torch.rand(3), expected)


def test_a_stale_lock_whose_pid_now_runs_another_process_is_taken_over(tmp_path) -> None:
    """issue 57: a lock left by a dead run whose pid the system gave to another process (here:
    this test's own, a live process that never took the lock) was never taken over."""
    import socket

    from edr.store.folders import LOCK, hold_folder, holder_alive, process_identity

    if process_identity(os.getpid()) is None:
        pytest.skip("the system does not say when a process started (no /proc)")
    stale = {"host": socket.gethostname(), "pid": os.getpid(), "since": "yesterday",
             "process": "another-boot:12345"}  # fmt: skip
    (tmp_path / LOCK).write_text(json.dumps(stale))
    assert not holder_alive(tmp_path)
    with hold_folder(tmp_path):
        assert json.loads((tmp_path / LOCK).read_text())["process"] == process_identity(os.getpid())
        assert holder_alive(tmp_path)  # the live holder is the holder
    assert not (tmp_path / LOCK).exists()


def test_two_sweeps_in_one_folder_count_their_own_cells(tmp_path, monkeypatch) -> None:
    """issue 57: two sweeps writing one folder at once each reported '4 ran' for its 2 cells."""
    import time as clock

    from edr.store.folders import SWEEP_ID, log_attempt, outcomes_since

    start = clock.time()
    for sweep, cells in (("first", ("a", "b")), ("second", ("c", "d"))):
        monkeypatch.setenv(SWEEP_ID, sweep)
        for cell in cells:
            (tmp_path / cell).mkdir()
            log_attempt(tmp_path / cell, "ran", "f")
    assert outcomes_since(tmp_path, start, "first") == {"ran": 2}
    assert outcomes_since(tmp_path, start, "second") == {"ran": 2}
    assert outcomes_since(tmp_path, start) == {"ran": 4}  # no sweep named: every cell


def test_a_signal_while_the_finished_record_is_written_waits_for_it(
    compose_config, tmp_path, monkeypatch
) -> None:
    """issue 57: Ctrl-C during a run's last write left its record ``running`` and no attempt line;
    the record and the line are written, then the interrupt stops what comes next."""
    import edr.run as edr_run

    def write_then_signal(out_dir: Path, record: dict) -> Path:
        if record["status"] == "finished":
            os.kill(os.getpid(), signal.SIGINT)  # lands as the record is written
        return write_record(out_dir, record)

    write_record = edr_run.write_record
    monkeypatch.setattr(edr_run, "write_record", write_then_signal)
    out = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        edr_run.run(compose_config("task=kth", "debug=tiny", f"task.cache_dir={tmp_path / 'cache'}",
                                   f"out_dir={out}"))  # fmt: skip
    assert json.loads((out / "run.json").read_text())["status"] == "finished"
    assert json.loads((out / "attempts.jsonl").read_text())["outcome"] == "ran"


@pytest.mark.parametrize("kind", ["a file", "run.json a folder", "run.json a named pipe"])
def test_edr_eval_on_a_path_that_holds_no_readable_record_is_one_line(kind, cli, tmp_path):
    """issue 57, fresh battery: tracebacks (NotADirectoryError, IsADirectoryError) and, for a
    named pipe, a hang."""
    target = tmp_path / "run"
    if kind == "a file":
        target.write_text("x")
    else:
        target.mkdir()
        (target / "run.json").mkdir() if "folder" in kind else os.mkfifo(target / "run.json")
    result = cli("edr-eval", str(target), cwd=tmp_path)
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    assert "is not a readable run record" in result.stderr


def test_a_run_folder_whose_record_is_a_folder_is_refused(compose_config, tmp_path) -> None:
    """issue 57, fresh battery: the run went ahead and failed at its first record write."""
    from edr.run import run
    from edr.store.records import UnreadableRecord

    out = tmp_path / "run"
    (out / "run.json").mkdir(parents=True)
    with pytest.raises(UnreadableRecord, match="a folder, not a file"):
        run(compose_config("task=kth", "debug=tiny", f"task.cache_dir={tmp_path / 'cache'}",
                           f"out_dir={out}"))  # fmt: skip


@pytest.mark.parametrize("content", [b"not a checkpoint\n", bytes(range(256)) * 4])
def test_a_checkpoint_of_any_damage_is_unreadable_not_a_traceback(content, tmp_path) -> None:
    """issue 57, fresh battery: text gave pickle's UnpicklingError, random bytes an IndexError."""
    from edr.store.checkpoints import UnreadableCheckpoint, load_checkpoint

    (tmp_path / "checkpoint.pt").write_bytes(content)
    with pytest.raises(UnreadableCheckpoint, match="cannot be read"):
        load_checkpoint(tmp_path / "checkpoint.pt")


def test_several_values_without_m_are_refused_as_a_sweep(cli, tmp_path) -> None:
    """battery c01: task=kth,atari without -m was Hydra's five-line "Ambiguous value", exit 1."""
    result = cli("edr-run", "task=kth,atari", "debug=tiny", f"hydra.run.dir={tmp_path}/run",
                 cwd=tmp_path)  # fmt: skip
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    assert "task=kth,atari: several values are a sweep, which needs -m" in result.stderr
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("folder", ["hydra.run.dir=", "hydra.sweep.dir="])
def test_an_empty_run_or_sweep_folder_is_refused_not_the_current_folder(
    folder, cli, tmp_path
) -> None:
    """battery c04: hydra.run.dir= (empty) wrote the run's files into the current folder."""
    multirun = ("-m",) if "sweep" in folder else ()
    result = cli("edr-run", *multirun, "task=kth", "debug=tiny", folder, cwd=tmp_path)
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    assert f"{folder}: expected a path (an empty one would mean the current folder)" in (
        result.stderr
    )
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("actions", "expected"),
    [("[boxing,boxing]", "a list without repeats (boxing given more than once)"),
     ("[]", "a list of at least one value")],
)  # fmt: skip
def test_kth_actions_are_each_listed_once_and_at_least_one(
    actions, expected, compose_config, tmp_path
) -> None:
    """battery c05, c06: [boxing,boxing] trained the same videos as two classes; [] all six."""
    from edr.checks.config import ConfigError, check_config
    from edr.data.datasets import kth
    from edr.run import ENTRY_KEYS

    cfg = compose_config("task=kth", "debug=tiny", f"task.videos.actions={actions}")
    with pytest.raises(
        ConfigError, match=rf"task\.videos\.actions=.*: expected {re.escape(expected)}"
    ):
        check_config(cfg, entry=ENTRY_KEYS)  # the config check, before any decoding
    with pytest.raises(ConfigError, match=re.escape(expected)):  # the data set's own, called alone
        kth(tmp_path, actions=list(cfg.task.videos.actions))


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="no /proc, where nothing can be made")
def test_a_cache_folder_that_cannot_be_made_is_refused_before_work(compose_config) -> None:
    """battery c08: EDR_CACHE=/proc/edr_cache was a traceback from the first cache write (a
    check of permissions passes as root: the check makes a folder there, and removes it)."""
    from edr.checks.config import ConfigError, check_config
    from edr.run import ENTRY_KEYS

    cfg = compose_config("task=kth", "debug=tiny", "task.cache_dir=/proc/edr_cache")
    with pytest.raises(ConfigError, match=r"task\.cache_dir='/proc/edr_cache': expected a folder "
                                          r"this process can write \(one made in /proc: "):  # fmt: skip
        check_config(cfg, entry=ENTRY_KEYS)


def test_edr_bench_refuses_an_out_dir_it_cannot_write_into_before_measuring(
    tmp_path, capsys
) -> None:
    """battery a26: --out-dir <a file> was a FileExistsError traceback after the timing."""
    from edr.studies import bench

    afile = tmp_path / "afile"
    afile.write_text("keep")
    with pytest.raises(SystemExit) as stop:
        bench.main(["--events", str(tmp_path / "never_read.raw"), "--out-dir", str(afile)])
    error = capsys.readouterr().err
    assert stop.value.code == 2 and error.count("\n") == 1
    assert f"edr-bench: --out-dir={afile}: expected a folder ({afile} is a file)" in error
    assert afile.read_text() == "keep"


def test_save_events_onto_a_folder_is_refused_before_the_run(compose_config, tmp_path) -> None:
    """battery a27: a folder named dvs_events.npz in the run folder was an IsADirectoryError
    traceback after every representation ran."""
    from edr.data.events import RecordingError
    from edr.run import run

    out = tmp_path / "run"
    (out / "dvs_events.npz" / "keep").mkdir(parents=True)
    with pytest.raises(
        RecordingError, match=r"dvs_events\.npz: \.npz: cannot be written: a folder"
    ):
        run(compose_config("task=event_camera", "task.save_events=.npz", "task.frames=6",
                           f"out_dir={out}"))  # fmt: skip
    assert (out / "dvs_events.npz" / "keep").is_dir() and not list(out.glob(".*partial*"))


def test_a_folder_made_where_a_result_goes_during_the_run_is_one_line(
    compose_config, tmp_path, monkeypatch, caplog
) -> None:
    """battery a27, the race the check before the run cannot see: the rename's OSError is one
    line (exit 1), the record says failed, and no partial file stays."""
    from edr import run as edr_run
    from edr.store.atomic import atomic_path
    from edr.tasks import event_camera

    def folder_appears(path: Path, events: object, sensor: tuple[int, int]) -> Path:
        path.mkdir()
        with atomic_path(path) as tmp:
            tmp.write_bytes(b"events")
        return path

    monkeypatch.setattr(event_camera, "write_recording", folder_appears)
    out = tmp_path / "run"
    with pytest.raises(SystemExit) as stop:
        edr_run.hydra_app(compose_config("task=event_camera", "task.save_events=.npz",
                                         "task.frames=6", f"out_dir={out}"))  # fmt: skip
    errors = [r.getMessage() for r in caplog.records if r.levelname == "ERROR"]
    assert stop.value.code == 1 and len(errors) == 1 and "Is a directory" in errors[0], errors
    assert json.loads((out / "run.json").read_text())["status"] == "failed"
    assert not list(out.glob(".*partial*"))
