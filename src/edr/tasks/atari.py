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

import json
import logging
import time
from collections import deque
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torchrl.envs import InitTracker, TransformedEnv
from tqdm import tqdm

from edr import interrupts
from edr.atomic import write_json_atomic
from edr.checkpoints import (
    CHECKPOINT,
    DATA_FINGERPRINT,
    UnreadableCheckpoint,
    check_same_data,
    load_checkpoint,
    restore,
    save_atomic,
    save_checkpoint,
)
from edr.models.dead_units import DeadUnits
from edr.models.paac import PAACNetwork
from edr.rebuild import UntrustedRecord, instantiate_from_record
from edr.records import UnreadableRecord, read_record
from edr.representations import EDR
from edr.rl.envs import Backend, make_atari_env, rom_fingerprint
from edr.rl.loss import n_step_returns, paac_loss
from edr.rl.optim import make_optimizer
from edr.rl.phases import PhaseClock
from edr.rl.rollout import Actor, UniformPolicy, observations_held
from edr.rl.settings import (
    INPUT_NAMES,
    EnvSettings,
    EvalSettings,
    LossSettings,
    NetworkSettings,
    OptimSettings,
)
from edr.rl.transform import ObservationFrame
from edr.tasks.divergence import divergence
from edr.tasks.plots import save_score_curve
from edr.tasks.scalars import open_logger
from edr.validate import ConfigError, LoggerName, PositiveInt, check_memory

