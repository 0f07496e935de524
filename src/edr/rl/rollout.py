"""PAAC's actor: every env plays on from where it stopped, the network's outputs kept in the graph.

The loss then needs no second pass over the rollout: the logits and values the actions were
sampled from are the ones it differentiates (the parameters do not change between collecting a
rollout and the update that uses it, so the gradient is the same as a replay's). The recurrent
state runs on across rollouts, cut from the graph at each rollout's start (truncated
backpropagation through time, as PAAC did) and restarted from zeros where an episode starts
(``is_init``, from torchrl's ``InitTracker``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.envs import EnvBase

from edr.models.paac import PAACNetwork
from edr.models.precision import autocast
from edr.rl.phases import PhaseClock


def observations_held(rollout_steps: int, frame_stack: int = 1) -> int:
    """How many observations an :class:`Actor` holds at once: a rollout's graph keeps the
    ``rollout_steps + frame_stack - 1`` frames its steps saw while the env writes the next one
    (the size of an ``ObservationFrame`` ring that never overwrites one still in use)."""
    return rollout_steps + frame_stack


@dataclass
class Rollout:
    """``steps`` agent steps of N envs; T = steps."""

    logits: torch.Tensor  # (N, T, A), in the graph
    values: torch.Tensor  # (N, T, 1), in the graph
    actions: torch.Tensor  # (N, T) int64, the actions taken
    rewards: torch.Tensor  # (N, T, 1) as the env gives them (clipped in training)
    dones: torch.Tensor  # (N, T, 1) bool: the step ended its episode
    bootstrap: torch.Tensor  # (N, 1) the value of the state after the last step, no graph
    scores: list[float]  # raw scores of the episodes that ended in the rollout

    @property
    def env_steps(self) -> int:
        return self.actions.numel()


@dataclass
class Games:
    """One whole game per env, played at once (:meth:`Actor.play`), in the envs' order."""

    scores: list[float]  # raw scores
    steps: list[int]  # agent steps each game lasted (``max_steps`` for one still on)
    clipped: list[float]  # rewards clipped to their sign, summed: training's (undiscounted) return


