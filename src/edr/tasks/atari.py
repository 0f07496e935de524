"""Atari with PAAC (the paper's Table 1 and Figure 5): FDR or FDR+EDR input, EDR on the fly.

Top to bottom: envs and network; the loop (:class:`edr.rl.rollout.Actor` plays
``rollout_steps`` steps of every env, the network's outputs kept for the loss; n-step returns
bootstrapped from the value of the state after the rollout; PAAC's loss (:func:`edr.rl.loss.paac_loss`); Adam or PAAC's TensorFlow-style RMSprop with the
gradient's L2 norm clipped and the learning rate decaying linearly to 0); checkpoints; then
``eval_plays`` full games scored (min / max / mean, Table 1's columns) and the training curve
(score against env steps).

Frames here count env steps — agent decisions, summed over envs; with the frame skip of 4
each is 4 emulator frames.
"""

from __future__ import annotations

import copy
import functools
import logging
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch
from torchrl.envs import InitTracker, TransformedEnv
from tqdm import tqdm

from edr.checks import interrupts
from edr.checks.config import Allocation, ConfigError, PositiveInt, check_allocations
from edr.models.dead_units import DeadUnits
from edr.models.paac import PAACNetwork
from edr.models.precision import Precision, choose_precision
from edr.representations import EDR
from edr.rl.envs import Backend, make_atari_env, rom_fingerprint
from edr.rl.learner import Diverged, Learner
from edr.rl.phases import PhaseClock
from edr.rl.rollout import Actor, Games, Rollout, UniformPolicy, observations_held
from edr.rl.settings import (
    EnvSettings,
    EvalSettings,
    LossSettings,
    NetworkSettings,
    OptimSettings,
)
from edr.rl.transform import ObservationFrame
from edr.store.atomic import write_json_atomic
from edr.store.checkpoints import (
    CHECKPOINT,
    DATA_FINGERPRINT,
    NETWORK,
    START_OVER,
    check_same_data,
    load_checkpoint,
    restore,
    save_atomic,
    save_checkpoint,
)
from edr.tasks.plots import save_score_curve
from edr.tasks.rebuild import instantiate_from_record
from edr.tasks.run_folder import (
    Reader,
    RunFolder,
    check_weights,
    open_run_folder,
    payload_part,
)
from edr.tasks.scalars import LoggerName, open_logger

# a row per log_every updates: env steps, losses, fps, training score; gzip-compressed JSON,
# read by edr.report.runs.read_history (as older runs' history.json)
HISTORY = "history.json.gz"
SCORES = "eval_scores.json"  # the raw score of every evaluation game
log = logging.getLogger(__name__)


def _env(**kwargs: Any) -> TransformedEnv:
    """An Atari env that also marks where episodes start (``is_init``)."""
    env = make_atari_env(**kwargs)
    env.append_transform(InitTracker())
    return env


