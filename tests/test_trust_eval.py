"""edr-eval never harms the folder it scores (issue 71, items 1 and 4; issue 68, item 3): a run
folder is checked before anything reads or writes it, each class of bad folder is one line
naming the file, what is wrong and a remedy edr-eval accepts, before any env is built, with
the folder byte for byte as it was; scores go beside the run's, in a file named for the
evaluation; the same seed gives the same scores. And a stopped run's record says
``interrupted``, an Atari record's config holds the groups its task uses. edr-run resuming a
stopped run checks its record and checkpoint the same way, before it rewrites the record."""

from __future__ import annotations

import datetime
import json
import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import torch

import edr.tasks.atari as atari
from edr.evaluate import main as evaluate_main
from edr.models.paac import PAACNetwork
from edr.report.runs import load_runs
from edr.run import run
from edr.store.folders import LOCK, process_identity
from edr.store.identity import run_identity
from test_adversarial_records import SRC, needs_mount

TINY = ("task=atari", "debug=tiny", "task.env.inputs=fdr", "task.env_steps=20",
        "task.evaluation.plays=1", "task.evaluation.max_steps=20", "task.network.precision=float32",
        "task.logger=")  # fmt: skip


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> tuple[Path, Any]:
    """One tiny finished Atari run (one update of 4 envs), for every test here; its config."""
    from conftest import _compose

    out = tmp_path_factory.mktemp("atari") / "run"
    cfg = _compose(*TINY, f"out_dir={out}")
    run(cfg)
    return out, cfg


@pytest.fixture
def folder(trained, tmp_path) -> Path:
    """A copy of the trained run's folder, to tamper with."""
    return Path(shutil.copytree(trained[0], tmp_path / "run"))


