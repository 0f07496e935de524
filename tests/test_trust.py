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
