"""The PAAC actor-critic network, with a recurrent core that carries state across agent steps.

Trunk (Clemente et al. 2017): conv 16 8x8/4, conv 32 4x4/2 (ReLU) -> on 84x84 a 32x9x9 map.
Core: ``lstm`` (FC 256 then an LSTM of 256), ``ftlstm`` (a feature-tracking LSTM: every gate's
recurrent term is, per channel, a map from every location to every location of that channel,
as FT-RCN; no recurrent weight couples channels) or ``none`` (FC 256, the original PAAC).
Heads: policy logits and state value.

In torchrl the network is one ``TensorDictModule``: it reads the observation, the recurrent
state (``rs_h``, ``rs_c``, primed with zeros by :func:`recurrent_primer`) and ``is_init``
(torchrl's ``InitTracker``), and writes ``logits``, ``state_value`` and the next state. Normally
a batch (..., C, H, W) is one step; a rollout (B, T, C, H, W) is replayed from its first state,
restarting wherever ``is_init`` is set (while ``network.sequence`` is True) — truncated
backpropagation through the rollout, as PAAC did.
"""

from __future__ import annotations

import math
from typing import Literal

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import Unbounded
from torchrl.envs import TensorDictPrimer

Core = Literal["lstm", "ftlstm", "none"]