def train_paac(
    *,
    out_dir: Path,
    seed: int,
    env: EnvSettings = EnvSettings(),
    network: NetworkSettings = NetworkSettings(),
    loss: LossSettings = LossSettings(),
    optim: OptimSettings = OptimSettings(),
    evaluation: EvalSettings = EvalSettings(),
    env_steps: PositiveInt = 80_000_000,
    checkpoint_every: PositiveInt = 500,
    log_every: PositiveInt = 10,
    resume: bool = False,
    logger: LoggerName = "csv",
) -> dict[str, Any]:
    """Train PAAC for ``env_steps`` agent steps (summed over envs) on ``env.game`` (or the
    gymnasium env ``env.env_id``), then score ``evaluation.plays`` games. Returns the run's metrics.

    Every ``log_every`` updates a row of the history: losses, entropy, gradient norm, the
    critic's mean value, the fraction of dead units per ReLU layer on the latest rollout, the
    logits' spread, the time per phase and the mean score of the last 20 training episodes.
    """
    _check_env(env, network)
    backend, env_kwargs = env.resolved_backend(), _env_kwargs(env)
    observation, actions = _probe(env_kwargs)
    _check_memory(env, loss.rollout_steps, evaluation.plays, observation)
    net, arguments = _fresh_network(observation, actions, network, env.frame_stack)
    fingerprint = (
        rom_fingerprint(env.game) if env.env_id is None else f"{env.env_module}:{env.env_id}"
    )
    checkpoint = out_dir / CHECKPOINT
    state = load_checkpoint(checkpoint) if resume else None
    if state is not None:
        check_same_data(state, fingerprint, checkpoint)  # the same ROM (or env) it trained on
    precision = _precision(net, network, state, env.num_envs * loss.rollout_steps, observation,
                           env.frame_stack)  # fmt: skip
    arguments["precision"], env_kwargs = net.precision, _frames_for(net, env_kwargs)
    clock = PhaseClock()  # where each update's time goes, into the history
    envs = _training_envs(env, loss, env_kwargs, backend, seed, clock)
    learner = Learner(net, loss, optim, env.num_envs * loss.rollout_steps, clock)
    steps_done, history = 0, []
    if state is not None:
        restore(state, learner.parts)  # episodes in progress restart
        steps_done, history = state["env_steps"], state["history"]
    progress = _TrainingLog(
        env.name, env_steps, steps_done, history, open_logger(logger, out_dir, step=steps_done),
        DeadUnits(net),
    )  # fmt: skip

    def save() -> None:
        save_checkpoint(checkpoint, learner.parts, env_steps=progress.steps_done,
                        history=progress.history, precision=net.precision,
                        **{DATA_FINGERPRINT: fingerprint})  # fmt: skip

    try:
        actor = Actor(envs, net, env.frame_stack, clock)
        diverged = _train(actor, learner, progress, save, env_steps, loss.rollout_steps,
                          checkpoint_every, log_every)  # fmt: skip
        if diverged:  # the checkpoint keeps the last network that was numbers; no games to score
            log.warning("training diverged at %d env steps (%s): recorded as diverged",
                        progress.steps_done, diverged["train/diverged_reason"])  # fmt: skip
            progress.flush()
    finally:
        progress.close()
        envs.close()
    if not diverged:
        save()
    scores, evaluated = _evaluation(net, env_kwargs, env.frame_stack, backend, seed, evaluation,
                                    played=not diverged)  # fmt: skip
    save_atomic({"state_dict": net.state_dict(), "arguments": arguments}, out_dir / NETWORK)
    _write_results(out_dir, history, scores, f"{env.name}, inputs={env.inputs}")
    return {
        "data/source": "emulator" if env.env_id is None else "gymnasium",
        "data/game": env.name,
        "data/fingerprint": fingerprint,
        **_training_metrics(history, progress.steps_done, learner.losses),
        **precision,
        **evaluated,
        **diverged,
    }


# What a checkpoint of train_paac holds that a resume reads (the learner's parts, the counters).
CHECKPOINT_PARTS = {"network": dict, "optimizer": dict, "schedule": dict, "rng": dict,
                    "env_steps": int, "history": list}  # fmt: skip


def check_resumable(
    out_dir: Path, *, env: EnvSettings = EnvSettings(),
    network: NetworkSettings = NetworkSettings(), **_: Any,
) -> None:  # fmt: skip
    """The checkpoint a resumed run would continue from, checked before edr-run rewrites the
    run's record, as edr-eval checks a file it scores (:mod:`edr.tasks.run_folder`): readable,
    holding what train_paac writes, its network's keys and shapes those of the network ``env``
    and ``network`` describe (one probe env is made). One line naming the file otherwise, with
    edr-run's remedy; the folder stays as it was."""
    path = out_dir / CHECKPOINT
    state = load_checkpoint(path)
    for key, kind in CHECKPOINT_PARTS.items():
        payload_part(path, state, key, kind, START_OVER)
    fresh = _network(_env_kwargs(env), network, env.frame_stack)
    check_weights(path, state["network"], fresh.state_dict(), START_OVER)


train_paac.check_resumable = check_resumable  # type: ignore[attr-defined]  # edr-run calls it


def _training_metrics(
    history: list[dict[str, float]], steps_done: int, losses: dict[str, float]
) -> dict[str, Any]:
    """The record's ``train/`` and ``dead/`` part: env steps trained, speed, the first and last
    training scores, the last update's losses and the last row's dead units."""
    scored = [row for row in history if "train/score" in row]
    return {
        "train/env_steps": steps_done,
        "train/fps": history[-1]["train/fps"] if history else float("nan"),
        "train/score_first": scored[0]["train/score"] if scored else None,
        "train/score_last": scored[-1]["train/score"] if scored else None,
        **losses,
        **({k: v for k, v in history[-1].items() if k.startswith("dead/")} if history else {}),
    }


