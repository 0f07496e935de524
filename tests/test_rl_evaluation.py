"""Evaluation as documented (issue 58): the network plays its scored games in eval mode, by the
running statistics training kept, so a game's score does not depend on which games share its
batch; the policy samples unless asked to be greedy; bfloat16 autocast computes what float32
does, to bfloat16's precision, and ``auto`` picks it only where it is measured faster."""

from __future__ import annotations

import time

import torch
from torch import nn

from catch_game import catch_envs
from edr.models.paac import PAACNetwork
from edr.models.precision import choose_precision
from edr.rl.rollout import Actor
from edr.rl.settings import EvalSettings, NetworkSettings
from edr.tasks.atari import _evaluate, _precision

CATCH = {"game": "EdrCatch-v0", "preset": "none", "module": "catch_game", "fdr": "rgb",
         "edr": None, "obs_dtype": "float32"}  # fmt: skip


def _network() -> PAACNetwork:
    torch.manual_seed(0)
    network = PAACNetwork(12, 3, "none", init="fan_in", input_norm="batchnorm", frames=4)
    frames = [torch.rand(8, 3, 84, 84) for _ in range(4)]
    zeros, starts = torch.zeros(8, 1), torch.zeros(8, 1, dtype=torch.bool)
    for _ in range(3):  # running statistics away from their start (mean 0, var 1)
        network(frames, zeros, zeros, starts)
    return network


def test_in_eval_mode_an_envs_action_does_not_depend_on_the_other_envs() -> None:
    network = _network()
    brightness = torch.linspace(0.1, 1.0, 6).view(6, 1, 1, 1)  # games at other moments
    frames = [torch.rand(6, 3, 84, 84) * brightness for _ in range(4)]
    zeros, starts = torch.zeros(6, 1), torch.zeros(6, 1, dtype=torch.bool)

    def first_env_alone_and_in_the_batch() -> tuple[torch.Tensor, torch.Tensor]:
        with torch.no_grad():
            batch = network(frames, zeros, zeros, starts)[0][:1]
            alone = network([f[:1] for f in frames], zeros[:1], zeros[:1], starts[:1])[0]
        return alone, batch

    alone, batch = first_env_alone_and_in_the_batch()  # training mode: the batch's statistics
    assert not torch.allclose(alone, batch, atol=1e-3)
    network.eval()
    running = network.normalise.running_mean.clone()
    alone, batch = first_env_alone_and_in_the_batch()
    torch.testing.assert_close(alone, batch)
    torch.testing.assert_close(network.normalise.running_mean, running, rtol=0, atol=0)


def test_the_evaluation_plays_in_eval_mode_and_leaves_the_network_as_it_was() -> None:
    network = _network()
    seen_modes: list[bool] = []
    network.register_forward_pre_hook(lambda module, args: seen_modes.append(module.training))
    before = {k: v.clone() for k, v in network.state_dict().items()}
    games = _evaluate(network, CATCH, 4, "serial", 0, EvalSettings(plays=2, max_steps=20))
    assert len(games.scores) == 2 and seen_modes and not any(seen_modes)
    assert network.training  # back in training mode for whatever comes next
    for key, value in network.state_dict().items():
        torch.testing.assert_close(value, before[key], rtol=0, atol=0, msg=key)


class _Prefers(nn.Module):
    """Logits that favour action ``best`` (probability ~0.6 of 3), whatever the frames."""

    state_size = 1

    def __init__(self, best: int) -> None:
        super().__init__()
        self.logits = torch.zeros(3)
        self.logits[best] = 1.1

    def forward(self, frames, h, c, is_init):
        n = h.shape[0]
        return self.logits.expand(n, 3), torch.zeros(n, 1), h, c


def test_greedy_takes_the_most_probable_action_and_sample_draws_from_the_policy() -> None:
    env = catch_envs(16)
    env.set_seed(0)
    torch.manual_seed(0)
    actions = {}
    for greedy in (True, False):
        actor = Actor(env, _Prefers(2))
        td = actor._state()
        taken = []
        for _ in range(5):
            actor._act(td, greedy)
            taken.append(td["action"].argmax(-1))
        actions[greedy] = torch.cat(taken)
    env.close()
    assert (actions[True] == 2).all()
    assert (actions[False] != 2).any() and (actions[False] == 2).float().mean() > 0.4


