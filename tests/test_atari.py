"""PAAC: the recurrent network restarts with episodes, n-step returns, and a tiny Pong run
writes a sound record."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
import torch

import edr.rl.learner as learner
import edr.tasks.atari as atari
from edr.checks.config import ConfigError
from edr.models.paac import PAACNetwork
from edr.report.runs import read_history
from edr.rl.loss import n_step_returns, paac_loss
from edr.run import run
from edr.tasks.atari import evaluate_checkpoint, load_network


@pytest.mark.parametrize("core", ["lstm", "ftlstm"])
def test_an_episode_start_cuts_the_recurrent_memory(core: str) -> None:
    torch.manual_seed(0)
    net = PAACNetwork(5, 6, core)
    obs = torch.rand(2, 5, 84, 84)
    h = c = torch.rand(2, net.state_size)
    is_init = torch.tensor([[False], [True]])  # env 1 starts a new episode
    logits, _, _, _ = net(obs, h, c, is_init)
    zeros = torch.zeros(1, net.state_size)
    fresh, _, _, _ = net(obs[1:], zeros, zeros, is_init[1:])
    torch.testing.assert_close(logits[1:], fresh)
    remembered, _, _, _ = net(obs[:1], zeros, zeros, is_init[:1])
    assert not torch.allclose(logits[:1], remembered)  # env 0 kept its state


def test_n_step_returns_bootstrap_and_stop_at_episode_ends() -> None:
    rewards = torch.tensor([[1.0, 0.0, 1.0], [0.0, 0.0, 0.0]]).unsqueeze(-1)  # (N=2, T=3, 1)
    dones = torch.tensor([[False, True, False], [False, False, False]]).unsqueeze(-1)
    bootstrap = torch.tensor([[10.0], [2.0]])
    returns = n_step_returns(rewards, dones, bootstrap, gamma=0.5).squeeze(-1)
    # env 0: the episode ends at step 1, so steps 0-1 see no bootstrap; step 2 sees 10
    torch.testing.assert_close(returns[0], torch.tensor([1.0, 0.0, 1.0 + 5.0]))
    torch.testing.assert_close(returns[1], torch.tensor([0.25, 0.5, 1.0]))


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


def test_the_authors_network_tracks_lenet_maps_one_frame_a_step() -> None:
    net = PAACNetwork(5, 6, "lenet_ftlstm", init="fan_in")
    assert net.cell.recurrent.shape == (4, 16, 324, 324)  # LeNet 6-16 on 84x84: 16 x 18x18 maps
    assert net.embed[0].out_features == 512 and net.policy.in_features == 512
    with pytest.raises(ValueError, match="one frame per step"):
        PAACNetwork(20, 6, "lenet_ftlstm", frames=4)
    settings = atari.NetworkSettings(core="lenet_ftlstm")
    with pytest.raises(ConfigError, match=r"task\.env\.frame_stack=1"):
        atari._check_env(atari.EnvSettings(inputs="fdr"), settings)


@pytest.mark.parametrize("core", ["none", "ftlstm"])
def test_input_normalisation_centres_or_batch_normalises_each_frame(core: str) -> None:
    torch.manual_seed(0)
    frames = [torch.rand(8, 5, 84, 84) for _ in range(4)]
    state = torch.zeros(8, PAACNetwork(20, 6, core, frames=4).state_size)
    first = torch.ones(8, 1, dtype=torch.bool)
    raw = PAACNetwork(20, 6, core, frames=4)
    centred = PAACNetwork(20, 6, core, input_norm="centred", frames=4)
    centred.load_state_dict(raw.state_dict())
    shifted = [f - 0.5 for f in frames]
    torch.testing.assert_close(centred(frames, state, state, first)[0],
                               raw(shifted, state, state, first)[0])  # fmt: skip
    normed = PAACNetwork(20, 6, core, input_norm="batchnorm", frames=4)
    assert normed.normalise.num_features == 5  # one frame's channels, shared by the 4 frames
    scaled = [3 * f + 1 for f in frames]  # batch statistics take out any per-channel affine map
    torch.testing.assert_close(normed(frames, state, state, first)[0],
                               normed(scaled, state, state, first)[0], atol=1e-4, rtol=1e-4)  # fmt: skip


@pytest.mark.parametrize(("core", "frames"), [("none", 4), ("lenet_ftlstm", 1)])
def test_batchnorm_folded_into_the_first_conv_is_batchnorm_then_the_conv(
    core: str, frames: int
) -> None:
    """The fast path's maps and every gradient (the normalisation's scale and shift included)
    equal normalising each frame with the BatchNorm2d module, then the trunk."""
    torch.manual_seed(0)
    net = PAACNetwork(5 * frames, 6, core, input_norm="batchnorm", frames=frames)
    with torch.no_grad():
        net.normalise.weight.uniform_(0.5, 2.0)
        net.normalise.bias.uniform_(-1.0, 1.0)
    reference = copy.deepcopy(net)
    obs = [torch.rand(8, 5, 84, 84) for _ in range(frames)]
    maps = net._maps(obs)
    normed = [reference.normalise(f).contiguous(memory_format=torch.channels_last) for f in obs]
    expected = reference.trunk(normed if core == "none" else normed[-1])
    torch.testing.assert_close(maps, expected, atol=1e-4, rtol=1e-4)
    weights = torch.randn_like(maps)
    (maps * weights).sum().backward()
    (expected * weights).sum().backward()
    for (name, ours), theirs in zip(net.named_parameters(), reference.parameters(), strict=True):
        if theirs.grad is not None:
            torch.testing.assert_close(ours.grad, theirs.grad, atol=1e-3, rtol=1e-4, msg=name)
    assert net.normalise.weight.grad.abs().sum() > 0
    torch.testing.assert_close(net.normalise.running_mean, reference.normalise.running_mean)
    assert net.normalise.num_batches_tracked == reference.normalise.num_batches_tracked


def test_frames_seen_one_step_before_reuse_their_batch_statistics(monkeypatch) -> None:
    """Acting as the Actor does (the stack moves on by one frame a step): the same logits,
    values and running statistics, bit for bit, as computing every frame's statistics at every
    step; 4 frames' passes at the first step, 1 after; a frame written by torch since, or one
    that needs a gradient, is passed over again."""
    import edr.models.paac as paac

    torch.manual_seed(0)
    net = PAACNetwork(20, 6, "none", input_norm="batchnorm", frames=4)
    fresh = copy.deepcopy(net)
    passes = {"n": 0}
    counted = paac.batch_statistics

    def counting(frame):
        passes["n"] += 1
        return counted(frame)

    monkeypatch.setattr(paac, "batch_statistics", counting)
    state, first = torch.zeros(8, 1), torch.zeros(8, 1, dtype=torch.bool)
    stream = [torch.rand(8, 5, 84, 84) for _ in range(7)]
    for t in range(4):
        frames = stream[t : t + 4]
        before = passes["n"]
        ours = net(frames, state, state, first)
        assert passes["n"] - before == (4 if t == 0 else 1)
        fresh._last_statistics = {}  # every frame's statistics, every step
        theirs = fresh(frames, state, state, first)
        for a, b in zip(ours[:2], theirs[:2], strict=True):
            assert torch.equal(a, b)
        assert torch.equal(net.normalise.running_var, fresh.normalise.running_var)
    stream[5].mul_(2)  # a torch write: of the 4 frames seen last step, only it passes again
    before = passes["n"]
    net(stream[3:7], state, state, first)
    assert passes["n"] - before == 1
    needs_grad = [f.clone().requires_grad_() for f in stream[3:7]]
    before = passes["n"]
    net(needs_grad, state, state, first)[0].sum().backward()
    assert passes["n"] - before == 4 and needs_grad[0].grad is not None


def test_a_setting_added_at_its_default_keeps_old_fingerprints(compose_config) -> None:
    """Runs recorded before task.network.input_norm existed (raw frames, its value then) keep
    their identity; another value is another run."""
    from edr.store.identity import run_identity

    today = run_identity(compose_config("task=atari", "task.network.input_norm=raw"))
    before = run_identity(compose_config("task=atari", "~task.network.input_norm"))
    assert today[1:] == before[1:]  # fingerprint and cell
    other = run_identity(compose_config("task=atari", "task.network.input_norm=centred"))
    assert other[1] != today[1]


def test_the_learning_rate_warms_up_then_decays_and_without_warmup_only_decays(
    compose_config,
) -> None:
    from edr.rl.settings import OptimSettings
    from edr.store.identity import run_identity

    def factors(**settings: int) -> list[float]:
        optim = OptimSettings(lr_decay_env_steps=1000, **settings)
        return [round(learner.lr_factor(u, batch=100, optim=optim), 6) for u in range(11)]

    assert factors() == [1.0, 0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2, 0.1, 0.0]
    # over the first 400 env steps: 100, 200, 300, 400 of them taken by the end of each update
    assert factors(lr_warmup_env_steps=400)[:6] == [0.25, 0.45, 0.6, 0.7, 0.6, 0.5]
    today = run_identity(compose_config("task=atari", "task.optim.lr_warmup_env_steps=0"))
    before = run_identity(compose_config("task=atari", "~task.optim.lr_warmup_env_steps"))
    assert today[1:] == before[1:]  # runs from before the setting keep their fingerprint and cell


def test_a_centred_advantage_leaves_the_policy_gradient_alone_when_the_critic_is_off_by_a_constant(
    compose_config,
) -> None:
    from edr.store.identity import run_identity

    torch.manual_seed(0)
    logits = torch.randn(4, 5, 3, requires_grad=True)  # (N, T, A)
    actions, returns = torch.randint(0, 3, (4, 5)), torch.randn(4, 5, 1)
    values = torch.randn(4, 5, 1)

    def actor_grad(form: str, offset: float) -> torch.Tensor:
        logits.grad = None
        loss, _ = paac_loss(logits, values + offset, actions, returns, 0.02, 0.0, 5.0, form)
        loss.backward()
        return logits.grad.clone()

    for form in ("centred", "normalised"):
        assert torch.allclose(actor_grad(form, 0.0), actor_grad(form, -20.0), atol=1e-6)
    assert not torch.allclose(actor_grad("raw", 0.0), actor_grad("raw", -20.0), atol=1e-3)
    raw, _ = paac_loss(logits, values, actions, returns, 0.02, 0.25, 5.0)
    assert torch.equal(raw, paac_loss(logits, values, actions, returns, 0.02, 0.25, 5.0, "raw")[0])
    today = run_identity(compose_config("task=atari", "task.loss.advantage=raw"))
    before = run_identity(compose_config("task=atari", "~task.loss.advantage"))
    assert today[1:] == before[1:]  # runs from before the setting keep their fingerprint and cell


@pytest.mark.slow
def test_tiny_pong_run_and_its_resume(compose_config, tmp_path, monkeypatch) -> None:
    overrides = ("task=atari", "debug=tiny", "representation.color=gray")
    real_returns, calls = learner.n_step_returns, {"n": 0}

    def dies_in_update_65(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] > 64:  # as Ctrl-C in update 65: 64 updates of 20 env steps are kept
            raise KeyboardInterrupt("killed")
        return real_returns(*args, **kwargs)

    monkeypatch.setattr(learner, "n_step_returns", dies_in_update_65)
    with pytest.raises(KeyboardInterrupt):
        run(compose_config(*overrides, f"out_dir={tmp_path}"))
    assert torch.load(tmp_path / "checkpoint.pt", weights_only=True)["env_steps"] == 1280
    alone = tmp_path.with_name(f"{tmp_path.name}_checkpoint")  # the stopped run's checkpoint, kept
    alone.mkdir()
    (alone / "checkpoint.pt").write_bytes((tmp_path / "checkpoint.pt").read_bytes())
    evaluated = evaluate_checkpoint(tmp_path, plays=1)  # a stopped run, scored where it stopped
    assert evaluated["train/env_steps"] == 1280 and evaluated["eval/plays"] == 1
    saved = json.loads((tmp_path / "checkpoint_eval_seed0_plays1.json").read_text())
    assert len(saved.pop("scores")) == 1 and saved == evaluated
    assert not (tmp_path / "eval_scores.json").exists()  # the run's own evaluation is its own
    bare = tmp_path.with_name(f"{tmp_path.name}_bare")  # beside the run: no run in a run's folder
    bare.mkdir()
    (bare / "run.json").write_text((tmp_path / "run.json").read_text())
    with pytest.raises(FileNotFoundError, match=r"has no checkpoint\.pt: a run writes one"):
        evaluate_checkpoint(bare)
    monkeypatch.setattr(learner, "n_step_returns", real_returns)
    metrics = run(compose_config(*overrides, f"out_dir={tmp_path}"))

    record = json.loads((tmp_path / "run.json").read_text())
    assert record["status"] == "finished" and record["resumed"] and record["metrics"] == metrics
    assert (
        record["data"]["source"] == "emulator" and "pong.bin md5" in record["data"]["fingerprint"]
    )
    assert metrics["train/env_steps"] == 2000
    for key in ("train/loss_actor", "train/loss_critic", "train/entropy"):
        assert np.isfinite(metrics[key])
    assert (
        metrics["eval/plays"] == 2 == len(json.loads((tmp_path / "eval_scores.json").read_text()))
    )
    assert metrics["eval/min"] <= metrics["eval/mean"] <= metrics["eval/max"]
    history = read_history(tmp_path)  # stored once, gzip-compressed
    assert not (tmp_path / "history.json").exists()
    # a row per 10 updates, one for the 4 updates before the interrupt, one at the end; none twice
    rows = [*range(200, 1201, 200), 1280, *range(1480, 1881, 200), 2000]
    assert [row["env_steps"] for row in history] == rows
    steps = [
        line.split(",")[0] for line in (tmp_path / "logs/scalars/train/fps.csv").read_text().split()
    ]
    assert steps == [str(f) for f in rows]  # the log was rewound, not doubled
    assert (tmp_path / "training_curve.png").is_file()
    network = load_network(tmp_path)
    assert sum(p.numel() for p in network.parameters()) > 0
    assert metrics["eval/network_mode"] == "eval" and metrics["eval/policy"] == "sample"

    # a finished run is scored from its network.pt, its own evaluation untouched
    own = (tmp_path / "eval_scores.json").read_text()
    assert evaluate_checkpoint(tmp_path, plays=1)["train/env_steps"] == 2000
    assert (tmp_path / "eval_scores.json").read_text() == own
    assert (tmp_path / "network_eval_seed0_plays1.json").is_file()
    # a finished run kept as Table 1 keeps it (run.json and network.pt) is scored again
    kept = tmp_path.with_name(f"{tmp_path.name}_kept")
    kept.mkdir()
    for name in ("run.json", "network.pt"):
        (kept / name).write_bytes((tmp_path / name).read_bytes())
    rescored = evaluate_checkpoint(kept, plays=2, random_play=True)
    assert rescored["train/env_steps"] == 2000 and rescored["eval/plays"] == 2
    assert rescored["random/plays"] == 2 and rescored["random/steps_mean"] >= 1
    for side in ("eval", "random"):  # a game's clipped return counts its points' signs
        assert abs(rescored[f"{side}/clipped_mean"]) <= rescored[f"{side}/steps_mean"]
    saved = json.loads((kept / "network_eval_seed0_plays2.json").read_text())
    assert len(saved.pop("scores")) == 2 and saved == rescored
    assert sorted(p.name for p in kept.iterdir()) == [
        "network.pt", "network_eval_seed0_plays2.json", "run.json"
    ]  # fmt: skip
    # a finished record with a checkpoint alone (Table 1's older runs): scored from it, nothing
    # of the run's own evaluation written
    (alone / "run.json").write_bytes((tmp_path / "run.json").read_bytes())
    assert evaluate_checkpoint(alone, plays=1)["train/env_steps"] == 1280
    assert sorted(p.name for p in alone.iterdir()) == [
        "checkpoint.pt", "checkpoint_eval_seed0_plays1.json", "run.json"
    ]  # fmt: skip

    # the finished run kept its network.pt and dropped its checkpoint once its record said so:
    # a larger budget is refused in one line, as a lower one
    assert not (tmp_path / "checkpoint.pt").exists()
    attempts = [
        json.loads(line) for line in (tmp_path / "attempts.jsonl").read_text().split("\n") if line
    ]
    assert [a["outcome"] for a in attempts] == ["interrupted", "resumed"]
    assert all(a["git"] for a in attempts) and attempts[-1]["git"] == record["git"]  # its commit
    with pytest.raises(ConfigError, match=r"finished and kept its network\.pt, not the checkpoint"):
        run(compose_config(*overrides, f"out_dir={tmp_path}", "task.env_steps=2400"))
    with pytest.raises(ConfigError, match=r"task\.env_steps: 2000 -> 1600"):
        run(compose_config(*overrides, f"out_dir={tmp_path}", "task.env_steps=1600"))


def test_groups_atari_does_not_read_leave_its_fingerprint_alone(compose_config) -> None:
    from edr.store.identity import ignored_overrides, run_identity

    base = run_identity(compose_config("task=atari"))[1]
    assert run_identity(compose_config("task=atari", "optimizer=adam"))[1] == base
    assert run_identity(compose_config("task=atari", "backbone=nin_lrcn"))[1] == base
    assert run_identity(compose_config("task=atari", "representation.beta=2"))[1] != base
    cfg = compose_config("task=atari", "optimizer=adam")
    assert ignored_overrides(cfg, ["optimizer=adam", "representation.beta=2"]) == ["optimizer=adam"]


@pytest.mark.slow
def test_the_readmes_own_game_command_runs(cli, tmp_path) -> None:
    """A gymnasium env of your own, as the README writes it (the catching game of the tests)."""
    from pathlib import Path

    own = ("task=atari", "task.env.preset=none", "task.env.env_id=EdrCatch-v0", "debug=tiny",
           "task.env_steps=400", "task.evaluation.max_steps=20")  # fmt: skip
    tests = str(Path(__file__).parent)
    result = cli("edr-run", *own, "task.env.env_module=catch_game", cwd=tmp_path,
                 env={"PYTHONPATH": tests})  # fmt: skip
    assert result.returncode == 0, result.stderr[-3000:]
    (record,) = (tmp_path / "results" / "runs" / "atari").glob("*/run.json")
    assert json.loads(record.read_text())["data"]["source"] == "gymnasium"
    missing = cli("edr-run", *own, "task.env.env_module=no_such_games", cwd=tmp_path)
    assert missing.returncode == 2 and "Traceback" not in missing.stderr
    (line,) = [x for x in (missing.stdout + missing.stderr).splitlines() if "no_such" in x]
    assert "task.env.env_module='no_such_games': expected a module" in line
    assert not list((tmp_path / "results" / "runs" / "atari").glob("*no_such_games*/run.json"))


@pytest.mark.learning
def test_the_first_convolution_stays_alive_on_pong(compose_config, tmp_path) -> None:
    """Pong with the Table 1 defaults, 20 updates (3,200 env steps), both inputs, seed 0: a
    diagnostic beside the learning tests (tests/test_rl_learning.py), not a choice of defaults.
    conv1's dead fraction is set within the first 10-20 updates. Measured 2026-12-03 (seeds 0
    and 1): the defaults (batch-normed frames, Adam 7e-4) 0 of 16 units dead with either input;
    the same with raw frames (``input_norm=raw``) 62-88 % dead, which this test fails on."""
    dead = []
    for inputs in ("fdr", "fdr_edr"):
        metrics = run(compose_config(
            "experiment=table1_atari", "game=pong", f"task.env.inputs={inputs}", "seed=0",
            "task.env_steps=3200", "task.evaluation.plays=1", "task.evaluation.max_steps=1",
            "task.logger=", f"out_dir={tmp_path / inputs}",
        ))  # fmt: skip
        dead.append(metrics["dead/trunk.1"])
    assert max(dead) <= 4 / 16, dead  # no run lost more than 4 of its 16 units


def test_the_screening_table_reads_scores_and_first_steps_from_a_history(tmp_path) -> None:
    import pandas as pd

    from edr.report.screening import screening_rows

    history = [{"env_steps": s, "train/score": score, "train/entropy": 1.7}
               for s, score in [(100_000, -20.5), (300_000, -14.0), (600_000, 0.5)]]  # fmt: skip
    (tmp_path / "history.json").write_text(json.dumps(history))
    runs = pd.DataFrame([{
        "record": str(tmp_path / "run.json"), "task": "atari", "seed": 0, "status": "finished",
        "config.task.network.core": "none", "config.task.optim.name": "adam",
        "config.task.optim.lr": 7e-4, "config.task.env.inputs": "fdr",
    }])  # fmt: skip
    row = screening_rows(runs).iloc[0]
    assert row["Steps to -15"] == "0.30M" and row["Steps to 0"] == "0.60M"
    assert row["Score @0.25M"] == -20.5 and row["Score @0.5M"] == -14.0
    assert row["Score @1M"] is None  # the run did not get that far
    assert row["Precision"] == "float32"  # a record from before the setting
    assert row["Optimizer"] == "adam 0.0007"