def _evaluation(
    net: PAACNetwork, env_kwargs: dict[str, Any], frame_stack: int, backend: Backend, seed: int,
    evaluation: EvalSettings, played: bool,
) -> tuple[list[float], dict[str, Any]]:  # fmt: skip
    """The evaluation games' raw scores (none unless ``played``) and the record's ``eval/``
    part; games cut short by ``max_steps`` get random play's mean on the same games beside."""
    games = _evaluate(net, env_kwargs, frame_stack, backend, seed, evaluation) if played else None
    random_games = (
        _evaluate(UniformPolicy(net.policy.out_features), env_kwargs, frame_stack, backend, seed,
                  evaluation)
        if evaluation.capped and games else None
    )  # fmt: skip
    metrics = {**_score_metrics(games), **_evaluation_mode(evaluation)}
    if random_games is not None:
        metrics |= {"eval/random_mean": float(np.mean(random_games.scores)),
                    "eval/max_steps": evaluation.max_steps}  # fmt: skip
    return games.scores if games else [], metrics


def _evaluation_mode(evaluation: EvalSettings) -> dict[str, str]:
    """How the evaluation played, for the record: the network in eval mode (batch-normed frames
    by training's running statistics; records without this key played in training mode, each
    batch of games normalised by its own frames) and the policy (sampled or greedy)."""
    return {"eval/network_mode": "eval", "eval/policy": evaluation.policy}


def _precision(
    net: PAACNetwork, network: NetworkSettings, state: dict[str, Any] | None, batch: int,
    observation: tuple[int, ...], frame_stack: int,
) -> dict[str, Any]:  # fmt: skip
    """Set ``net``'s precision: ``network.precision``, where ``auto`` is the checkpoint's choice
    on a resumed run (a run keeps one precision) and else :func:`choose_precision` timing one
    forward and backward pass of ``batch`` observations (C, H, W) (an update's). The record's
    ``train/precision`` part: the precision, and the times that chose it."""
    choice = network.precision
    if choice == "auto" and state is not None and "precision" in state:
        choice = state["precision"]

    @functools.cache  # made once, and only if choose_precision times (auto on a bf16 CPU)
    def timed_inputs() -> tuple[PAACNetwork, list[torch.Tensor], torch.Tensor, torch.Tensor]:
        noise = torch.Generator().manual_seed(0)  # the run's own random streams stay untouched
        frames = [torch.rand(batch, *observation, generator=noise).contiguous(
            memory_format=torch.channels_last) for _ in range(frame_stack)]  # fmt: skip
        starts = torch.zeros(batch, 1, dtype=torch.bool)
        # timed on a copy: the net's running statistics stay its own
        return copy.deepcopy(net), frames, torch.zeros(batch, net.state_size), starts

    def update(precision: Precision) -> None:
        probe, frames, zeros, starts = timed_inputs()
        probe.precision = precision
        logits, value, _, _ = probe(frames, zeros, zeros, starts)
        (logits.sum() + value.sum()).backward()

    net.precision, timed = choose_precision(choice, update)
    if timed:
        log.info("precision auto: %s (update %.1f ms in float32, %.1f ms in bfloat16)",
                 net.precision, timed["float32_ms"], timed["bfloat16_ms"])  # fmt: skip
    return {
        "train/precision": net.precision,
        **{f"train/precision_{k}": v for k, v in timed.items()},
    }


def _frames_for(net: PAACNetwork, env_kwargs: dict[str, Any]) -> dict[str, Any]:
    """``env_kwargs`` with the frames in bfloat16 where ``net`` computes in bfloat16 and the
    frames would be float32: autocast would round each frame to bfloat16 at every forward pass
    that sees it (4 a frame); the env rounds it once, and the convolutions see the same numbers
    (batch normalisation's statistics are then those of the rounded frames)."""
    if net.precision == "bfloat16" and env_kwargs["obs_dtype"] == "float32":
        return {**env_kwargs, "obs_dtype": "bfloat16"}
    return env_kwargs