def test_bfloat16_autocast_computes_what_float32_does_and_keeps_float32_outside() -> None:
    network = _network()
    frames = [torch.rand(5, 3, 84, 84) for _ in range(4)]
    zeros, starts = torch.zeros(5, 1), torch.zeros(5, 1, dtype=torch.bool)
    outputs, grads = {}, {}
    for precision in ("float32", "bfloat16"):
        network.precision = precision
        network.zero_grad()
        logits, value, _, _ = network(frames, zeros, zeros, starts)
        assert logits.dtype == value.dtype == torch.float32
        (logits.square().sum() + value.sum()).backward()
        outputs[precision] = torch.cat([logits, value], 1).detach()
        grads[precision] = network.trunk[0].weight.grad.clone()
        assert network.trunk[0].weight.grad.dtype == torch.float32
    torch.testing.assert_close(outputs["bfloat16"], outputs["float32"], atol=0.05, rtol=0.05)
    cosine = nn.functional.cosine_similarity(
        grads["bfloat16"].flatten(), grads["float32"].flatten(), 0
    )
    assert cosine > 0.99
    assert not torch.equal(outputs["bfloat16"], outputs["float32"])  # it did run in bfloat16


def test_auto_takes_bfloat16_only_with_bfloat16_units_and_a_measured_gain(tmp_path) -> None:
    with_units, without = tmp_path / "amx", tmp_path / "old"
    with_units.write_text("processor : 0\nflags : fpu sse2 avx512f amx_bf16 amx_tile\n")
    without.write_text("processor : 0\nflags : fpu sse2 avx2\n")
    costs = {"float32": 0.004, "bfloat16": 0.002}
    calls: list[str] = []

    def step(precision: str) -> None:
        calls.append(precision)
        time.sleep(costs[precision])

    assert choose_precision("auto", step, without) == ("float32", {})
    assert calls == []  # no bfloat16 units: nothing timed
    chosen, times = choose_precision("auto", step, with_units)
    assert chosen == "bfloat16" and times["bfloat16_ms"] < times["float32_ms"]
    costs.update(float32=0.002, bfloat16=0.004)
    assert choose_precision("auto", step, with_units)[0] == "float32"
    assert choose_precision("bfloat16", step, without) == ("bfloat16", {})  # asked for: given


def test_a_resumed_auto_run_keeps_the_precision_its_checkpoint_names() -> None:
    network = _network()
    chosen = _precision(network, NetworkSettings(precision="auto"), {"precision": "bfloat16"},
                        8, (3, 84, 84), 4)  # fmt: skip
    assert network.precision == "bfloat16" == chosen["train/precision"]
    assert "train/precision_float32_ms" not in chosen  # not timed again
    plain = _precision(network, NetworkSettings(precision="float32"), None, 8, (3, 84, 84), 4)
    assert network.precision == "float32" == plain["train/precision"]


def test_a_bfloat16_network_is_rebuilt_from_its_saved_arguments() -> None:
    # load_network (edr-eval of a finished run) builds the network with the precision it trained
    # in; its constructor's probe of the trunk ran outside autocast and failed in bfloat16
    trained = _network()
    trained.precision = "bfloat16"
    rebuilt = PAACNetwork(12, 3, "none", init="fan_in", input_norm="batchnorm", frames=4,
                          precision="bfloat16")  # fmt: skip
    rebuilt.load_state_dict(trained.state_dict())
    rebuilt.eval(), trained.eval()
    frames = [torch.rand(4, 3, 84, 84) for _ in range(4)]
    zeros, starts = torch.zeros(4, 1), torch.zeros(4, 1, dtype=torch.bool)
    logits = rebuilt(frames, zeros, zeros, starts)[0]
    assert logits.dtype == torch.float32 and torch.isfinite(logits).all()
    assert torch.equal(logits, trained(frames, zeros, zeros, starts)[0])
