"""PAAC: the recurrent network's two modes agree, and a tiny Pong run writes a sound record."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from conftest import compose_config
from edr.rl.paac import PAACNetwork
from edr.run import run


@pytest.mark.parametrize("core", ["lstm", "ftlstm", "none"])
def test_stepping_equals_replaying_the_rollout(core: str) -> None:
    torch.manual_seed(0)
    net = PAACNetwork(5, 6, core)
    n, t = 3, 4
    obs = torch.rand(n, t, 5, 84, 84)
    is_init = torch.zeros(n, t, 1, dtype=torch.bool)
    is_init[1, 2] = True  # env 1 starts a new episode at step 2
    h = c = torch.zeros(n, net.state_size)
    stepped = []
    for step in range(t):
        logits, value, h, c = net(obs[:, step], h, c, is_init[:, step])
        stepped.append((logits, value))
    net.sequence = True
    first = torch.zeros(n, t, net.state_size)
    logits_seq, value_seq, _, _ = net(obs, first, first, is_init)
    torch.testing.assert_close(logits_seq, torch.stack([s[0] for s in stepped], 1))
    torch.testing.assert_close(value_seq, torch.stack([s[1] for s in stepped], 1))
    if core != "none":  # the reset really cut env 1's memory
        net.sequence = False
        fresh, _, _, _ = net(
            obs[1:2, 2],
            torch.zeros(1, net.state_size),
            torch.zeros(1, net.state_size),
            is_init[1:2, 2],
        )
        torch.testing.assert_close(stepped[2][0][1:2], fresh)


def test_float16_observations_go_through_the_network_in_float32() -> None:
    torch.manual_seed(0)
    net = PAACNetwork(5, 6, "lstm")
    obs = torch.rand(2, 5, 84, 84).half()
    h = c = torch.zeros(2, net.state_size)
    first = torch.ones(2, 1, dtype=torch.bool)
    logits, value, _, _ = net(obs, h, c, first)
    assert logits.dtype == value.dtype == torch.float32
    torch.testing.assert_close(logits, net(obs.float(), h, c, first)[0])


def test_ft_lstm_recurrence_stays_within_channels() -> None:
    net = PAACNetwork(2, 4, "ftlstm")
    assert net.cell.recurrent.shape == (4, 32, 81, 81)  # (gate, channel, location, location)


def test_tiny_pong_run(tmp_path) -> None:
    metrics = run(
        compose_config(
            "task=atari", "debug=tiny", "representation.color=gray", f"out_dir={tmp_path}"
        )
    )
    record = json.loads((tmp_path / "run.json").read_text())
    assert record["metrics"]["train/frames"] == 2000
    for key in ("train/loss_objective", "train/loss_critic", "train/loss_entropy"):
        assert np.isfinite(metrics[key])
    assert metrics["eval/plays"] == 2
    assert metrics["eval/min"] <= metrics["eval/mean"] <= metrics["eval/max"]
    assert (tmp_path / "checkpoint.pt").is_file() and (tmp_path / "training_curve.png").is_file()
    resumed = run(
        compose_config(
            "task=atari", "debug=tiny", "representation.color=gray", f"out_dir={tmp_path}",
            "task.resume=true", "task.total_frames=2400",
        )
    )  # fmt: skip
    assert resumed["train/frames"] == 2400  # went on from the checkpoint's 2,000