def _training_envs(
    env: EnvSettings, loss: LossSettings, env_kwargs: dict[str, Any], backend: Backend, seed: int,
    clock: PhaseClock,
) -> TransformedEnv:  # fmt: skip
    """The training envs, seeded, their observation transform timed by ``clock``."""
    envs = _env(
        num_envs=env.num_envs, backend=backend, keep_inputs=False,
        frame_ring=observations_held(loss.rollout_steps, env.frame_stack), **env_kwargs,
    )  # fmt: skip
    envs.set_seed(seed)
    for transform in envs.transform:  # the observation's transform, where it runs in-process
        if isinstance(transform, ObservationFrame):
            transform.clock = clock
    return envs


class _TrainingLog:
    """A run's progress: the env steps trained, the history (a row per ``log_every`` updates,
    also written to the logger and the progress bar), and the last 20 training episodes' scores."""

    def __init__(
        self, name: str, env_steps: int, steps_done: int, history: list[dict[str, float]],
        scalars: Any, dead_units: DeadUnits,
    ) -> None:  # fmt: skip
        self.steps_done, self.history = steps_done, history
        self.scalars, self.dead_units = scalars, dead_units
        self.recent: deque[float] = deque(maxlen=20)
        self.window: list[dict[str, float]] = []  # the updates since the last row
        self._start, self._steps_at_start = time.perf_counter(), steps_done
        self._bar = tqdm(
            total=env_steps, initial=steps_done, desc=f"PAAC {name}", unit="step", unit_scale=True
        )

    def add(self, rollout: Rollout, values: dict[str, float]) -> None:
        """An update trained on ``rollout``; ``values``: its part of the next row."""
        self.steps_done += rollout.env_steps
        self.recent.extend(rollout.scores)
        self.window.append(values)
        self._bar.update(rollout.env_steps)

    def flush(self) -> None:
        """The updates since the last row as one row of the history, the logs and the bar."""
        if not self.window:
            return
        fps = (self.steps_done - self._steps_at_start) / (time.perf_counter() - self._start)
        row = _history_row(self.steps_done, fps, self.window, self.recent)
        row.update(self.dead_units.fractions())  # of the latest rollout
        self.window = []
        self.history.append(row)
        if self.scalars is not None:
            for key, value in row.items():
                if key != "env_steps":
                    self.scalars.log_scalar(key, value, step=self.steps_done)
        self._bar.set_postfix(score=f"{row.get('train/score', float('nan')):.1f}", fps=f"{fps:.0f}")

    def close(self) -> None:
        self._bar.close()


def _train(
    actor: Actor, learner: Learner, progress: _TrainingLog, save: Callable[[], None],
    env_steps: int, rollout_steps: int, checkpoint_every: int, log_every: int,
) -> dict[str, Any]:  # fmt: skip
    """Rollouts and updates until ``env_steps`` are trained, a checkpoint every
    ``checkpoint_every`` updates; the record's note of a divergence, empty if none came. An
    interrupt (Ctrl-C, SIGTERM) saves a checkpoint unless it landed inside the optimizer's step."""
    learner.clock.lap()  # the first row's times start with the loop, not with the envs' set-up
    update = 0
    try:
        while progress.steps_done < env_steps:
            update += 1
            interrupts.raise_if_stopping()  # a Ctrl-C some callback dropped stops here
            progress.dead_units.reset()
            try:
                rollout = actor.rollout(rollout_steps)  # the envs' steps, forward passes
            except FloatingPointError as error:  # the network's outputs stopped being numbers
                return _diverged(progress.steps_done, update, str(error))
            try:
                values = learner.update(rollout)
            except Diverged as error:
                steps = progress.steps_done + (rollout.env_steps if error.stepped else 0)
                return _diverged(steps, update, str(error))
            progress.add(rollout, {**values, **learner.clock.lap()})
            if update % log_every == 0 or progress.steps_done >= env_steps:
                progress.flush()
            if update % checkpoint_every == 0:
                save()
    except KeyboardInterrupt:  # Ctrl-C, or SIGTERM through edr-run: keep what was trained
        if not learner.stepping:
            progress.flush()
            save()
            log.info("interrupted: checkpoint saved at %d env steps", progress.steps_done)
        raise
    return {}


