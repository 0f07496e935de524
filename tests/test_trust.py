"""A run folder from someone else is safe to load: its record builds only the suite's own parts,
and never imports a module it names unless the user says so."""

from __future__ import annotations

import datetime
import json
import os
import pickle
import shutil
import socket
from pathlib import Path

import pytest
import torch

from edr.checks.config import ConfigError
from edr.run import run
from edr.store.checkpoints import UnreadableCheckpoint
from edr.store.folders import LOCK, process_identity
from edr.tasks.atari import evaluate_checkpoint
from edr.tasks.rebuild import UntrustedRecord, check_targets
from edr.tasks.recognition import load_model


class _Payload:
    """Unpickling this writes a file: what a crafted pickle would do, harmlessly."""

    def __init__(self, marker: str) -> None:
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


@pytest.fixture(scope="module")
def kth_run(tmp_path_factory, compose_config):
    out = tmp_path_factory.mktemp("kth")
    run(compose_config("task=kth", "debug=tiny", f"out_dir={out}",
                       f"task.cache_dir={out / 'cache'}", "task.logger="))  # fmt: skip
    return out


@pytest.fixture(scope="module")
def compose_config():
    from conftest import _compose

    return _compose


def _crafted(run_dir, key: str, node: dict) -> None:
    record = json.loads((run_dir / "run.json").read_text())
    record["config"][key] = node
    (run_dir / "run.json").write_text(json.dumps(record))


def test_a_sound_record_loads(kth_run) -> None:
    assert sum(p.numel() for p in load_model(kth_run).parameters()) > 0


@pytest.mark.parametrize(
    ("key", "node"),
    [
        ("representation", {"_target_": "torch.load", "f": "PICKLE", "weights_only": False}),
        ("representation", {"_target_": "numpy.load", "file": "PICKLE", "allow_pickle": True}),
        ("backbone", {"_target_": "builtins.open", "file": "MARKER", "mode": "w"}),
        ("backbone", {"_target_": "shutil.copyfile", "src": "PICKLE", "dst": "MARKER"}),
        ("backbone", {"_target_": "edr.store.atomic.write_text_atomic", "path": "MARKER", "text": "x"}),
        ("backbone", {"_target_": "edr.models.LeNet", "_partial_": True,
                      "extra": {"_target_": "os.system", "command": "touch MARKER"}}),
    ],
)  # fmt: skip
def test_a_crafted_record_is_refused_before_anything_runs(key, node, kth_run, tmp_path) -> None:
    pickled, marker = tmp_path / "payload.pkl", tmp_path / "marker"
    pickled.write_bytes(pickle.dumps(_Payload(str(marker))))
    text = json.dumps(node).replace("PICKLE", str(pickled)).replace("MARKER", str(marker))
    saved = (kth_run / "run.json").read_text()
    try:
        _crafted(kth_run, key, json.loads(text))
        with pytest.raises(UntrustedRecord, match=r"config\.\w+.*_target_="):
            load_model(kth_run)
    finally:
        (kth_run / "run.json").write_text(saved)
    assert not marker.exists()


# ---- load_model checks the folder as edr-eval does (edr.tasks.run_folder) -------------------
def _copy(kth_run: Path, tmp_path: Path) -> Path:
    """The files load_model reads, in a folder of their own to tamper with."""
    folder = tmp_path / "run"
    folder.mkdir()
    for name in ("run.json", "model.pt"):
        shutil.copy(kth_run / name, folder / name)
    return folder


def _load_refused(folder: Path) -> str:
    """``load_model(folder)`` refused in one line naming the folder's file, with a remedy
    (load ...), nothing in the folder changed; the line."""
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    with pytest.raises((ConfigError, UnreadableCheckpoint)) as refused:
        load_model(folder)
    line = str(refused.value)
    assert "\n" not in line and str(folder) in line and "load " in line, line
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
    return line


@pytest.mark.parametrize(
    ("change", "said"),
    [
        (lambda saved: torch.zeros(3), "model.pt holds Tensor, not what edr-run writes"),
        (lambda saved: {k: v for k, v in saved.items() if k != "online"},
         "model.pt: 'online' is missing, expected bool"),
        (lambda saved: {**saved, "state_dict": {"w": torch.zeros(2)}},
         "model.pt holds the weights of another network than its run.json describes"),
        (lambda saved: {**saved, "backbone_args": {**saved["backbone_args"], "num_classes": 7}},
         "where the network its run.json describes takes (7,"),
        (lambda saved: {**saved, "backbone_args": {"nope": 1}},
         "model.pt: backbone_args={'nope': 1} do not build config.backbone"),
        (lambda saved: {"x": datetime.date(2020, 1, 1)},
         "model.pt cannot be read (it holds Python objects"),
    ],
    ids=["a bare tensor", "no online", "another network's keys", "another class count",
         "another backbone's arguments", "a pickled object"],
)  # fmt: skip
def test_load_model_refuses_a_foreign_model_file(change, said, kth_run, tmp_path) -> None:
    folder = _copy(kth_run, tmp_path)
    saved = torch.load(folder / "model.pt", weights_only=True)
    torch.save(change(saved), folder / "model.pt")
    assert said in _load_refused(folder)


