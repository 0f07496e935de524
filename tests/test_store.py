"""The results store: run identity, folder names, config checks before any work, the plan a run
makes in its folder, atomic files, and caches keyed by content and safe to fill at once."""

from __future__ import annotations

import json
import multiprocessing
import os
from functools import partial
from pathlib import Path

import numpy as np
import pytest

import edr.tasks.scalars
from edr import tables
from edr.checks.config import ConfigError
from edr.data.clips import VideoSource
from edr.data.datasets import DataLayoutError, resolve_root
from edr.data.synthetic import action_video, write_synthetic_kth
from edr.data.video import write_video
from edr.report.runs import BadRecord, read_history
from edr.run import run
from edr.store.atomic import atomic_path, publish_dir, write_json_atomic
from edr.store.folders import plan_attempt
from edr.store.identity import (
    ADDED_DEFAULTS,
    IDENTITY_KEYS,
    flatten,
    job_dirname,
    run_identity,
    with_root_symbols,
    without_added_defaults,
)

TINY_KTH = ("task=kth", "debug=tiny")
REPO = Path(__file__).resolve().parents[1]


def test_fingerprint_ignores_where_and_how_and_the_cell_ignores_the_seed(compose_config) -> None:
    _, base, cell = run_identity(compose_config(*TINY_KTH, "out_dir=a"))
    same = compose_config(
        *TINY_KTH, "out_dir=b", "threads=2", "task.logger=", "resume=false", "task.cache_dir=/c"
    )
    assert run_identity(same)[1] == base
    assert run_identity(compose_config(*TINY_KTH, "out_dir=a", "task.epochs=3"))[1] != base
    seeded = compose_config(*TINY_KTH, "out_dir=a", "seed=1")  # also the split's ${seed}
    semantic, fingerprint, seeded_cell = run_identity(seeded)
    assert semantic["task"]["videos"]["seed"] == 1
    assert fingerprint != base and seeded_cell == cell


def test_a_setting_has_one_identity_wherever_the_suites_folders_are(
    compose_config, monkeypatch, tmp_path
) -> None:
    """Two checkouts: the same experiment, other results and real-video folders."""
    identities = []
    for checkout in ("one", "two"):
        monkeypatch.setenv("EDR_RESULTS", str(tmp_path / checkout / "results"))
        monkeypatch.setenv("EDR_REAL_VIDEO", str(tmp_path / checkout / "real-video"))
        semantic, fingerprint, cell = run_identity(compose_config("experiment=kth_real"))
        identities.append((fingerprint, cell))
    assert identities[0] == identities[1]
    assert semantic["task"]["data_root"] == "<paths.real_video>/kth"
    assert str(tmp_path) not in json.dumps(semantic)
    given = run_identity(compose_config("experiment=kth_real", "task.data_root=/data/KTH"))[0]
    assert given["task"]["data_root"] == "/data/KTH"  # a path given directly stays as given


def test_paths_under_a_root_are_written_from_its_symbol() -> None:
    roots = {"results": "/me/edr/results", "cache": "/me/edr/results/cache", "x": "<paths.x>"}
    written = with_root_symbols(
        {
            "out_dir": "/me/edr/results/runs/kth/seed=0",
            "paths": {"results": "/me/edr/results"},
            "root": "/me/edr/results/cache/kth_1",  # the innermost root
            "events": "DVS simulator on 10 videos per class of /me/edr/results/cache/kth_1",
            "videos": ["/me/edr/results/a.avi", "/me/edr/results2/a.avi", "/you/me/edr/results"],
            "given": "results/cache/bikes.mp4",
            "frames": 3,
        },
        roots,
    )
    assert written == {
        "out_dir": "<paths.results>/runs/kth/seed=0",
        "paths": {"results": "<paths.results>"},
        "root": "<paths.cache>/kth_1",
        "events": "DVS simulator on 10 videos per class of <paths.cache>/kth_1",
        "videos": ["<paths.results>/a.avi", "/me/edr/results2/a.avi", "/you/me/edr/results"],
        "given": "results/cache/bikes.mp4",
        "frames": 3,
    }