def _diverged(env_steps: int, update: int, reason: str) -> dict[str, Any]:
    """The record's note of a divergence: where (env steps, update) and why."""
    return {"train/diverged_step": env_steps, "train/diverged_update": update,
            "train/diverged_reason": reason}  # fmt: skip


def _check_env(env: EnvSettings, network: NetworkSettings) -> None:
    """One line for a setting that cannot work, before any env starts."""
    if network.core == "lenet_ftlstm" and env.frame_stack != 1:
        raise ConfigError(
            "task.network.core=lenet_ftlstm reads one frame per step (its LSTM holds the past): "
            f"add task.env.frame_stack=1 (got {env.frame_stack})"
        )
    if env.inputs != "fdr" and not isinstance(env.edr, EDR):
        raise ConfigError(
            f"task.env.inputs={env.inputs} computes EDR events on the fly from the representation "
            f"group, which holds {type(env.edr).__name__}: use representation=edr "
            "(representation.color=gray for the paper's input), or task.env.inputs=fdr"
        )
    if env.inputs != "fdr" and env.edr.learnable:
        raise ConfigError(
            "representation.learnable=true: the Atari loop computes EDR inside the env, without "
            "gradients, so its parameters would not learn; learnable EDR trains in the "
            "recognition tasks (task=kth, task=ucf101)"
        )
    pairing = {"env_id": env.env_id, "preset": env.preset, "backend": env.backend}
    if problem := EnvSettings.pairing_problem(pairing):
        raise ConfigError(f"task.env.{problem}")


def _allocations(
    env: EnvSettings, rollout_steps: int, plays: int, observation: tuple[int, ...]
) -> list[Allocation]:
    """What a run's sizes make it hold at once, for observations of ``observation`` (C, H, W):
    the frames the training envs hold, one step's stacked input of the evaluation games (one env
    per game), and the first convolution's weights (with their gradient and Adam's two moments)."""
    frame = int(np.prod(observation)) * (2 if env.obs_dtype == "float16" else 4)  # bytes, at most
    held = observations_held(rollout_steps, env.frame_stack)
    stack = f"task.env.frame_stack={env.frame_stack}"
    conv1 = env.frame_stack * observation[0] * 16 * 8 * 8 * 4  # PAAC's conv 16 8x8, float32
    return [
        Allocation(
            f"task.env.num_envs={env.num_envs}, task.loss.rollout_steps={rollout_steps}, {stack}",
            f"the {held} observations each of the {env.num_envs} envs holds",
            env.num_envs * held * frame,
        ),
        Allocation(f"task.evaluation.plays={plays}, {stack}",
                   f"one step's input of {plays} games played at once", plays * env.frame_stack * frame),
        Allocation(stack, "the first convolution's weights, gradient and Adam moments", 4 * conv1),
    ]  # fmt: skip


def _check_memory(
    env: EnvSettings, rollout_steps: int, plays: int, observation: tuple[int, ...]
) -> None:
    """Refuse sizes whose arrays cannot fit in memory (:func:`_allocations`), before the
    network is built."""
    check_allocations(_allocations(env, rollout_steps, plays, observation))


def _sizes_problem(values: dict[str, Any]) -> None:
    """edr-run's check before the run's record: :func:`_check_memory` for the smallest
    observation the settings give (84x84 frames; RGB 3 channels or gray 1, EDR's ON and OFF 2
    at least), so a size that cannot fit is one line before any env or network is made."""
    given, loss, evaluation = _settings_values(values["env"]), values["loss"], values["evaluation"]
    env = replace(EnvSettings(), **{
        k: v for k, v in given.items() if k in ("num_envs", "frame_stack", "obs_dtype")})  # fmt: skip
    inputs, fdr = given.get("inputs", env.inputs), given.get("fdr", env.fdr)
    channels = (0 if inputs == "edr" else 3 if fdr == "rgb" else 1) + (0 if inputs == "fdr" else 2)
    rollout_steps = _settings_values(loss).get("rollout_steps", LossSettings.rollout_steps)
    plays = _settings_values(evaluation).get("plays", EvalSettings.plays)
    _check_memory(env, rollout_steps, plays, (channels, 84, 84))