@pytest.mark.parametrize(
    ("change", "said"),
    [
        (lambda r: r.update(status="done"), "run.json: status='done': expected one of"),
        (lambda r: r.update(seed="zero"), "run.json: seed='zero': expected an integer"),
        (lambda r: r.update(task="atari"), "is a atari run: load_model reads kth or ucf101 runs"),
        (lambda r: r["config"].pop("backbone"), "run.json has no config.backbone"),
    ],
    ids=["status", "seed", "task", "no backbone"],
)  # fmt: skip
def test_load_model_refuses_a_tampered_record(change, said, kth_run, tmp_path) -> None:
    folder = _copy(kth_run, tmp_path)
    record = json.loads((folder / "run.json").read_text())
    change(record)
    (folder / "run.json").write_text(json.dumps(record))
    assert said in _load_refused(folder)


def test_load_model_refuses_a_folder_a_live_run_holds(kth_run, tmp_path) -> None:
    folder = _copy(kth_run, tmp_path)
    holder = {"host": socket.gethostname(), "pid": os.getpid(),
              "process": process_identity(os.getpid())}  # fmt: skip
    (folder / LOCK).write_text(json.dumps(holder))
    assert f"{folder / LOCK}: a live run holds this folder" in _load_refused(folder)


def test_an_atari_record_builds_only_a_partial_task_and_imports_no_named_module(tmp_path) -> None:
    record = {
        "status": "finished",
        "seed": 0,
        "config": {"task": {"_target_": "numpy.load", "file": "x.npy", "allow_pickle": True}},
    }
    (tmp_path / "run.json").write_text(json.dumps(record))
    (tmp_path / "checkpoint.pt").write_bytes(b"")
    with pytest.raises(UntrustedRecord, match=r"config\.task\._target_=numpy\.load"):
        evaluate_checkpoint(tmp_path)
    record["config"]["task"] = {"_target_": "edr.tasks.atari.train_paac", "out_dir": "x"}
    (tmp_path / "run.json").write_text(json.dumps(record))
    with pytest.raises(UntrustedRecord, match="only as a partial"):
        evaluate_checkpoint(tmp_path)
    record["config"]["task"] = {
        "_target_": "edr.tasks.atari.train_paac", "_partial_": True,
        "env": {"_target_": "edr.rl.settings.EnvSettings", "env_id": "Mine-v0", "preset": "none",
                "env_module": "some_module_that_would_run_code"},
    }  # fmt: skip
    (tmp_path / "run.json").write_text(json.dumps(record))
    with pytest.raises(UntrustedRecord, match="--trust-env-module"):
        evaluate_checkpoint(tmp_path)


def test_the_suites_own_parts_pass() -> None:
    check_targets({"_target_": "edr.representations.EDR", "half_lives": [3.8]}, "representation")
    check_targets({"_target_": "torch.optim.Adam", "_partial_": True, "lr": 1e-3}, "optimizer")
    check_targets({"_target_": "edr.rl.settings.EvalSettings", "plays": 2}, "evaluation")


# ---- a recognition run's resume checks its checkpoint against the model, before any work ------
def _kth(kth_run: Path, folder: Path) -> list[str]:
    """The overrides of kth_run's config, writing into ``folder``."""
    return ["task=kth", "debug=tiny", f"out_dir={folder}", f"task.cache_dir={kth_run / 'cache'}",
            "task.logger="]  # fmt: skip


def _stopped(kth_run: Path, tmp_path: Path) -> Path:
    """A copy of kth_run's files (its cache left where it is), its record saying interrupted:
    edr-run of its config resumes it from its checkpoint.pt."""
    folder = tmp_path / "run"
    folder.mkdir()
    for path in kth_run.iterdir():
        if path.is_file():
            shutil.copy(path, folder / path.name)
    record = json.loads((folder / "run.json").read_text())
    (folder / "run.json").write_text(json.dumps({**record, "status": "interrupted"}))
    return folder