NETWORK = "network.pt"  # the trained network's state_dict and the arguments that rebuild it
HISTORY = "history.json"  # a row per log_every updates: env steps, losses, fps, training score
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
    critic's mean value, the fraction of dead units per ReLU layer on the latest rollout, and
    the mean score of the last 20 training episodes.
    """
    _check_env(env, network)
    backend = env.resolved_backend()
    # ---- envs, network, optimizer ------------------------------------------------------------
    env_kwargs = _env_kwargs(env)
    net, arguments, observation = _network(env_kwargs, network, env.frame_stack)
    _check_memory(env, loss.rollout_steps, evaluation.plays, observation)
    envs = _env(
        num_envs=env.num_envs, backend=backend, keep_inputs=False,
        frame_ring=observations_held(loss.rollout_steps, env.frame_stack), **env_kwargs,
    )  # fmt: skip
    envs.set_seed(seed)
    clock = PhaseClock()  # where each update's time goes, into the history
    for transform in envs.transform:  # the observation's transform, where it runs in-process
        if isinstance(transform, ObservationFrame):
            transform.clock = clock
    actor = Actor(envs, net, env.frame_stack, clock)
    dead_units = DeadUnits(net)
    opt = make_optimizer(
        optim.name,
        net.parameters(),
        lr=optim.learning_rate,
        rmsprop_decay=optim.rmsprop_decay,
        rmsprop_eps=optim.rmsprop_eps,
        adam_eps=optim.adam_eps,
    )
    batch = env.num_envs * loss.rollout_steps
    schedule = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda update: max(0.0, 1.0 - update * batch / optim.lr_decay_env_steps)
    )
    steps_done, history = 0, []
    checkpoint = out_dir / CHECKPOINT
    parts = {"network": net, "optimizer": opt, "schedule": schedule}
    fingerprint = (
        rom_fingerprint(env.game) if env.env_id is None else f"{env.env_module}:{env.env_id}"
    )
    if resume:
        state = load_checkpoint(checkpoint)
        check_same_data(state, fingerprint, checkpoint)  # the same ROM (or env) it trained on
        restore(state, parts)  # episodes in progress restart
        steps_done, history = state["env_steps"], state["history"]
    scalars = open_logger(logger, out_dir, step=steps_done)

    def save() -> None:
        save_checkpoint(checkpoint, parts, env_steps=steps_done, history=history,
                        **{DATA_FINGERPRINT: fingerprint})  # fmt: skip

    # ---- training ----------------------------------------------------------------------------
    recent: deque[float] = deque(maxlen=20)
    losses: dict[str, float] = {}
    start, steps_at_start = time.perf_counter(), steps_done
    bar = tqdm(
        total=env_steps, initial=steps_done, desc=f"PAAC {env.name}", unit="step", unit_scale=True
    )
    updating = False  # between the optimizer's step and the count of env steps that it trained
    window: list[dict[str, float]] = []  # the updates since the last history row

    def log_row() -> None:
        """The updates of ``window`` as one row of the history, the logs and the progress bar."""
        fps = (steps_done - steps_at_start) / (time.perf_counter() - start)
        row = _history_row(steps_done, fps, window, recent)
        row.update(dead_units.fractions())  # of the latest rollout
        window.clear()
        history.append(row)
        if scalars is not None:
            for key, value in row.items():
                if key != "env_steps":
                    scalars.log_scalar(key, value, step=steps_done)
        bar.set_postfix(score=f"{row.get('train/score', float('nan')):.1f}", fps=f"{fps:.0f}")

    diverged: dict[str, Any] = {}  # where training stopped being numbers, if it did
    clock.lap()  # the first row's times start with the loop, not with the envs' set-up
    try:
        update = 0
        while steps_done < env_steps:
            update += 1
            interrupts.raise_if_stopping()  # a Ctrl-C some callback dropped stops here
            dead_units.reset()
            try:
                rollout = actor.rollout(loss.rollout_steps)  # the envs' steps, forward passes
            except FloatingPointError as error:  # the network's outputs stopped being numbers
                diverged = _diverged(steps_done, update, str(error))
                break
            with clock.phase("backward"):  # the loss and its gradient
                returns = n_step_returns(
                    rollout.rewards, rollout.dones, rollout.bootstrap, loss.discount
                )
                total, loss_parts = paac_loss(
                    rollout.logits, rollout.values, rollout.actions, returns,
                    loss.entropy_coeff, loss.critic_coeff, loss.scale,
                )  # fmt: skip
                if reason := divergence(net, total):
                    diverged = _diverged(steps_done, update, reason)
                    break
                opt.zero_grad(set_to_none=True)
                total.backward()
            with clock.phase("optimizer"):
                grad_norm = torch.nn.utils.clip_grad_norm_(net.parameters(), optim.max_grad_norm)
                updating = True
                opt.step()
                schedule.step()
            steps_done += rollout.env_steps
            updating = False
            recent.extend(rollout.scores)
            losses = {k: float(v) for k, v in loss_parts.items()}
            if reason := divergence(net):  # the step left NaN or inf in the network
                diverged = _diverged(steps_done, update, reason)
                break
            window.append({
                "train/grad_norm": float(grad_norm),
                "train/value_mean": float(rollout.values.detach().mean()),
                "train/logit_spread": _logit_spread(rollout.logits),
                **clock.lap(),  # time/env_ms, observation, forward, backward, optimizer, other
                **_prefixed(losses),
            })  # fmt: skip
            bar.update(rollout.env_steps)
            if update % log_every == 0 or steps_done >= env_steps:
                log_row()
            if update % checkpoint_every == 0:
                save()
    except KeyboardInterrupt:  # Ctrl-C, or SIGTERM through edr-run: keep what was trained
        if not updating:
            if window:
                log_row()
            save()
            log.info("interrupted: checkpoint saved at %d env steps", steps_done)
        raise
    finally:
        bar.close()
        envs.close()
    if diverged:  # the checkpoint keeps the last network that was numbers; no games to score
        log.warning("training diverged at %d env steps (%s): recorded as diverged",
                    steps_done, diverged["train/diverged_reason"])  # fmt: skip
        if window:
            log_row()
        scores: list[float] = []
    else:
        save()
        scores = _evaluate(net, env_kwargs, env.frame_stack, backend, seed, evaluation)
    # games cut short: random play under the same cap, on the same games, is the yardstick
    random_scores = (
        _evaluate(UniformPolicy(net.policy.out_features), env_kwargs, env.frame_stack, backend, seed,
                  evaluation)
        if evaluation.capped and scores else None
    )  # fmt: skip

    # ---- results -----------------------------------------------------------------------------
    save_atomic({"state_dict": net.state_dict(), "arguments": arguments}, out_dir / NETWORK)
    _write_results(out_dir, history, scores, f"{env.name}, {INPUT_NAMES[env.inputs]}")
    scored = [row for row in history if "train/score" in row]
    return {
        "data/source": "emulator" if env.env_id is None else "gymnasium",
        "data/game": env.name,
        "data/fingerprint": fingerprint,
        "train/env_steps": steps_done,
        "train/fps": history[-1]["train/fps"] if history else float("nan"),
        "train/score_first": scored[0]["train/score"] if scored else None,
        "train/score_last": scored[-1]["train/score"] if scored else None,
        **_prefixed(losses),
        **({k: v for k, v in history[-1].items() if k.startswith("dead/")} if history else {}),
        **_score_metrics(scores),
        **_random_metrics(random_scores, evaluation),
        **diverged,
    }


def _random_metrics(scores: list[float] | None, evaluation: EvalSettings) -> dict[str, float]:
    """Random play's mean under the evaluation's cap, when the run measured it."""
    if scores is None:
        return {}
    return {"eval/random_mean": float(np.mean(scores)), "eval/max_steps": evaluation.max_steps}


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
    if (env.env_id is None) != (env.preset != "none"):
        raise ConfigError(
            "a gymnasium env of your own takes task.env.env_id=<id> with task.env.preset=none "
            f"(and task.env.env_module=<module that registers it>); got env_id={env.env_id!r}, "
            f"preset={env.preset!r}"
        )
    if env.preset == "none" and env.backend == "envpool":
        raise ConfigError(
            "task.env.backend=envpool plays ALE games only: your env needs backend auto, serial "
            "or parallel"
        )


def _check_memory(
    env: EnvSettings, rollout_steps: int, plays: int, observation: tuple[int, ...]
) -> None:
    """Refuse env counts whose observations cannot fit in memory: the frames the training envs
    hold at once, and one step's stacked input of the evaluation games (one env per game)."""
    frame = int(np.prod(observation)) * (2 if env.obs_dtype == "float16" else 4)  # bytes
    held = observations_held(rollout_steps, env.frame_stack)
    check_memory(
        f"task.env.num_envs={env.num_envs}, task.loss.rollout_steps={rollout_steps}, "
        f"task.env.frame_stack={env.frame_stack}",
        f"the {held} observations each of the {env.num_envs} envs holds", env.num_envs * held * frame,
    )  # fmt: skip
    check_memory(
        f"task.evaluation.plays={plays}, task.env.frame_stack={env.frame_stack}",
        f"one step's input of {plays} games played at once", plays * env.frame_stack * frame,
    )  # fmt: skip