def test_a_record_from_before_the_folders_had_symbols_is_the_same_run(
    compose_config, tmp_path
) -> None:
    """Its identity held its machine's folders; its config says which they were."""
    cfg = compose_config("experiment=kth_real", f"out_dir={tmp_path}")
    semantic, fingerprint, _ = run_identity(cfg)
    there = "/elsewhere/real-video"
    before = json.loads(json.dumps(semantic).replace("<paths.real_video>", there))
    record = {"status": "finished", "fingerprint": "before", "metrics": {"eval/accuracy": 0.5},
              "semantic_config": before, "config": {"paths": {"real_video": there}}}  # fmt: skip
    (tmp_path / "run.json").write_text(json.dumps(record))
    assert plan_attempt(tmp_path, fingerprint, semantic, "auto").action == "skip"
    record["config"]["paths"]["real_video"] = "/another/folder"  # not under its root: another run
    (tmp_path / "run.json").write_text(json.dumps(record))
    with pytest.raises(ConfigError, match=r"task\.data_root: '/elsewhere/real-video/kth' -> '<"):
        plan_attempt(tmp_path, fingerprint, semantic, "auto")


def test_raw_input_runs_from_before_standardised_became_the_default_keep_their_identity(
    compose_config, tmp_path
) -> None:
    """task.normalize_input came in false and became true: a raw run's identity is the one it
    had without the key, and a record that holds the key at false (experiment=kth_real's
    first sweep) is that same run, skipped, not refused."""
    raw = run_identity(compose_config("task=kth", "task.normalize_input=false"))
    before = run_identity(compose_config("task=kth", "~task.normalize_input"))
    assert raw[1:] == before[1:]  # fingerprint and cell
    assert run_identity(compose_config("task=kth"))[1] != raw[1]  # standardised: another run
    semantic, fingerprint, _ = run_identity(compose_config("experiment=kth_real"))
    held = json.loads(json.dumps(semantic))
    held["task"]["normalize_input"] = False
    record = {"status": "finished", "fingerprint": "with the key", "semantic_config": held,
              "metrics": {"eval/accuracy": 0.5}}  # fmt: skip
    (tmp_path / "run.json").write_text(json.dumps(record))
    assert plan_attempt(tmp_path, fingerprint, semantic, "auto").action == "skip"


def test_every_key_added_since_the_committed_runs_is_registered(compose_config) -> None:
    """One committed record per folder behind paper/, composed again from its own overrides with
    today's config: a key it did not have must be in ADDED_DEFAULTS (with the value it ran
    with), or adding it has silently given every old run another identity. Changed values are
    changed settings, not this test's business."""
    unregistered = set()
    registered = {key for keys in ADDED_DEFAULTS.values() for key in keys}
    for folder in (p for p in tables.COMMITTED_SCOPE if p.parts[1] == "learning"):
        path = next((REPO / folder).glob("*/run.json"))
        record = json.loads(path.read_text())
        overrides = [o.removeprefix("+") for o in record["overrides"]]  # added keys exist now
        semantic = run_identity(compose_config(*overrides))[0]
        held = {k: v for k, v in record["semantic_config"].items() if k in IDENTITY_KEYS}
        held = without_added_defaults(with_root_symbols(held, record["config"]["paths"]))
        new = flatten(semantic).keys() - flatten(held).keys()
        unregistered |= {
            f"{key} ({folder.name})" for key in new if key.split(".")[-1] not in registered
        }
    assert unregistered == set()