def _settings_values(node: Any) -> dict[str, Any]:
    """A settings group's values, as a dataclass or as the config's mapping gives them."""
    return dict(node) if isinstance(node, Mapping) else vars(node)


train_paac.settings_problem = _sizes_problem  # type: ignore[attr-defined]  # edr-run's check


def _history_row(
    env_steps: int, fps: float, window: list[dict[str, float]], recent: deque[float]
) -> dict[str, float]:
    """One row of the training history: the means over the updates of ``window`` (gradient norm,
    losses, entropy, the critic's mean value), the env steps per second so far, and the mean
    score of ``recent``."""
    row = {"env_steps": env_steps, "train/fps": fps}
    row.update({key: float(np.mean([w[key] for w in window])) for key in window[0]})
    if recent:
        row["train/score"] = float(np.mean(recent))
    return row


def _env_kwargs(env: EnvSettings) -> dict[str, Any]:
    """What ``make_atari_env`` takes for these envs (training and evaluation alike): one frame
    per observation, which the :class:`Actor` stacks for the network."""
    return {
        "game": env.name,
        "preset": env.preset,
        "life_loss": env.life_loss,
        "module": env.env_module,
        "fdr": env.fdr if env.inputs != "edr" else "none",
        "edr": env.edr if env.inputs != "fdr" else None,
        "obs_dtype": env.obs_dtype,
    }


def _probe(env_kwargs: dict[str, Any]) -> tuple[tuple[int, ...], int]:
    """One observation's shape (C, H, W) and the action count of these envs (one env made)."""
    probe = make_atari_env(backend="single", **env_kwargs)
    observation = tuple(probe.observation_spec["observation"].shape[-3:])  # (C, H, W)
    actions = probe.action_spec.shape[-1]
    probe.close()
    return observation, actions


def _fresh_network(
    observation: tuple[int, ...], actions: int, network: NetworkSettings, frame_stack: int
) -> tuple[PAACNetwork, dict[str, Any]]:
    """A fresh network for ``frame_stack`` observations of ``observation`` (C, H, W) and
    ``actions`` actions; its arguments."""
    arguments = {
        "in_channels": frame_stack * observation[0],
        "num_actions": actions,
        "core": network.core,
        "init": network.init,
        "input_norm": network.input_norm,
        "frames": frame_stack,
    }
    return PAACNetwork(**arguments), arguments


def _network(env_kwargs: dict[str, Any], network: NetworkSettings, frame_stack: int) -> PAACNetwork:
    """A fresh network for ``frame_stack`` frames of these envs and their actions."""
    return _fresh_network(*_probe(env_kwargs), network, frame_stack)[0]


def _evaluate(
    network: PAACNetwork | UniformPolicy, env_kwargs: dict[str, Any], frame_stack: int, backend: Backend,
    seed: int, settings: EvalSettings,
) -> Games:  # fmt: skip
    """``settings.plays`` whole games (raw scores: no life loss, no clipping), played at once
    on as many envs: EnvPool's or a batch's when training used it, else serial (the network
    steps them as one batch). The network plays in eval mode: batch-normed frames by the running statistics
    training left, not by the statistics of the games played together, which it leaves as they
    were; its actions sampled from the policy or greedy (``settings.policy``)."""
    backend = backend if backend in ("envpool", "batch") else "serial"
    env = _env(num_envs=settings.plays, backend=backend, train=False, **env_kwargs)
    env.set_seed(seed + 1)
    was_training = network.training
    network.eval()
    try:
        with tqdm(total=settings.plays, desc="evaluation", unit="game", leave=False) as bar:
            return Actor(env, network, frame_stack).play(
                settings.max_steps, greedy=settings.policy == "greedy", on_end=bar.update
            )
    finally:
        network.train(was_training)
        env.close()


def _write_results(out_dir: Path, history: list[dict], scores: list[float], title: str) -> None:
    write_json_atomic(out_dir / HISTORY, history)
    write_json_atomic(out_dir / SCORES, scores)
    save_score_curve(history, out_dir / "training_curve.png", title=title)