def _logit_spread(logits: torch.Tensor) -> float:
    """How much the policy tells states apart: the logits' std across the rollout's states
    (N*T of them), averaged over actions. Near 0 while the policy ignores what it sees."""
    return float(logits.detach().reshape(-1, logits.shape[-1]).std(0).mean())  # (N*T, A) -> ()


def _prefixed(losses: dict[str, float]) -> dict[str, float]:
    return {f"train/{k}": v for k, v in losses.items()}


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


def _network(
    env_kwargs: dict[str, Any], network: NetworkSettings, frame_stack: int
) -> tuple[PAACNetwork, dict[str, Any], tuple[int, ...]]:
    """A fresh network for ``frame_stack`` frames of these envs and their actions; its
    arguments; one observation's shape (C, H, W)."""
    probe = make_atari_env(backend="single", **env_kwargs)
    observation = tuple(probe.observation_spec["observation"].shape[-3:])  # (C, H, W)
    channels, actions = observation[0], probe.action_spec.shape[-1]
    probe.close()
    arguments = {
        "in_channels": frame_stack * channels,
        "num_actions": actions,
        "core": network.core,
        "init": network.init,
        "input_norm": network.input_norm,
        "frames": frame_stack,
    }
    return PAACNetwork(**arguments), arguments, observation


def _evaluate(
    network: PAACNetwork | UniformPolicy, env_kwargs: dict[str, Any], frame_stack: int, backend: Backend,
    seed: int, settings: EvalSettings,
) -> list[float]:  # fmt: skip
    """Raw scores of ``settings.plays`` whole games (no life loss, no clipping), played at once
    on as many envs: EnvPool's when training used it, else serial (the network steps them as
    one batch)."""
    backend = "envpool" if backend == "envpool" else "serial"
    env = _env(num_envs=settings.plays, backend=backend, train=False, **env_kwargs)
    env.set_seed(seed + 1)
    try:
        with tqdm(total=settings.plays, desc="evaluation", unit="game", leave=False) as bar:
            return Actor(env, network, frame_stack).play(settings.max_steps, on_end=bar.update)
    finally:
        env.close()


def _write_results(out_dir: Path, history: list[dict], scores: list[float], title: str) -> None:
    write_json_atomic(out_dir / HISTORY, history)
    write_json_atomic(out_dir / SCORES, scores)
    save_score_curve(history, out_dir / "training_curve.png", title=title)