def test_job_folder_names_come_from_semantic_overrides() -> None:
    name = job_dirname(["seed=1", "task=kth", "threads=2", "resume=true", "task.logger=", "+x.y=1"])
    assert name == "seed=1,task=kth,x.y=1"
    assert job_dirname(["task.data_root=/data/KTH", "paths.cache=/s"]) == "task.data_root=_data_KTH"
    assert job_dirname([]) == "defaults"
    long = job_dirname([f"task.k{i}={'v' * 20}" for i in range(10)])
    assert len(long) == 120 and long != job_dirname([f"task.k{i}={'w' * 20}" for i in range(10)])


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("task.epochs=abc", "task.epochs='abc': expected an integer"),
        ("task.epochs=-1", "task.epochs=-1: expected a number >= 1"),
        ("task.batch_size=0", "task.batch_size=0: expected a number >= 1"),
        ("task.resize=[40,30,1]", "task.resize=[40, 30, 1]: expected a list of 2 values"),
        (
            "task.videos.train_fraction=1.5",
            "task.videos.train_fraction=1.5: expected a number < 1",
        ),
        ("task.logger=nope", "task.logger='nope': expected one of csv, tensorboard"),
        ("threads=0", "threads=0: expected a number >= 1"),
        ("resume=maybe", "resume='maybe': expected one of 'auto', True, False"),
    ],
)
def test_bad_settings_fail_before_any_work(compose_config, tmp_path, override, message) -> None:
    cache = tmp_path / "cache"
    cfg = compose_config(
        *TINY_KTH, f"out_dir={tmp_path / 'run'}", f"task.cache_dir={cache}", override
    )
    with pytest.raises(ConfigError) as error:
        run(cfg)
    assert str(error.value).startswith(message) and "\n" not in str(error.value)
    assert not cache.exists() and not (tmp_path / "run").exists()  # nothing decoded or written


def test_a_missing_logger_package_fails_before_any_work(
    compose_config, tmp_path, monkeypatch
) -> None:
    monkeypatch.setitem(edr.tasks.scalars.LOGGER_PACKAGES, "wandb", "edr_no_such_package")
    cfg = compose_config(*TINY_KTH, f"out_dir={tmp_path}", "task.logger=wandb")
    with pytest.raises(ConfigError, match=r"task.logger='wandb': expected the edr_no_such_package"):
        run(cfg)


def test_a_missing_data_root_names_the_layout_before_decoding(compose_config, tmp_path) -> None:
    cfg = compose_config(
        *TINY_KTH, f"out_dir={tmp_path / 'run'}", f"task.cache_dir={tmp_path / 'cache'}",
        f"task.data_root={tmp_path / 'KTH'}",
    )  # fmt: skip
    with pytest.raises(DataLayoutError, match=r"personXX_<action>_dY_uncomp\.avi"):
        run(cfg)
    assert not (tmp_path / "cache").exists()


def test_a_folder_refuses_another_config_and_names_the_keys(compose_config, tmp_path) -> None:
    common = (*TINY_KTH, f"out_dir={tmp_path}", f"task.cache_dir={tmp_path / 'cache'}")
    run(compose_config(*common, "task.epochs=1", "task.logger="))
    record = (tmp_path / "run.json").stat().st_mtime_ns
    assert run(compose_config(*common, "task.epochs=1")) is not None  # the logger is not semantic
    assert (tmp_path / "run.json").stat().st_mtime_ns == record  # skipped: not rewritten
    with pytest.raises(ConfigError, match=r"another config \(task\.epochs: 1 -> 2\)"):
        run(compose_config(*common, "task.epochs=2"))
    with pytest.raises(ConfigError, match="no checkpoint to resume"):
        run(compose_config(*common, "task.epochs=1", f"out_dir={tmp_path / 'typo'}", "resume=true"))


def test_atomic_path_leaves_nothing_behind_on_failure(tmp_path) -> None:
    target = tmp_path / "table.md"
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("killed")
    assert list(tmp_path.iterdir()) == []