def _files(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder``, by its path there, with its bytes."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


@pytest.fixture
def no_env(monkeypatch) -> None:
    """Building an env fails the test: a refusal comes before any."""

    def built(**kwargs: Any) -> None:
        raise AssertionError("an env was built before the refusal")

    monkeypatch.setattr(atari, "make_atari_env", built)


def _refused(folder: Path, capsys, *argv: str) -> str:
    """``edr-eval folder argv``: refused (exit 2) in one line, the folder untouched; the line."""
    before = _files(folder)
    with pytest.raises(SystemExit) as stopped:
        evaluate_main([str(folder), *argv])
    line = capsys.readouterr().err
    assert stopped.value.code == 2, line
    assert line.startswith("edr-eval: ") and line.count("\n") == 1, line
    assert "resume=false" not in line and "weights_only" not in line, line
    assert _files(folder) == before
    return line


def _tamper(folder: Path, change) -> None:
    record = json.loads((folder / "run.json").read_text())
    change(record)
    (folder / "run.json").write_text(json.dumps(record))


def _env(record: dict) -> dict:
    return record["config"]["task"]["env"]


@pytest.mark.parametrize(
    ("change", "said"),
    [
        (lambda r: r.pop("seed"), "seed=None: expected an integer"),
        (lambda r: r.update(seed="zero"), "seed='zero': expected an integer"),
        (lambda r: r.update(status="done"), "status='done': expected one of"),
        (lambda r: _env(r).update(frame_stack=0), "config.task.env.frame_stack=0: expected"),
        (lambda r: r["config"]["task"]["evaluation"].update(max_steps=0),
         "config.task.evaluation.max_steps=0: expected"),
        (lambda r: _env(r).update(game="Joust2"), "config.task.env.game='Joust2': expected an ALE"),
        (lambda r: _env(r).update(_target_="edr.rl.settings.NetworkSettings"),
         "config.task.env.game: not a setting of edr.rl.settings.NetworkSettings"),
        (lambda r: _env(r).update(_target_="os.system"), "config.task.env._target_=os.system"),
        (lambda r: r["config"].pop("task"), "has no config.task"),
    ],
)  # fmt: skip
def test_a_tampered_record_is_refused_before_any_env(change, said, folder, no_env, capsys) -> None:
    _tamper(folder, change)
    line = _refused(folder, capsys)
    assert f"{folder / 'run.json'}: " in line or f"{folder / 'run.json'} " in line
    assert said in line, line


def test_a_folder_a_live_run_holds_is_refused(folder, no_env, capsys) -> None:
    holder = {"host": socket.gethostname(), "pid": os.getpid(),
              "process": process_identity(os.getpid())}  # fmt: skip
    (folder / LOCK).write_text(json.dumps(holder))
    line = _refused(folder, capsys)
    assert f"{folder / LOCK}: a live run holds this folder" in line


@pytest.mark.slow  # a command of its own (about 10 s)
@needs_mount
def test_a_read_only_folder_is_refused_before_any_game(folder) -> None:
    before = _files(folder)
    command = (f"mount --bind {folder} {folder} && mount -o remount,ro,bind {folder} && "
               f"{sys.executable} -m edr.evaluate {folder}")  # fmt: skip
    said = subprocess.run(["unshare", "-m", "sh", "-c", command], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": SRC}, timeout=300)  # fmt: skip
    assert said.returncode == 2, said.stderr[-2000:]
    (line,) = said.stderr.strip().splitlines()
    assert line.startswith(f"edr-eval: {folder}: expected a folder this process can write")
    assert "score a copy of the folder" in line and "evaluation" not in said.stdout
    assert _files(folder) == before


class _Foreign:
    """Pickled, an object ``torch.load(weights_only=True)`` refuses to build."""

    def __reduce__(self):
        return (datetime.date, (2020, 1, 1))


# network.pt files that are not a run's network, and what a refusal of each says
FOREIGN_NETWORKS = [
    (torch.zeros(3), "network.pt holds Tensor, not what edr-run writes"),
    ({"model": {}, "epoch": 3}, "network.pt: 'state_dict' is missing, expected dict"),
    ({"state_dict": {"w": torch.zeros(2)}, "arguments": {}},
     "network.pt holds the weights of another network than its run.json describes"),
    ({"x": _Foreign()}, "network.pt cannot be read (it holds Python objects"),
]  # fmt: skip


@pytest.mark.parametrize(("payload", "said"), FOREIGN_NETWORKS)
def test_a_foreign_network_file_is_refused(payload, said, folder, capsys) -> None:
    torch.save(payload, folder / "network.pt")
    line = _refused(folder, capsys)
    assert said in line and "score " in line, line


def test_the_other_inputs_network_is_refused(folder, capsys) -> None:
    saved = torch.load(folder / "network.pt", weights_only=True)
    arguments = {**saved["arguments"], "in_channels": 20}  # FDR+EDR: 5 channels a frame
    other = PAACNetwork(**{k: v for k, v in arguments.items() if k != "precision"})
    torch.save({"state_dict": other.state_dict(), "arguments": arguments}, folder / "network.pt")
    line = _refused(folder, capsys)
    # its first layer normalises 5 channels a frame, this run's network 3
    assert "network.pt: normalise.weight is (5,), where the network its run.json" in line
    assert "takes (3,) (another input, game or network?)" in line


def test_a_foreign_checkpoint_of_a_stopped_run_is_refused(folder, capsys) -> None:
    _tamper(folder, lambda r: r.update(status="interrupted"))
    torch.save({"network": torch.zeros(3), "env_steps": 20}, folder / "checkpoint.pt")
    line = _refused(folder, capsys)
    assert "checkpoint.pt: 'network' is Tensor, expected dict" in line


def test_the_same_seed_scores_the_same_beside_the_runs_own_evaluation(
    folder, capsys, monkeypatch
) -> None:
    sampled: list[torch.Tensor] = []  # every action the network drew, in order
    multinomial = torch.multinomial

    def recorded(*args: Any, **kwargs: Any) -> torch.Tensor:
        sampled.append(multinomial(*args, **kwargs))
        return sampled[-1]

    monkeypatch.setattr(torch, "multinomial", recorded)
    own = _files(folder)
    first = atari.evaluate_checkpoint(folder, plays=2, seed=3)
    first_actions, sampled[:] = torch.cat(sampled), []
    scored = folder / "network_eval_seed3_plays2.json"
    saved = json.loads(scored.read_text())
    scores = saved.pop("scores")
    assert first["eval/seed"] == 3 and len(scores) == 2 and saved == first
    evaluate_main([str(folder), "--plays", "2", "--seed", "3"])  # the same network, seed, games
    assert json.loads(capsys.readouterr().out) == first
    assert json.loads(scored.read_text())["scores"] == scores
    assert torch.equal(torch.cat(sampled), first_actions)  # action for action
    sampled[:] = []
    atari.evaluate_checkpoint(folder, plays=2, seed=4)
    assert not torch.equal(torch.cat(sampled), first_actions)
    written = {scored.name, "network_eval_seed4_plays2.json"}
    assert set(_files(folder)) - set(own) == written  # nothing else written, nothing changed
    assert all(_files(folder)[name] == data for name, data in own.items())
    # a record that says stopped, in a folder whose finished run dropped its checkpoint.pt: its
    # network.pt is scored, and still none of the run's own files is written
    assert not (folder / "checkpoint.pt").exists()
    _tamper(folder, lambda r: r.update(status="interrupted"))
    own = _files(folder)
    stopped = atari.evaluate_checkpoint(folder, plays=1)  # the run's own seed, 0
    assert stopped["eval/seed"] == 0 and stopped["train/env_steps"] == 20
    assert set(_files(folder)) - set(own) == {"network_eval_seed0_plays1.json"}


def test_a_bad_seed_is_one_line(folder, capsys) -> None:
    with pytest.raises(SystemExit) as stopped:
        evaluate_main([str(folder), "--seed", "-1"])
    assert stopped.value.code == 2
    assert capsys.readouterr().err == "edr-eval: --seed=-1: expected a number >= 0\n"


def test_an_atari_record_holds_the_groups_its_task_uses(trained) -> None:
    out, cfg = trained
    record = json.loads((out / "run.json").read_text())
    assert "backbone" not in record["config"] and "optimizer" not in record["config"]
    assert record["config"]["representation"]["_target_"] == "edr.representations.EDR"
    assert record["config"]["paths"] and record["config"]["seed"] == 0
    assert record["fingerprint"] == run_identity(cfg)[1]  # from seed and task, as before


def test_stopped_runs_read_as_interrupted_old_and_new(tmp_path) -> None:
    resumes = {"checkpoint": "checkpoint.pt", "env_steps": 20}
    for name, record in (("old", {"status": "failed", "error": "interrupted"}),
                         ("new", {"status": "interrupted"})):  # fmt: skip
        (tmp_path / name).mkdir()
        (tmp_path / name / "run.json").write_text(
            json.dumps({**record, "task": "atari", "resumes_from": resumes})
        )
    runs = load_runs([tmp_path]).set_index("run_dir")
    for name in ("old", "new"):
        row = runs.loc[str(tmp_path / name)]
        assert row["status"] == "interrupted"
        assert (
            row["error"] == "stopped by Ctrl-C or SIGTERM: running it again resumes from "
            "env_steps 20"
        )


# ---- edr-run resuming a stopped run: the same checks, before its record is rewritten ---------
def _stopped(folder: Path, cfg: Any) -> None:
    """``folder``'s record says interrupted, beside the checkpoint train_paac would have left
    (its finished run dropped its own): its network's weights, fresh optimizer and schedule."""
    from hydra.utils import instantiate

    from edr.rl.learner import Learner
    from edr.rl.phases import PhaseClock
    from edr.store.checkpoints import save_checkpoint

    task = instantiate(cfg.task).keywords
    saved = torch.load(folder / "network.pt", weights_only=True)
    network = PAACNetwork(**{k: v for k, v in saved["arguments"].items() if k != "precision"})
    network.load_state_dict(saved["state_dict"])
    record = json.loads((folder / "run.json").read_text())
    learner = Learner(network, task["loss"], task["optim"], 20, PhaseClock())
    save_checkpoint(folder / "checkpoint.pt", learner.parts, env_steps=20, history=[],
                    precision="float32", data_fingerprint=record["data"]["fingerprint"])  # fmt: skip
    _tamper(folder, lambda r: r.update(status="interrupted"))


def _resume_refused(folder: Path) -> str:
    """``edr-run`` of the folder's own config, resuming it: refused in one line advising an
    edr-run option, the folder byte for byte as it was; the line."""
    from conftest import _compose
    from edr.checks.config import ConfigError
    from edr.store.checkpoints import UnreadableCheckpoint

    before = _files(folder)
    with pytest.raises((ConfigError, UnreadableCheckpoint)) as refused:
        run(_compose(*TINY, f"out_dir={folder}"))
    line = str(refused.value)
    assert "\n" not in line and "resume=false" in line, line
    assert _files(folder) == before
    return line


def test_the_check_takes_the_checkpoint_train_paac_writes(trained, folder) -> None:
    """(A whole resume through the check: test_atari's tiny Pong run, stopped and resumed.)"""
    from hydra.utils import instantiate

    _stopped(folder, trained[1])
    atari.check_resumable(folder, **instantiate(trained[1].task).keywords)


def _without(key: str):
    """A checkpoint's payload without ``key``."""
    return lambda state: {k: v for k, v in state.items() if k != key}


@pytest.mark.parametrize(
    ("change", "said"),
    [
        (lambda state: torch.zeros(3), "checkpoint.pt holds Tensor, not what edr-run writes"),
        (_without("history"), "checkpoint.pt: 'history' is missing, expected list"),
        (lambda state: {**state, "network": {"w": torch.zeros(2)}},
         "checkpoint.pt holds the weights of another network than its run.json describes"),
        (lambda state: {**state, "network": {**state["network"], "normalise.weight": torch.ones(5)}},
         "checkpoint.pt: normalise.weight is (5,), where the network its run.json describes"),
        (lambda state: {"x": _Foreign()}, "checkpoint.pt cannot be read (it holds Python objects"),
    ],
    ids=["a bare tensor", "no history", "another network's keys",
         "the other input's first layer", "a pickled object"],
)  # fmt: skip
def test_a_foreign_checkpoint_is_refused_before_the_run_resumes(change, said, trained, folder):
    _stopped(folder, trained[1])
    state = torch.load(folder / "checkpoint.pt", weights_only=True)
    torch.save(change(state), folder / "checkpoint.pt")
    line = _resume_refused(folder)
    assert said in line and str(folder / "checkpoint.pt") in line, line


@pytest.mark.parametrize(
    ("change", "said"),
    [
        (lambda r: r.update(status="done"), "run.json: status='done': expected one of"),
        (lambda r: r.update(seed="zero"), "run.json: seed='zero': expected an integer"),
        (lambda r: r.update(attempt="x"), "run.json: attempt='x': expected an integer"),
    ],
    ids=["status", "seed", "attempt"],
)  # fmt: skip
def test_a_tampered_record_is_refused_before_the_run_resumes(
    change, said, trained, folder, no_env
) -> None:
    _stopped(folder, trained[1])
    _tamper(folder, change)
    assert said in _resume_refused(folder)


def test_a_folder_a_live_run_holds_is_not_resumed(trained, folder, no_env) -> None:
    from conftest import _compose
    from edr.checks.config import ConfigError

    _stopped(folder, trained[1])
    holder = {"host": socket.gethostname(), "pid": os.getpid(),
              "process": process_identity(os.getpid())}  # fmt: skip
    (folder / LOCK).write_text(json.dumps(holder))
    before = _files(folder)
    with pytest.raises(ConfigError) as refused:
        run(_compose(*TINY, f"out_dir={folder}"))
    said = str(refused.value)
    assert f"is held by process {os.getpid()}" in said and f"({folder / LOCK}): wait" in said
    assert _files(folder) == before


# ---- load_network (a library call) checks the folder as edr-eval does --------------------------
def _load_refused(folder: Path) -> str:
    """``atari.load_network(folder)`` refused in one line naming a file of the folder, with a
    remedy that says to load something, the folder byte for byte as it was; the line."""
    from edr.checks.config import ConfigError
    from edr.store.checkpoints import UnreadableCheckpoint
    from edr.store.records import UnreadableRecord
    from edr.tasks.rebuild import UntrustedRecord

    before = _files(folder)
    with pytest.raises(
        (ConfigError, UnreadableRecord, UnreadableCheckpoint, UntrustedRecord)
    ) as refused:
        atari.load_network(folder)
    line = str(refused.value)
    assert "\n" not in line and str(folder) in line and "load " in line, line
    assert "resume=false" not in line and "weights_only" not in line, line
    assert _files(folder) == before
    return line


def test_load_network_loads_a_sound_folder(folder) -> None:
    network = atari.load_network(folder)
    saved = torch.load(folder / "network.pt", weights_only=True)
    assert network.precision == "float32"
    for key, tensor in network.state_dict().items():
        assert torch.equal(tensor, saved["state_dict"][key]), key


@pytest.mark.parametrize(
    ("change", "said"),
    [
        (lambda r: r.update(status="done"), "run.json: status='done': expected one of"),
        (lambda r: r.update(status=3), "run.json: status=3: expected one of"),
        (lambda r: r.pop("seed"), "run.json: seed=None: expected an integer"),
        (lambda r: r.update(seed="zero"), "run.json: seed='zero': expected an integer"),
        (lambda r: r.update(seed=[0]), "run.json: seed=[0]: expected an integer"),
        (lambda r: r.update(attempt="x"), "run.json: attempt='x': expected an integer"),
        (lambda r: r.update(task="kth"), "is a kth run: load_network reads atari runs only"),
        (lambda r: _env(r).update(frame_stack=0), "config.task.env.frame_stack=0: expected"),
        (lambda r: _env(r).update(_target_="os.system"), "config.task.env._target_=os.system"),
        (lambda r: r["config"].update(task=[1, 2]), "run.json has no config.task"),
    ],
    ids=["status", "status a number", "no seed", "seed a word", "seed a list", "attempt",
         "another task", "frame_stack", "a foreign target", "config.task a list"],
)  # fmt: skip
def test_load_network_refuses_a_tampered_record(change, said, folder, no_env) -> None:
    _tamper(folder, change)
    line = _load_refused(folder)
    assert str(folder / "run.json") in line and said in line, line


def test_load_network_refuses_a_record_that_is_not_one_and_a_held_folder(
    trained, folder, no_env
) -> None:
    (folder / "run.json").write_text("[1, 2]")
    assert "run.json holds list, not a run record: load a run folder" in _load_refused(folder)
    (folder / "run.json").write_text("")
    assert "run.json is not a readable run record" in _load_refused(folder)
    shutil.copy(trained[0] / "run.json", folder / "run.json")
    holder = {"host": socket.gethostname(), "pid": os.getpid(),
              "process": process_identity(os.getpid())}  # fmt: skip
    (folder / LOCK).write_text(json.dumps(holder))
    assert f"{folder / LOCK}: a live run holds this folder and writes into it: load it once" in (
        _load_refused(folder)
    )


@pytest.mark.parametrize(
    ("payload", "said"),
    [
        *FOREIGN_NETWORKS,
        ({"state_dict": {}, "arguments": [1]}, "network.pt: 'arguments' is list, expected dict"),
        (b"", "network.pt cannot be read"),
        ("half", "network.pt cannot be read"),
    ],
    ids=["a bare tensor", "no state_dict", "another network's keys", "a pickled object",
         "arguments a list", "an empty file", "cut in half"],
)  # fmt: skip
def test_load_network_refuses_a_foreign_network_file(payload, said, folder) -> None:
    path = folder / "network.pt"
    if payload == "half":
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    elif isinstance(payload, bytes):
        path.write_bytes(payload)
    else:
        torch.save(payload, path)
    line = _load_refused(folder)
    assert said in line and ("load the file with the run folder" in line
                             or "load a run folder edr-run wrote" in line), line  # fmt: skip


def test_load_network_refuses_the_other_inputs_network_and_a_recognition_model(folder) -> None:
    saved = torch.load(folder / "network.pt", weights_only=True)
    arguments = {**saved["arguments"], "in_channels": 20}  # FDR+EDR: 5 channels a frame
    other = PAACNetwork(**{k: v for k, v in arguments.items() if k != "precision"})
    torch.save({"state_dict": other.state_dict(), "arguments": arguments}, folder / "network.pt")
    line = _load_refused(folder)
    assert "network.pt: normalise.weight is (5,), where the network its run.json" in line
    # a recognition run's model.pt, as it saves it: its state dict and backbone's arguments
    torch.save({"state_dict": {"backbone.fc.weight": torch.zeros(6, 4)}, "online": True,
                "backbone_args": {"in_channels": 2}}, folder / "network.pt")  # fmt: skip
    assert "network.pt: 'arguments' is missing, expected dict" in _load_refused(folder)


# ---- a refused resume through Hydra: run.log and .hydra/ wait for the folder's check ----------
@pytest.fixture
def edr_run():
    """``edr_run(*argv)``: edr-run in a process of its own, Hydra's job logging and files as the
    command has them (in this process Hydra's logging setup would close pytest's own log
    handlers); its exit status, its output printed here for capsys."""

    def call(*argv: str) -> int:
        done = subprocess.run(
            [sys.executable, "-c", "from edr.run import main; main()", *argv],
            capture_output=True, text=True, timeout=600,
        )  # fmt: skip
        print(done.stdout + done.stderr)
        return done.returncode

    return call


def _snapshot(folder: Path) -> dict[str, tuple[bytes, int]]:
    """Every file under ``folder`` with its bytes and modification time."""
    return {str(p.relative_to(folder)): (p.read_bytes(), p.stat().st_mtime_ns)
            for p in folder.rglob("*") if p.is_file()}  # fmt: skip


def _earlier_attempt(folder: Path) -> None:
    """``folder``'s run.log and .hydra/ as an earlier attempt through Hydra left them."""
    (folder / "run.log").write_text("[earlier] the first attempt's log\n")
    (folder / ".hydra").mkdir()
    for name in ("config.yaml", "hydra.yaml", "overrides.yaml"):
        (folder / ".hydra" / name).write_text(f"# the first attempt's {name}\n")


def _held(folder: Path) -> None:
    holder = {"host": socket.gethostname(), "pid": os.getpid(),
              "process": process_identity(os.getpid())}  # fmt: skip
    (folder / LOCK).write_text(json.dumps(holder))


@pytest.mark.parametrize(
    ("spoil", "said"),
    [
        (lambda f: torch.save({"network": torch.zeros(3)}, f / "checkpoint.pt"),
         "checkpoint.pt: 'network' is Tensor, expected dict"),
        (lambda f: _tamper(f, lambda r: r.update(attempt="x")),
         "run.json: attempt='x': expected an integer"),
        (_held, "is held by process"),
    ],
    ids=["a foreign checkpoint", "a tampered record", "a live lock"],
)  # fmt: skip
def test_a_refused_resume_leaves_its_folder_byte_for_byte(
    spoil, said, trained, folder, edr_run, capsys
) -> None:
    _stopped(folder, trained[1])
    _earlier_attempt(folder)
    spoil(folder)
    before = _snapshot(folder)
    assert edr_run(*TINY, f"hydra.run.dir={folder}") == 2
    assert _snapshot(folder) == before  # run.log, .hydra/ and the lock's file included
    (line,) = [line for line in capsys.readouterr().out.splitlines() if "[ERROR]" in line]
    assert said in line, line


@pytest.mark.slow  # a resume through Hydra, to its evaluation game (about 5 s)
def test_a_resume_that_passes_writes_its_log_and_hydras_files(trained, folder, edr_run) -> None:
    """The lines said before the check (the checkpoint loaded) land in run.log once it passed,
    after the earlier attempt's; .hydra/ says this attempt's config."""
    _stopped(folder, trained[1])
    _earlier_attempt(folder)
    assert edr_run(*TINY, f"hydra.run.dir={folder}", "threads=1") == 0
    log = (folder / "run.log").read_text().splitlines()
    assert log[0] == "[earlier] the first attempt's log"
    loading = next(i for i, line in enumerate(log) if "loading" in line and "checkpoint.pt" in line)
    resuming = next(i for i, line in enumerate(log) if "resuming from its checkpoint" in line)
    assert loading < resuming and "atari finished" in log[-1]
    assert "threads=1" in (folder / ".hydra" / "overrides.yaml").read_text()
    assert "task:" in (folder / ".hydra" / "config.yaml").read_text()
    assert "job_logging" in (folder / ".hydra" / "hydra.yaml").read_text()
    assert json.loads((folder / "run.json").read_text())["attempt"] == 2


@pytest.mark.slow  # a sweep through Hydra (about 3 s)
def test_a_refused_sweep_cell_leaves_its_folder_and_a_new_folder_keeps_its_log(
    trained, folder, edr_run, tmp_path, capsys
) -> None:
    """In a sweep, the refused cell's folder stays as it was; a cell refused in a folder of its
    own (new, empty: resume=true with nothing to resume) says why in its run.log, as before."""
    from edr.store.identity import job_dirname

    sweep = tmp_path / "sweep"
    cells = {seed: sweep / job_dirname([*TINY, f"seed={seed}"]) for seed in (0, 1)}
    shutil.copytree(folder, cells[0])
    _stopped(cells[0], trained[1])
    _earlier_attempt(cells[0])
    torch.save(torch.zeros(3), cells[0] / "checkpoint.pt")
    before = _snapshot(cells[0])
    assert edr_run("-m", *TINY, "seed=0,1", "resume=true", f"hydra.sweep.dir={sweep}") == 1
    assert _snapshot(cells[0]) == before
    said = capsys.readouterr().out
    assert "checkpoint.pt holds Tensor, not what edr-run writes" in said
    assert "0 ran, 0 failed, 0 interrupted, 2 refused" in said, said[-2000:]
    (line,) = (cells[1] / "run.log").read_text().splitlines()
    assert "resume=true but" in line and "holds no checkpoint" in line


def test_the_run_log_writes_at_once_in_a_new_folder_and_waits_in_one_that_holds_files(tmp_path):
    import logging

    from edr.store.job_files import RunLog

    def said(handler: RunLog, message: str) -> None:
        handler.handle(logging.makeLogRecord({"msg": message}))
        handler.flush()

    new = tmp_path / "new"
    new.mkdir()  # as Hydra makes a run's folder
    handler = RunLog(str(new / "run.log"))
    said(handler, "a new folder's first line")
    assert (new / "run.log").read_text() == "a new folder's first line\n"
    handler.close()
    old = tmp_path / "old"
    old.mkdir()
    (old / "run.json").write_text("{}")
    refused = RunLog(str(old / "run.log"))
    said(refused, "refused")
    refused.close()  # the run refused: its lines dropped, the file never made
    assert sorted(p.name for p in old.iterdir()) == ["run.json"]
    checked = RunLog(str(old / "run.log"))
    said(checked, "before the check")
    assert not (old / "run.log").exists()
    checked.start_writing()
    said(checked, "after it")
    checked.close()
    assert (old / "run.log").read_text() == "before the check\nafter it\n"