class FeatureTrackingLSTMCell(nn.Module):
    """LSTM over feature maps: input term a 1x1 conv (mixes channels), recurrent term per channel."""

    def __init__(self, channels: int, locations: int) -> None:
        super().__init__()
        self.channels, self.locations = channels, locations
        self.input_gates = nn.Conv1d(channels, 4 * channels, 1)  # i, f, g, o
        # (gate, channel, from location, to location)
        self.recurrent = nn.Parameter(
            torch.randn(4, channels, locations, locations) / math.sqrt(locations)
        )

    def forward(
        self, x: torch.Tensor, state: tuple[torch.Tensor, torch.Tensor]
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """x (B, C, P), state (B, C*P) twice -> (h, c), each (B, C*P)."""
        b = x.shape[0]
        h, c = (s.view(b, self.channels, self.locations) for s in state)
        gates = self.input_gates(x).view(b, 4, self.channels, self.locations)
        gates = gates + torch.einsum("bcp,gcpq->bgcq", h, self.recurrent)
        i, f, g, o = gates.unbind(1)
        c = torch.sigmoid(f) * c + torch.sigmoid(i) * torch.tanh(g)
        h = torch.sigmoid(o) * torch.tanh(c)
        return h.flatten(1), c.flatten(1)


class PAACNetwork(nn.Module):
    """(obs, h, c, is_init) -> (logits, value, h', c'); obs (B, C, 84, 84) or (B, T, C, 84, 84)."""

    def __init__(
        self, in_channels: int, num_actions: int, core: Core = "lstm", hidden: int = 256
    ) -> None:
        super().__init__()
        self.trunk = nn.Sequential(
            nn.Conv2d(in_channels, 16, 8, stride=4),
            nn.ReLU(),
            nn.Conv2d(16, 32, 4, stride=2),
            nn.ReLU(),
        ).to(memory_format=torch.channels_last)  # ~3x faster convolutions on CPU
        with torch.no_grad():
            _, channels, h, w = self.trunk(torch.zeros(1, in_channels, 84, 84)).shape
        self.core_type, self.channels, self.locations = core, channels, h * w
        if core == "ftlstm":
            self.state_size = channels * h * w
            self.cell: nn.Module = FeatureTrackingLSTMCell(channels, h * w)
            features = self.state_size
        else:
            self.embed = nn.Sequential(nn.Flatten(), nn.Linear(channels * h * w, hidden), nn.ReLU())
            self.state_size = hidden if core == "lstm" else 1
            self.cell = nn.LSTMCell(hidden, hidden) if core == "lstm" else nn.Identity()
            features = hidden
        self.policy = nn.Linear(features, num_actions)
        self.value = nn.Linear(features, 1)
        self.sequence = False  # set by the trainer while it replays rollouts (B, T, ...)
        self._init_weights()

    def _init_weights(self) -> None:
        """Orthogonal weights, zero biases (as OpenAI's A2C): gain sqrt(2) before a ReLU, 0.01
        for the policy (it starts uniform, its logits not a random function of the frame) and
        1 for the value. The recurrent cells keep their own initialisation."""
        relu_layers = [m for m in (*self.trunk, *getattr(self, "embed", ())) if m._parameters]
        for layer, gain in [*((m, math.sqrt(2)) for m in relu_layers), (self.policy, 0.01),
                            (self.value, 1.0)]:  # fmt: skip
            with torch.no_grad():  # via a contiguous tensor: the trunk's weights are channels-last
                layer.weight.copy_(nn.init.orthogonal_(torch.empty(layer.weight.shape), gain))
                layer.bias.zero_()

    def _step(
        self, obs: torch.Tensor, h: torch.Tensor, c: torch.Tensor
    ) -> tuple[torch.Tensor, ...]:
        # (B, 32, 9, 9); observations may come as float16, and go channels-last as the trunk
        maps = self.trunk(obs.to(torch.float32, memory_format=torch.channels_last))
        if self.core_type == "ftlstm":
            h, c = self.cell(maps.flatten(2), (h, c))
            features = h
        elif self.core_type == "lstm":
            h, c = self.cell(self.embed(maps), (h, c))
            features = h
        else:
            features = self.embed(maps)
        return self.policy(features), self.value(features), h, c

    def forward(
        self, obs: torch.Tensor, h: torch.Tensor, c: torch.Tensor, is_init: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        if not self.sequence:  # one step of any batch of envs: (..., C, H, W)
            batch = obs.shape[:-3]
            keep = (~is_init.reshape(-1, 1)).to(h.dtype)  # a new episode starts from zeros
            flat_h, flat_c = h.reshape(-1, h.shape[-1]) * keep, c.reshape(-1, c.shape[-1]) * keep
            out = self._step(obs.reshape(-1, *obs.shape[-3:]), flat_h, flat_c)
            return tuple(o.reshape(*batch, o.shape[-1]) for o in out)
        h, c = h[:, 0], c[:, 0]  # (N, T, ...): replay each env's rollout from its first state
        outs = []
        for step in range(obs.shape[1]):
            keep = (~is_init[:, step]).to(h.dtype)
            out = self._step(obs[:, step], h * keep, c * keep)
            h, c = out[2], out[3]
            outs.append(out)
        return tuple(torch.stack(parts, 1) for parts in zip(*outs, strict=True))


def paac_module(network: PAACNetwork) -> TensorDictModule:
    """The network as a torchrl module over the keys its docstring names."""
    return TensorDictModule(
        network,
        in_keys=["observation", "rs_h", "rs_c", "is_init"],
        out_keys=["logits", "state_value", ("next", "rs_h"), ("next", "rs_c")],
    )


def recurrent_primer(network: PAACNetwork) -> TensorDictPrimer:
    """Zero recurrent state in every reset, so the collector carries it from step to step."""
    spec = Unbounded(shape=(network.state_size,), dtype=torch.float32)
    return TensorDictPrimer(rs_h=spec, rs_c=spec.clone(), reset_key="_reset", expand_specs=True)


def paac_loss(
    network: PAACNetwork,
    data: TensorDictBase,
    entropy_coeff: float,
    critic_coeff: float,
    scale: float,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """PAAC's loss on a rollout (N, T) with ``advantage`` and ``value_target`` (N, T, 1):

    ``scale * (mean(-(log pi(a) * A + entropy_coeff * H)) + critic_coeff * mean((R - V)^2))``
    (Clemente et al.: scale 5, entropy 0.02, critic 0.25). The rollout is replayed from its first
    recurrent state. Returns the loss and its parts (detached) for the logs.
    """
    network.sequence = True
    try:
        logits, values, _, _ = network(
            data["observation"], data["rs_h"], data["rs_c"], data["is_init"]
        )  # (N, T, A), (N, T, 1)
    finally:
        network.sequence = False
    log_pi = logits.log_softmax(-1)
    taken = (log_pi * data["action"].to(log_pi.dtype)).sum(-1)  # actions one-hot (N, T, A)
    entropy = -(log_pi.exp() * log_pi).sum(-1)
    actor = -(taken * data["advantage"].squeeze(-1) + entropy_coeff * entropy).mean()
    critic = critic_coeff * (data["value_target"] - values).pow(2).mean()
    parts = {"loss_actor": actor, "loss_critic": critic, "entropy": entropy.mean()}
    return scale * (actor + critic), {k: v.detach() for k, v in parts.items()}