def _resume_refused(folder: Path, kth_run: Path, compose_config, monkeypatch) -> str:
    """edr-run of the folder's config, resuming it: refused in one line advising an edr-run
    option, before any video is read, the folder byte for byte as it was; the line."""
    from edr.tasks import recognition

    def read(*args, **kwargs) -> None:
        raise AssertionError("the videos were read before the refusal")

    monkeypatch.setattr(recognition._Data, "find", read)
    before = {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in folder.iterdir()}
    with pytest.raises((ConfigError, UnreadableCheckpoint)) as refused:
        run(compose_config(*_kth(kth_run, folder)))
    line = str(refused.value)
    assert "\n" not in line and "resume=false" in line and str(folder) in line, line
    assert {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in folder.iterdir()} == before
    return line


def _other_class_count(state: dict) -> dict:
    """``state`` with its classifier (the model's last weight) for 7 classes."""
    weights = dict(state["model"])
    last = [key for key in weights if key.endswith("weight")][-1]
    weights[last] = torch.zeros(7, *weights[last].shape[1:])
    return {**state, "model": weights}


ATARI_CHECKPOINT = {"network": {"w": torch.zeros(2)}, "optimizer": {}, "schedule": {}, "rng": {},
                    "env_steps": 20, "history": []}  # fmt: skip


@pytest.mark.parametrize(
    ("change", "said"),
    [
        (lambda state: torch.zeros(3), "checkpoint.pt holds Tensor, not what edr-run writes"),
        (lambda state: {k: v for k, v in state.items() if k != "history"},
         "checkpoint.pt: 'history' is missing, expected list"),
        (lambda state: {**state, "model": {"w": torch.zeros(2)}},
         "checkpoint.pt holds the weights of another network than its run.json describes"),
        (_other_class_count, "where the network its run.json describes takes (6,"),
        (lambda state: ATARI_CHECKPOINT, "checkpoint.pt: 'model' is missing, expected dict"),
        (lambda state: {"x": datetime.date(2020, 1, 1)},
         "checkpoint.pt cannot be read (it holds Python objects"),
        (lambda state: b"PK\x03\x04 cut", "checkpoint.pt cannot be read"),
    ],
    ids=["a bare tensor", "no history", "another network's keys", "another class count",
         "an Atari run's checkpoint", "a pickled object", "cut short"],
)  # fmt: skip
def test_a_foreign_checkpoint_is_refused_before_a_recognition_run_resumes(
    change, said, kth_run, tmp_path, compose_config, monkeypatch
) -> None:
    folder = _stopped(kth_run, tmp_path)
    changed = change(torch.load(folder / "checkpoint.pt", weights_only=True))
    if isinstance(changed, bytes):
        (folder / "checkpoint.pt").write_bytes(changed)
    else:
        torch.save(changed, folder / "checkpoint.pt")
    line = _resume_refused(folder, kth_run, compose_config, monkeypatch)
    assert said in line and str(folder / "checkpoint.pt") in line, line


@pytest.mark.parametrize(
    ("change", "said"),
    [
        (lambda r: r.update(status=3), "run.json: status=3: expected one of"),
        (lambda r: r.update(attempt=[1]), "run.json: attempt=[1]: expected an integer"),
    ],
    ids=["status a number", "attempt a list"],
)  # fmt: skip
def test_a_tampered_record_is_refused_before_a_recognition_run_resumes(
    change, said, kth_run, tmp_path, compose_config, monkeypatch
) -> None:
    folder = _stopped(kth_run, tmp_path)
    record = json.loads((folder / "run.json").read_text())
    change(record)
    (folder / "run.json").write_text(json.dumps(record))
    assert said in _resume_refused(folder, kth_run, compose_config, monkeypatch)


def test_each_unfinished_folds_checkpoint_is_checked(kth_run, tmp_path, compose_config) -> None:
    from hydra.utils import instantiate

    from edr.tasks.recognition import check_resumable
    from edr.tasks.run_folder import RefusedFolder

    settings = instantiate(compose_config(*_kth(kth_run, tmp_path)).task).keywords
    for fold in (0, 1):
        (tmp_path / f"fold{fold}").mkdir()
        shutil.copy(kth_run / "checkpoint.pt", tmp_path / f"fold{fold}" / "checkpoint.pt")
    check_resumable(tmp_path, **settings)  # the checkpoints fit_recognition writes pass
    torch.save(torch.zeros(3), tmp_path / "fold1" / "checkpoint.pt")
    with pytest.raises(RefusedFolder, match=r"fold1/checkpoint\.pt holds Tensor.*resume=false"):
        check_resumable(tmp_path, **settings)
    for name in ("fold.json", "predictions.json"):  # a finished fold is not read again
        (tmp_path / "fold1" / name).write_text("{}")
    check_resumable(tmp_path, **settings)