def _fill(cache: str, _: int) -> list[float]:
    """One process's first run: generate the data set, decode every video into the cache."""
    root = resolve_root(None, partial(write_synthetic_kth, persons=4, scenarios=1, frames=6), cache)
    source = VideoSource(cache, size=(40, 30), gray=True)
    paths = sorted(root.rglob("*.avi"))
    source.cache.fill(paths, source.decode, desc="decoding")
    return [float(np.asarray(source(p)).mean()) for p in paths]


def test_two_processes_fill_the_same_empty_cache(tmp_path) -> None:
    with multiprocessing.get_context("spawn").Pool(2) as pool:
        first, second = pool.map(partial(_fill, str(tmp_path)), [0, 1])
    assert first == second and len(first) == 24
    assert not [p for p in tmp_path.rglob("*") if "partial" in p.name]
    assert len([p for p in tmp_path.iterdir() if p.name.startswith("write_synthetic_kth")]) == 1


def test_publish_dir_keeps_the_first_copy(tmp_path) -> None:
    root = publish_dir(tmp_path / "set", lambda d: (d / "a").write_text("1"))
    publish_dir(root, lambda d: (d / "a").write_text("2"))
    assert (root / "a").read_text() == "1" and [p.name for p in tmp_path.iterdir()] == ["set"]


def test_a_replaced_video_is_decoded_again(tmp_path) -> None:
    rng = np.random.default_rng(0)
    video = write_video(tmp_path / "v.avi", action_video("boxing", rng, 4, 48, 64))
    before = np.array(VideoSource(tmp_path / "cache", size=(32, 24), gray=True)(video))
    write_video(video, np.full((4, 48, 64), 200, np.uint8))
    os.utime(video, ns=(1, 1))  # even a copy that kept an old mtime has another size
    after = np.array(VideoSource(tmp_path / "cache", size=(32, 24), gray=True)(video))
    assert not np.array_equal(before, after) and after.mean() > 190


@pytest.mark.slow
def test_one_writer_per_run_folder(cli, tmp_path) -> None:
    """A second run on a folder another live process holds exits at once, naming the holder;
    a lock left by a process that is gone is taken over."""
    import json
    import socket
    import subprocess
    import sys
    import time

    from edr.store.folders import LOCK

    folder = tmp_path / "run"
    args = [str(Path(sys.executable).parent / "edr-run"), *TINY_KTH, "task.epochs=6",
            "task.clips_per_epoch=60", f"hydra.run.dir={folder}"]  # fmt: skip
    env = {**os.environ, "EDR_CACHE": str(tmp_path / "cache")}
    first = subprocess.Popen(args, cwd=tmp_path, env=env, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while not (folder / LOCK).exists():
            assert first.poll() is None and time.monotonic() < deadline
            time.sleep(0.05)
        second = cli(
            *["edr-run", *args[1:]], cwd=tmp_path, env={"EDR_CACHE": str(tmp_path / "cache")}
        )
        assert second.returncode == 2
        assert f"is held by process {first.pid} on {socket.gethostname()}" in second.stdout
    finally:
        first.wait(timeout=300)
    assert first.returncode == 0 and not (folder / LOCK).exists()  # released at the end
    steps = (folder / "logs/scalars/train/loss.csv").read_text().split()
    assert [s.split(",")[0] for s in steps] == ["1", "2", "3", "4", "5", "6"]  # one writer

    (folder / LOCK).write_text(json.dumps({"host": socket.gethostname(), "pid": 2**22 + 7}))
    again = cli(*["edr-run", *args[1:]], cwd=tmp_path, env={"EDR_CACHE": str(tmp_path / "cache")})
    assert again.returncode == 0, again.stderr[-2000:]
    said = again.stdout + again.stderr
    assert "taking over the lock of a process that is gone" in said  # then skips the finished run
    assert "finished already with this config: skipped" in said and not (folder / LOCK).exists()


def test_a_running_record_whose_process_is_gone_reads_as_interrupted(tmp_path) -> None:
    import json

    from edr.report.runs import load_runs

    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "run.json").write_text(json.dumps({"status": "running", "task": "kth"}))
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "run.json").write_text("{truncated")
    runs = load_runs([tmp_path]).set_index("record")
    assert runs.loc[str(tmp_path / "a" / "run.json"), "status"] == "interrupted"
    assert runs.loc[str(tmp_path / "b" / "run.json"), "status"] == "unreadable"
    from edr.report.runs import unfinished

    listed = unfinished(runs.reset_index(), "atari")  # every table lists unreadable records
    assert list(listed["record"]) == [str(tmp_path / "b" / "run.json")]