def _score_metrics(games: Games | None, prefix: str = "eval/") -> dict[str, float | int]:
    """Min, max and mean of the games' scores (NaN when no game was played: a divergence), and
    their mean length (agent steps) and clipped return (what training maximises)."""
    if games is None:
        nan = float("nan")
        return {f"{prefix}plays": 0, f"{prefix}min": nan, f"{prefix}max": nan,
                f"{prefix}mean": nan}  # fmt: skip
    return {
        f"{prefix}plays": len(games.scores),
        f"{prefix}min": float(np.min(games.scores)),
        f"{prefix}max": float(np.max(games.scores)),
        f"{prefix}mean": float(np.mean(games.scores)),
        f"{prefix}steps_mean": float(np.mean(games.steps)),
        f"{prefix}clipped_mean": float(np.mean(games.clipped)),
    }


def _scored_file(folder: RunFolder) -> Path:
    """What :func:`evaluate_checkpoint` scores: a finished run's ``network.pt``, though it keeps
    its checkpoint (to train on), else the checkpoint (a stopped run; a diverged one, whose
    ``network.pt`` may hold NaN and whose checkpoint the last network that was numbers)."""
    finished = folder.record["status"] == "finished"
    metrics = folder.record.get("metrics")
    diverged = isinstance(metrics, dict) and "train/diverged_step" in metrics
    order = (NETWORK, CHECKPOINT) if finished and not diverged else (CHECKPOINT, NETWORK)
    source = next((folder.path / n for n in order if (folder.path / n).is_file()), None)
    if source is None:
        raise FileNotFoundError(
            f"{folder.path} has no {CHECKPOINT}: a run writes one every task.checkpoint_every "
            f"updates and where Ctrl-C or SIGTERM stops it (nor the {NETWORK} a finished run "
            "leaves)"
        )
    return source


def evaluation_file(source: Path, seed: int, plays: int) -> Path:
    """Where edr-eval writes its scores of ``source``: beside it, named for the evaluation
    (``network_eval_seed0_plays30.json``); never over the run's own evaluation."""
    return source.with_name(f"{source.stem}_eval_seed{seed}_plays{plays}.json")


# What edr-eval's refusals of a record or checkpoint advise (never an edr-run option).
EDR_EVAL = Reader(
    name="edr-eval", verb="score", tasks=("atari",),
    elsewhere="a recognition run's test accuracy is in its run.json, its model in model.pt",
    remedy="score a run folder edr-run wrote, or a copy of it whose files are whole",
)  # fmt: skip
# What load_network's refusals advise.
NETWORK_LOADER = Reader(
    name="load_network", verb="load", tasks=("atari",),
    elsewhere="load a recognition run's model with edr.tasks.recognition.load_model",
    remedy="load a run folder edr-run wrote, or a copy of it whose files are whole",
)  # fmt: skip


class _Saved(NamedTuple):
    """What a checkpoint or ``network.pt`` holds that a reader of its network uses."""

    weights: dict[str, Any]  # the network's state dict, not yet checked against the network
    precision: Any  # the precision it trained in (None in runs from before the setting)
    env_steps: int | None  # the env steps the weights had trained


def _saved(folder: RunFolder, source: Path, reader: Reader) -> _Saved:
    """What ``source`` (the folder's checkpoint or ``network.pt``) holds, read without building
    anything; one line naming the file, with ``reader``'s remedy, where it is not what edr-run
    writes. The env steps: a checkpoint's own count, else the record's."""
    state = load_checkpoint(source, remedy=reader.remedy)
    part = functools.partial(payload_part, source, state, remedy=reader.file_remedy)
    if source.name == CHECKPOINT:
        return _Saved(part("network", dict), state.get("precision"), part("env_steps", int))
    weights, arguments = part("state_dict", dict), part("arguments", dict)
    metrics = folder.record.get("metrics")
    steps = metrics.get("train/env_steps") if isinstance(metrics, dict) else None
    return _Saved(weights, arguments.get("precision"), steps)