class Actor:
    """Plays ``network``'s policy (sampled) in ``env``, a batched env with ``InitTracker``.

    ``env`` writes ``observation`` (..., C, 84, 84), ``is_init``, ``reward``, ``done`` and
    ``episode_reward`` (the raw score so far); its action is one-hot. The network sees the last
    ``frame_stack`` observations, oldest first (an env that restarts repeats its first one), as
    separate frames: nothing copies them into a stack.
    """

    def __init__(
        self,
        env: EnvBase,
        network: PAACNetwork | UniformPolicy,
        frame_stack: int = 1,
        clock: PhaseClock | None = None,
    ) -> None:
        self.env, self.network, self.frame_stack = env, network, frame_stack
        self.clock = clock or PhaseClock()  # the env's steps and the acting forward passes
        self.num_actions = env.action_spec.shape[-1]
        self._td: TensorDictBase | None = None  # the envs' current step; None: reset first
        self._h = self._c = torch.zeros(0)  # (N, state_size) the recurrent state
        self._frames: list[torch.Tensor] = []  # the network's last input, (N, C, H, W) each

    def _state(self) -> TensorDictBase:
        if self._td is None:
            self._td = self.env.reset()
            n = self._td.batch_size.numel()
            self._h = self._c = torch.zeros(n, self.network.state_size)
            self._frames = []
        return self._td

    def _input(self, td: TensorDictBase) -> list[torch.Tensor]:
        """The frames the network sees at step ``td``: the last input's, moved on by one."""
        new = td["observation"]
        if not self._frames:
            return [new] * self.frame_stack
        older = self._frames[1:]
        restart = td["is_init"]  # (..., 1)
        if restart.any():  # those envs' older frames become their first (new tensors: the
            restart = restart[..., None, None]  # old ones may be in the graph)
            older = [torch.where(restart, new, frame) for frame in older]
        return [*older, new]

    def _act(self, td: TensorDictBase, greedy: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
        """The action of every env at step ``td``, sampled from the policy (or its most probable
        one, ``greedy``); -> logits (N, A) and value (N, 1)."""
        self._frames = self._input(td)
        logits, value, self._h, self._c = self.network(
            self._frames, self._h, self._c, td["is_init"]
        )
        probs = logits.detach().reshape(-1, self.num_actions).softmax(-1)
        if not bool(torch.isfinite(probs).all()):  # multinomial would fail with a trace
            raise FloatingPointError("the policy's action probabilities are NaN or inf")
        action = probs.argmax(-1) if greedy else torch.multinomial(probs, 1).squeeze(-1)  # (N,)
        one_hot = torch.nn.functional.one_hot(action, self.num_actions)
        td["action"] = one_hot.reshape(*td.batch_size, self.num_actions)
        return logits, value

    def rollout(self, steps: int) -> Rollout:
        """``steps`` steps of every env, in the graph; the envs that end restart on their own."""
        td = self._state()
        self._h, self._c = self._h.detach(), self._c.detach()  # truncated backpropagation
        logits, values, actions, rewards, dones, scores = [], [], [], [], [], []
        # one autocast region for the whole rollout: a bfloat16 network's weights are cast once,
        # not at every step (they change only in the update after it)
        with autocast(getattr(self.network, "precision", "float32")):
            for _ in range(steps):
                with self.clock.phase("forward"):
                    step_logits, value = self._act(td)
                actions.append(td["action"].argmax(-1))
                with self.clock.phase("env"):
                    out, td = self.env.step_and_maybe_reset(td)
                done = out["next", "done"].reshape(-1, 1)
                logits.append(step_logits.reshape(done.shape[0], -1))
                values.append(value.reshape(-1, 1))
                rewards.append(out["next", "reward"].reshape(-1, 1))
                dones.append(done)
                if done.any():
                    scores += out["next", "episode_reward"].reshape(-1, 1)[done].tolist()
            with torch.no_grad(), self.clock.phase("forward"):
                inputs = self._input(td)
                _, bootstrap, _, _ = self.network(inputs, self._h, self._c, td["is_init"])
        self._td = td
        return Rollout(
            logits=torch.stack(logits, 1),
            values=torch.stack(values, 1),
            actions=torch.stack(actions, 1).reshape(done.shape[0], steps),
            rewards=torch.stack(rewards, 1),
            dones=torch.stack(dones, 1),
            bootstrap=bootstrap.reshape(-1, 1),
            scores=scores,
        )

    @torch.no_grad()
    def play(
        self, max_steps: int, greedy: bool = False, on_end: Callable[[int], object] | None = None
    ) -> Games:
        """One whole game on every env at once, from a reset: their raw scores, lengths and
        clipped returns. The actions are sampled from the policy, as in training, or its most
        probable ones (``greedy``). A game still on after ``max_steps`` agent steps counts what
        it scored so far; an env whose game ended plays on (the batch steps together) and its
        later rewards are not counted. ``on_end(k)`` hears of the k games that ended at each
        step (a progress bar's update). The network plays as it is: its caller puts it in eval
        mode."""
        self._td = None
        td = self._state()
        n = td.batch_size.numel()
        scores, clipped, steps = torch.zeros(n), torch.zeros(n), torch.zeros(n, dtype=torch.long)
        playing = torch.ones(n, dtype=torch.bool)
        for _ in range(max_steps):
            self._act(td, greedy)
            out, td = self.env.step_and_maybe_reset(td)
            reward = out["next", "reward"].reshape(n)
            scores += reward * playing
            clipped += reward.sign() * playing
            steps += playing
            ended = playing & out["next", "done"].reshape(n)
            playing &= ~ended
            if on_end is not None and ended.any():
                on_end(int(ended.sum()))
            if not playing.any():
                break
        self._td = None
        return Games(scores.tolist(), steps.tolist(), clipped.tolist())


class UniformPolicy(nn.Module):
    """Random play in an :class:`Actor`: every action equally likely, whatever the frames."""

    state_size = 0

    def __init__(self, num_actions: int) -> None:
        super().__init__()
        self.num_actions = num_actions

    def forward(
        self, frames: list[torch.Tensor], h: torch.Tensor, c: torch.Tensor, is_init: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        n = h.shape[0]
        return torch.zeros(n, self.num_actions), torch.zeros(n, 1), h, c  # logits (N, A)