def test_a_run_that_sigterm_stopped_reads_as_interrupted_with_where_it_resumes(tmp_path) -> None:
    import json

    from edr.report.runs import load_runs

    stopped = {"status": "failed", "task": "atari", "error": "interrupted"}
    for name, extra in (("a", {"resumes_from": {"checkpoint": "checkpoint.pt", "env_steps": 65600}}),
                        ("b", {"resumes_from": None}), ("c", {"error": "RuntimeError: boom"})):  # fmt: skip
        (tmp_path / name).mkdir()
        (tmp_path / name / "run.json").write_text(json.dumps({**stopped, **extra}))
    runs = load_runs([tmp_path]).set_index("record")
    row = {n: runs.loc[str(tmp_path / n / "run.json")] for n in "abc"}
    assert row["a"]["status"] == "interrupted"
    assert row["a"]["error"].endswith("running it again resumes from env_steps 65,600")
    assert row["b"]["status"] == "interrupted" and row["b"]["error"].endswith("starts over")
    assert (row["c"]["status"], row["c"]["error"]) == ("failed", "RuntimeError: boom")


def test_a_truncated_record_names_itself_and_the_remedy(compose_config, tmp_path) -> None:
    (tmp_path / "run.json").write_text('{"status": "runn')
    with pytest.raises(ValueError, match=r"run\.json is not a readable run record .*resume=false"):
        run(compose_config(*TINY_KTH, f"out_dir={tmp_path}"))


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (("seed=-1",), "seed=-1: expected a number >= 0"),
        (("seed=99999999999",), "seed=99999999999: expected a number <= 4294967295"),
        (("optimizer.lr=-1",), "task.optimizer.lr=-1: expected a number > 0"),
        (("optimizer.lr=abc",), "task.optimizer.lr='abc': expected a number"),
        (("optimizer.momentum=-5",), "task.optimizer.momentum=-5: expected a number >= 0"),
        (("task.data_root=''",), "task.data_root='': expected a folder (an empty path"),
        (("task.crop=500",), "task.crop=500: expected at most the frames' short side, 30"),
        (("task=dvs_transfer", "task.dvs_root=/nope"), "task.dvs_root='/nope': expected an existing folder"),
        (("task=atari", "task.env.game=Pongg"), "task.env.game='Pongg': expected an ALE game (Pong"),
        (("task=atari", "representation.learnable=true"), "the Atari loop computes EDR inside the env"),
    ],
)  # fmt: skip
def test_a_bad_value_is_one_line_before_any_work(compose_config, overrides, message, tmp_path):
    task = () if any(o.startswith("task=") for o in overrides) else ("task=kth",)
    cache_key = "task.pretrain.cache_dir" if "task=dvs_transfer" in overrides else "task.cache_dir"
    cache = () if "task=atari" in overrides else (f"{cache_key}={tmp_path / 'cache'}",)
    cfg = compose_config(*task, "debug=tiny", *overrides, *cache, f"out_dir={tmp_path / 'run'}")
    with pytest.raises(ConfigError) as caught:
        run(cfg)
    assert message in str(caught.value) and "\n" not in str(caught.value)
    assert not list(tmp_path.rglob("*.avi"))  # nothing decoded or generated