def _loaded(task: dict[str, Any], source: Path, saved: _Saved, reader: Reader) -> PAACNetwork:
    """The network ``task`` (train_paac's arguments, from the run's record) describes (one probe
    env made), holding ``saved``'s weights (refused in one line naming ``source`` unless they
    are its keys and shapes), in the precision it trained in."""
    env = task["env"]
    network = _network(_env_kwargs(env), task["network"], env.frame_stack)
    check_weights(source, saved.weights, network.state_dict(), reader.file_remedy)
    network.load_state_dict(saved.weights)
    # runs from before the precision setting trained in float32
    precision = saved.precision
    network.precision = precision if precision in ("float32", "bfloat16") else "float32"
    return network


def load_network(run_dir: str | Path, trust_env_module: bool = False) -> PAACNetwork:
    """The network an Atari run trained, from its ``network.pt``. The folder is checked first, as
    edr-eval checks the folder it scores (:mod:`edr.tasks.run_folder`): no live run holds it,
    its record is an Atari run's as edr-run writes it and builds only the suite's own parts
    (a module it names imported only with ``trust_env_module``), and ``network.pt`` holds what
    edr-run writes, the weights of the network the record describes. Each refusal is one line
    naming the file; nothing is written."""
    folder = open_run_folder(Path(run_dir), NETWORK_LOADER, trust_env_module=trust_env_module,
                             writes=False)  # fmt: skip
    source = folder.path / NETWORK
    saved = _saved(folder, source, NETWORK_LOADER)
    task = instantiate_from_record(folder.task, "config.task").keywords  # EDR built
    return _loaded(task, source, saved, NETWORK_LOADER)


def evaluate_checkpoint(
    run_dir: str | Path, plays: int | None = None, trust_env_module: bool = False,
    random_play: bool = False, seed: int | None = None,
) -> dict[str, Any]:  # fmt: skip
    """Score an Atari run's network again: a finished run's trained ``network.pt`` (such as those
    kept behind Table 1), else its latest checkpoint (a run stopped before its end, or one that
    diverged: its checkpoint holds the last network that was numbers).

    The folder is checked first (:func:`edr.tasks.run_folder.open_run_folder`: no live run
    holds it, it takes a new file, its record is one edr-run wrote); then the envs and network
    are rebuilt from the record, the file's weights checked against that network, and ``plays``
    games (the run's ``evaluation.plays`` by default) played as the run's evaluation does, the
    network in eval mode, its actions and the envs seeded by ``seed`` (the run's own by
    default): the same seed gives the same scores. With ``random_play``, random play's games on
    the same envs and seeds beside (``random/`` metrics). The metrics hold each side's mean
    game length (agent steps) and clipped return. They, with every game's score, go to
    :func:`evaluation_file` beside the scored file; nothing of the run's own is written over.
    Returns them. The record builds only the suite's own parts (:mod:`edr.tasks.rebuild`), and
    a module it names (``task.env.env_module``, or gymnasium's ``module:Env-v0`` in an env id)
    is imported only with ``trust_env_module``.
    """
    folder = open_run_folder(Path(run_dir), EDR_EVAL, trust_env_module=trust_env_module)
    source = _scored_file(folder)
    saved = _saved(folder, source, EDR_EVAL)
    # train_paac's arguments, EDR built
    task = instantiate_from_record(folder.task, "config.task").keywords
    network = _loaded(task, source, saved, EDR_EVAL)
    env, evaluation = task["env"], task["evaluation"]
    if plays is not None:
        evaluation = replace(evaluation, plays=plays)
    seed = folder.record["seed"] if seed is None else seed
    env_kwargs = _env_kwargs(env)
    play = functools.partial(_evaluate, env_kwargs=_frames_for(network, env_kwargs),
                             frame_stack=env.frame_stack, backend=env.resolved_backend(),
                             seed=seed, settings=evaluation)  # fmt: skip
    torch.manual_seed(seed)  # the actions sampled
    games = play(network)
    metrics = {"train/env_steps": saved.env_steps, "eval/seed": seed, **_score_metrics(games),
               **_evaluation_mode(evaluation)}  # fmt: skip
    if random_play:
        torch.manual_seed(seed)
        metrics |= _score_metrics(play(UniformPolicy(network.policy.out_features)), "random/")
    write_json_atomic(evaluation_file(source, seed, evaluation.plays),
                      {**metrics, "scores": games.scores})  # fmt: skip
    return metrics