def _score_metrics(scores: list[float]) -> dict[str, float | int]:
    """Min, max and mean of the games' scores (NaN when no game was played: a divergence)."""
    nan = float("nan")
    return {
        "eval/plays": len(scores),
        "eval/min": float(np.min(scores)) if scores else nan,
        "eval/max": float(np.max(scores)) if scores else nan,
        "eval/mean": float(np.mean(scores)) if scores else nan,
    }


def load_network(run_dir: str | Path) -> PAACNetwork:
    """The network an Atari run trained, rebuilt from ``network.pt``."""
    saved = torch.load(Path(run_dir) / NETWORK, weights_only=True)
    network = PAACNetwork(**saved["arguments"])
    network.load_state_dict(saved["state_dict"])
    return network


def evaluate_checkpoint(
    run_dir: str | Path, plays: int | None = None, trust_env_module: bool = False
) -> dict[str, Any]:
    """Score the network of an Atari run's latest checkpoint, for a run stopped before its end.

    Rebuilds the envs and network from the run's record (``run.json``), plays ``plays`` games
    (the run's ``evaluation.plays`` by default) as the run would have, and writes
    ``eval_scores.json``, ``history.json``, the training curve and ``checkpoint_eval.json``
    (these metrics, with the env steps the checkpoint had trained) beside the record. Returns
    the metrics. The record builds only the suite's own parts (:mod:`edr.rebuild`), and a
    module it names (``task.env.env_module``, or gymnasium's ``module:Env-v0`` in an env id) is
    imported only with ``trust_env_module``.
    """
    run_dir = Path(run_dir)
    record = read_record(run_dir / "run.json")
    if not (run_dir / CHECKPOINT).is_file():
        raise FileNotFoundError(
            f"{run_dir} has no {CHECKPOINT}: a run writes one every task.checkpoint_every "
            "updates and where Ctrl-C or SIGTERM stops it"
        )
    node = record.get("config", {})
    if not isinstance(node, dict) or not isinstance(node.get("task"), dict):
        raise UnreadableRecord(f"{run_dir / 'run.json'} has no config.task to rebuild the run from")
    # train_paac's arguments, EDR built
    task = instantiate_from_record(node["task"], "config.task").keywords
    env = task["env"]
    if env.modules and not trust_env_module:
        raise UntrustedRecord(
            f"{run_dir / 'run.json'} names the module {', '.join(env.modules)} (task.env: "
            f"env_module={env.env_module}, env_id={env.env_id}, game={env.game}): making its env "
            "imports it, which runs its code; pass --trust-env-module (trust_env_module=True) "
            "if you trust it"
        )
    evaluation = task["evaluation"]
    env_kwargs = _env_kwargs(env)
    network, _, _ = _network(env_kwargs, task["network"], env.frame_stack)
    state = load_checkpoint(run_dir / CHECKPOINT)
    network.load_state_dict(state["network"])
    if plays is not None:
        evaluation = replace(evaluation, plays=plays)
    scores = _evaluate(
        network, env_kwargs, env.frame_stack, env.resolved_backend(), record["seed"], evaluation
    )
    _write_results(run_dir, state["history"], scores, f"{env.name}, {INPUT_NAMES[env.inputs]}")
    metrics = {"train/env_steps": state["env_steps"], **_score_metrics(scores)}
    write_json_atomic(run_dir / "checkpoint_eval.json", metrics)
    return metrics


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(
        prog="python -m edr.tasks.atari", description=evaluate_checkpoint.__doc__.split("\n")[0]
    )
    parser.add_argument("run_dir", type=Path, help="the run's folder (run.json, checkpoint.pt)")
    parser.add_argument("--plays", type=int, default=None, help="games (default: the run's)")
    parser.add_argument(
        "--trust-env-module",
        action="store_true",
        help="import the module the record names (task.env.env_module): it runs its code",
    )
    args = parser.parse_args()
    try:
        metrics = evaluate_checkpoint(args.run_dir, args.plays, args.trust_env_module)
    except (UntrustedRecord, UnreadableRecord, UnreadableCheckpoint, FileNotFoundError) as error:
        parser.exit(2, f"{parser.prog}: {error}\n")
    print(json.dumps(metrics, indent=1))