def test_corrupt_checkpoint_csv_and_attempts_name_themselves_or_are_survived(tmp_path) -> None:
    from edr.store.checkpoints import UnreadableCheckpoint, load_checkpoint
    from edr.store.folders import log_attempt, outcomes_since
    from edr.tasks.scalars import rewind_csv_logs

    for content in (b"", b"PK\x03\x04 truncated zip"):
        (tmp_path / "checkpoint.pt").write_bytes(content)
        with pytest.raises(
            UnreadableCheckpoint, match=r"checkpoint\.pt cannot be read .*resume=false"
        ):
            load_checkpoint(tmp_path / "checkpoint.pt")
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "loss.csv").write_text("1,0.5\n2,0.4\n\x00\x00garbage\n3,0.3\n")
    rewind_csv_logs(logs, 2)  # a resume from step 2
    assert (logs / "loss.csv").read_text() == "1,0.5\n2,0.4\n"
    cell = tmp_path / "cell"
    cell.mkdir()
    (cell / "attempts.jsonl").write_text('{"at": "x", "unix": 1, "outc')  # cut short by a crash
    log_attempt(cell, "ran", "f00")
    assert outcomes_since(tmp_path, 0)["ran"] == 1


@pytest.mark.slow
def test_a_disk_that_fills_mid_run_leaves_no_half_written_file(tmp_path) -> None:
    """The kernel refuses every write past 64 KB (``RLIMIT_FSIZE``, as a full disk refuses
    them): the run fails naming the OS's error, its checkpoint is not left half-written, and
    the same command then runs it whole."""
    import resource
    import signal
    import subprocess
    import sys

    exe = str(Path(sys.executable).parent / "edr-run")
    args = [exe, *TINY_KTH, f"task.cache_dir={tmp_path / 'cache'}", "task.logger="]
    subprocess.run([*args, f"out_dir={tmp_path / 'warm'}"], check=True, capture_output=True)

    def full_disk() -> None:  # in the child: writes past 64 KB fail with EFBIG
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (64 * 1024, 64 * 1024))

    run_dir = tmp_path / "run"
    failed = subprocess.run([*args, f"out_dir={run_dir}"], preexec_fn=full_disk,
                            capture_output=True, text=True)  # fmt: skip
    said = failed.stdout + failed.stderr  # the one line goes to the log (stdout), no traceback
    assert (
        failed.returncode == 1 and "the write stopped part-way" in said and "Traceback" not in said
    )
    record = json.loads((run_dir / "run.json").read_text())
    assert record["status"] == "failed" and "checkpoint.pt" in record["error"]
    assert not [p.name for p in run_dir.rglob("*") if "partial" in p.name]  # nothing half-written
    assert not (run_dir / "checkpoint.pt").exists()
    again = subprocess.run([*args, f"out_dir={run_dir}"], capture_output=True, text=True)
    assert again.returncode == 0, again.stderr[-2000:]
    assert json.loads((run_dir / "run.json").read_text())["status"] == "finished"


def test_a_history_is_stored_once_compactly_and_read_as_the_old_json(tmp_path) -> None:
    rows = [{"env_steps": s, "train/score": -21.0 + s / 1e5} for s in range(0, 10**6, 1600)]
    new, old = tmp_path / "new", tmp_path / "old"
    write_json_atomic(new / "history.json.gz", rows)
    write_json_atomic(old / "history.json", rows)
    assert read_history(new) == read_history(old) == rows
    assert (new / "history.json.gz").stat().st_size * 5 < (old / "history.json").stat().st_size
    # the same rows, the same bytes (no time stamp): a re-render changes nothing
    first = (new / "history.json.gz").read_bytes()
    assert write_json_atomic(new / "history.json.gz", rows).read_bytes() == first
    assert read_history(tmp_path) == []  # a run without a history
    (new / "history.json.gz").write_bytes(first[:40])
    with pytest.raises(BadRecord, match=r"history\.json\.gz is not gzip-compressed whole"):
        read_history(new)
