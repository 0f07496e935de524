"""Atari with PAAC (the paper's Table 1 and Figure 5): FDR or FDR+EDR input, EDR on the fly.

Top to bottom: envs and network; the loop (:class:`edr.rl.rollout.Actor` plays
``rollout_steps`` steps of every env, the network's outputs kept for the loss; n-step returns
bootstrapped from the value of the state after the rollout; PAAC's loss (:func:`edr.rl.paac.paac_loss`); Adam or PAAC's TensorFlow-style RMSprop with the
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
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from hydra.utils import instantiate
from torchrl.envs import InitTracker, TransformedEnv
from tqdm import tqdm

from edr.atomic import write_json_atomic
from edr.records import read_record
from edr.representations import EDR
from edr.rl.envs import Backend, Preset, make_atari_env, rom_fingerprint
from edr.rl.optim import OptimizerName, make_optimizer
from edr.rl.paac import Core, PAACNetwork, n_step_returns, paac_loss
from edr.rl.rollout import Actor, observations_held
from edr.tasks.checkpoints import (
    CHECKPOINT,
    load_checkpoint,
    restore,
    save_atomic,
    save_checkpoint,
)
from edr.tasks.plots import save_score_curve
from edr.tasks.scalars import open_logger
from edr.validate import (
    ConfigError,
    Fraction,
    LoggerName,
    NonNegativeFloat,
    PositiveFloat,
    PositiveInt,
)

INPUT_NAMES = {"fdr": "FDR", "fdr_edr": "FDR+EDR", "edr": "EDR"}  # as Table 1 names them
NETWORK = "network.pt"  # the trained network's state_dict and the arguments that rebuild it
HISTORY = "history.json"  # a row per log_every updates: env steps, losses, fps, training score
SCORES = "eval_scores.json"  # the raw score of every evaluation game
DEFAULT_LR = {"adam": 7e-4, "rmsprop_tf": 0.0224}  # lr=None: ours for Adam; PAAC's for RMSprop
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
    game: str = "Pong",
    env_id: str | None = None,
    env_module: str | None = None,
    preset: Preset = "paac",
    backend: Backend = "envpool",
    life_loss: bool = False,
    num_envs: PositiveInt = 32,
    input: Literal["fdr", "fdr_edr", "edr"] = "fdr_edr",
    fdr: Literal["rgb", "gray"] = "rgb",
    edr: EDR | None = None,
    frame_stack: PositiveInt = 4,
    obs_dtype: Literal["float16", "float32"] = "float32",
    core: Core = "ftlstm",
    total_frames: PositiveInt = 80_000_000,
    lr_decay_frames: PositiveInt = 80_000_000,
    rollout_steps: PositiveInt = 5,
    optimizer: OptimizerName = "adam",
    lr: PositiveFloat | None = None,
    rmsprop_decay: Fraction = 0.99,
    rmsprop_eps: PositiveFloat = 0.1,
    adam_eps: PositiveFloat = 1e-5,
    gamma: Fraction = 0.99,
    loss_scale: PositiveFloat = 5.0,
    entropy_coeff: NonNegativeFloat = 0.02,
    critic_coeff: NonNegativeFloat = 0.25,
    max_grad_norm: PositiveFloat = 3.0,
    eval_plays: PositiveInt = 30,
    eval_max_steps: PositiveInt = 27_000,
    checkpoint_every: PositiveInt = 500,
    log_every: PositiveInt = 10,
    resume: bool = False,
    logger: LoggerName = "csv",
) -> dict[str, Any]:
    """Train PAAC on ``game`` (or the gymnasium env ``env_id``), then score ``eval_plays`` games.

    ``input``: the frames (``fdr``, in the colour ``fdr`` names), the frames and the ``edr``
    layer's events (``fdr_edr``), or the events alone (``edr``). ``lr=None``: the optimizer's
    own default (:data:`DEFAULT_LR`). Returns the run's metrics.
    """
    if input != "fdr" and not isinstance(edr, EDR):
        raise ConfigError(
            f"task.input={input} computes EDR events on the fly from the representation group, "
            f"which holds {type(edr).__name__}: use representation=edr (representation.color=gray "
            "for the paper's input), or task.input=fdr for frames alone"
        )
    if (env_id is None) != (preset != "none"):
        raise ConfigError(
            "a gymnasium env of your own takes task.env_id=<id> with task.preset=none "
            f"(and task.env_module=<module that registers it>); got env_id={env_id!r}, "
            f"preset={preset!r}"
        )
    name = env_id or game
    # ---- envs, network, optimizer ------------------------------------------------------------
    env_kwargs = _env_kwargs(name, preset, life_loss, env_module, input, fdr, edr, obs_dtype)
    network, arguments = _network(env_kwargs, core, frame_stack)
    env = _env(
        num_envs=num_envs, mode=backend, keep_inputs=False,
        stack_ring=observations_held(rollout_steps, frame_stack), **env_kwargs,
    )  # fmt: skip
    env.set_seed(seed)
    actor = Actor(env, network, frame_stack)
    optim = make_optimizer(
        optimizer,
        network.parameters(),
        lr=lr or DEFAULT_LR[optimizer],
        rmsprop_decay=rmsprop_decay,
        rmsprop_eps=rmsprop_eps,
        adam_eps=adam_eps,
    )
    batch = num_envs * rollout_steps
    schedule = torch.optim.lr_scheduler.LambdaLR(
        optim, lambda update: max(0.0, 1.0 - update * batch / lr_decay_frames)
    )
    frames_done, history = 0, []
    checkpoint = out_dir / CHECKPOINT
    parts = {"network": network, "optimizer": optim, "schedule": schedule}
    if resume:
        state = load_checkpoint(checkpoint)
        restore(state, parts)  # episodes in progress restart
        frames_done, history = state["frames"], state["history"]
    scalars = open_logger(logger, out_dir, step=frames_done)

    def save() -> None:
        save_checkpoint(checkpoint, parts, frames=frames_done, history=history)

    # ---- training ----------------------------------------------------------------------------
    recent: deque[float] = deque(maxlen=20)
    losses: dict[str, float] = {}
    start, frames_at_start = time.perf_counter(), frames_done
    bar = tqdm(
        total=total_frames, initial=frames_done, desc=f"PAAC {name}", unit="frame", unit_scale=True
    )
    updating = False  # between the optimizer's step and the count of env steps that it trained
    window: list[dict[str, float]] = []  # the updates since the last history row

    def log_row() -> None:
        """The updates of ``window`` as one row of the history, the logs and the progress bar."""
        fps = (frames_done - frames_at_start) / (time.perf_counter() - start)
        row = _history_row(frames_done, fps, window, recent)
        window.clear()
        history.append(row)
        if scalars is not None:
            for key, value in row.items():
                if key != "frames":
                    scalars.log_scalar(key, value, step=frames_done)
        bar.set_postfix(score=f"{row.get('train/score', float('nan')):.1f}", fps=f"{fps:.0f}")

    try:
        update = 0
        while frames_done < total_frames:
            update += 1
            rollout = actor.rollout(rollout_steps)
            returns = n_step_returns(rollout.rewards, rollout.dones, rollout.bootstrap, gamma)
            loss, loss_parts = paac_loss(
                rollout.logits, rollout.values, rollout.actions, returns,
                entropy_coeff, critic_coeff, loss_scale,
            )  # fmt: skip
            optim.zero_grad(set_to_none=True)
            loss.backward()
            grad_norm = torch.nn.utils.clip_grad_norm_(network.parameters(), max_grad_norm)
            updating = True
            optim.step()
            schedule.step()
            frames_done += rollout.env_steps
            updating = False
            recent.extend(rollout.scores)
            losses = {k: float(v) for k, v in loss_parts.items()}
            if not all(np.isfinite(v) for v in losses.values()):
                raise FloatingPointError(f"non-finite loss at {frames_done} frames: {losses}")
            window.append({"train/grad_norm": float(grad_norm), **_prefixed(losses)})
            bar.update(rollout.env_steps)
            if update % log_every == 0 or frames_done >= total_frames:
                log_row()
            if update % checkpoint_every == 0:
                save()
    except KeyboardInterrupt:  # Ctrl-C, or SIGTERM through edr-run: keep what was trained
        if not updating:
            if window:
                log_row()
            save()
            log.info("interrupted: checkpoint saved at %d env steps", frames_done)
        raise
    finally:
        bar.close()
        env.close()
    save()

    # ---- evaluation --------------------------------------------------------------------------
    scores = _evaluate(network, env_kwargs, frame_stack, backend, seed, eval_plays, eval_max_steps)
    save_atomic({"state_dict": network.state_dict(), "arguments": arguments}, out_dir / NETWORK)
    _write_results(out_dir, history, scores, f"{name}, {INPUT_NAMES[input]}")
    scored = [row for row in history if "train/score" in row]
    return {
        "data/source": "emulator" if env_id is None else "gymnasium",
        "data/game": name,
        "data/fingerprint": rom_fingerprint(game) if env_id is None else f"{env_module}:{env_id}",
        "train/frames": frames_done,
        "train/fps": history[-1]["train/fps"] if history else float("nan"),
        "train/score_first": scored[0]["train/score"] if scored else None,
        "train/score_last": scored[-1]["train/score"] if scored else None,
        **_prefixed(losses),
        **_score_metrics(scores),
    }


def _prefixed(losses: dict[str, float]) -> dict[str, float]:
    return {f"train/{k}": v for k, v in losses.items()}


def _history_row(
    frames: int, fps: float, window: list[dict[str, float]], recent: deque[float]
) -> dict[str, float]:
    """One row of the training history: the means over the updates of ``window`` (gradient norm,
    losses, entropy), the env steps per second so far, and the mean score of ``recent``."""
    row = {"frames": frames, "train/fps": fps}
    row.update({key: float(np.mean([w[key] for w in window])) for key in window[0]})
    if recent:
        row["train/score"] = float(np.mean(recent))
    return row


def _env_kwargs(
    name: str, preset: Preset, life_loss: bool, env_module: str | None, input: str, fdr: str,
    edr: EDR | None, obs_dtype: str,
) -> dict[str, Any]:  # fmt: skip
    """What ``make_atari_env`` takes for this input (training and evaluation alike): one frame
    per observation, which the :class:`Actor` stacks for the network."""
    return {
        "game": name,
        "preset": preset,
        "life_loss": life_loss,
        "module": env_module,
        "fdr": fdr if input != "edr" else "none",
        "edr": edr if input != "fdr" else None,
        "obs_dtype": obs_dtype,
    }


def _network(
    env_kwargs: dict[str, Any], core: Core, frame_stack: int
) -> tuple[PAACNetwork, dict[str, Any]]:
    """A fresh network for ``frame_stack`` frames of these envs and their actions; its arguments."""
    probe = make_atari_env(mode="single", **env_kwargs)
    channels, actions = probe.observation_spec["observation"].shape[-3], probe.action_spec.shape[-1]
    probe.close()
    arguments = {"in_channels": frame_stack * channels, "num_actions": actions, "core": core}
    return PAACNetwork(**arguments), arguments


def _evaluate(
    network: PAACNetwork, env_kwargs: dict[str, Any], frame_stack: int, backend: Backend,
    seed: int, plays: int, max_steps: int,
) -> list[float]:  # fmt: skip
    """Raw scores of ``plays`` whole games (no life loss, no clipping), played at once on as many
    envs: EnvPool's when training used it, else serial (the network steps them as one batch)."""
    mode = "envpool" if backend == "envpool" else "serial"
    env = _env(num_envs=plays, mode=mode, train=False, **env_kwargs)
    env.set_seed(seed + 1)
    try:
        with tqdm(total=plays, desc="evaluation", unit="game", leave=False) as bar:
            return Actor(env, network, frame_stack).play(max_steps, on_end=bar.update)
    finally:
        env.close()


def _write_results(out_dir: Path, history: list[dict], scores: list[float], title: str) -> None:
    write_json_atomic(out_dir / HISTORY, history)
    write_json_atomic(out_dir / SCORES, scores)
    save_score_curve(history, out_dir / "training_curve.png", title=title)


def _score_metrics(scores: list[float]) -> dict[str, float | int]:
    return {
        "eval/plays": len(scores),
        "eval/min": float(np.min(scores)),
        "eval/max": float(np.max(scores)),
        "eval/mean": float(np.mean(scores)),
    }


def evaluate_checkpoint(run_dir: str | Path, plays: int | None = None) -> dict[str, Any]:
    """Score the network of an Atari run's latest checkpoint, for a run stopped before its end.

    Rebuilds the envs and network from the run's record (``run.json``), plays ``plays`` games
    (the run's ``eval_plays`` by default) as the run would have, and writes ``eval_scores.json``,
    ``history.json``, the training curve and ``checkpoint_eval.json`` (these metrics, with the
    env steps the checkpoint had trained) beside the record. Returns the metrics.
    """
    run_dir = Path(run_dir)
    record = read_record(run_dir / "run.json")
    task = instantiate(record["config"]["task"]).keywords  # train_paac's arguments, EDR built
    name = task["env_id"] or task["game"]
    env_kwargs = _env_kwargs(
        name, task["preset"], task["life_loss"], task["env_module"], task["input"], task["fdr"],
        task["edr"], task["obs_dtype"],
    )  # fmt: skip
    if not (run_dir / CHECKPOINT).is_file():
        raise FileNotFoundError(
            f"{run_dir} has no {CHECKPOINT}: a run writes one every task.checkpoint_every "
            "updates and where Ctrl-C or SIGTERM stops it"
        )
    network, _ = _network(env_kwargs, task["core"], task["frame_stack"])
    state = load_checkpoint(run_dir / CHECKPOINT)
    network.load_state_dict(state["network"])
    scores = _evaluate(
        network, env_kwargs, task["frame_stack"], task["backend"], record["seed"],
        plays or task["eval_plays"], task["eval_max_steps"],
    )  # fmt: skip
    _write_results(run_dir, state["history"], scores, f"{name}, {INPUT_NAMES[task['input']]}")
    metrics = {"train/frames": state["frames"], **_score_metrics(scores)}
    write_json_atomic(run_dir / "checkpoint_eval.json", metrics)
    return metrics


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(
        prog="python -m edr.tasks.atari", description=evaluate_checkpoint.__doc__.split("\n")[0]
    )
    parser.add_argument("run_dir", type=Path, help="the run's folder (run.json, checkpoint.pt)")
    parser.add_argument("--plays", type=int, default=None, help="games (default: the run's)")
    args = parser.parse_args()
    print(json.dumps(evaluate_checkpoint(args.run_dir, args.plays), indent=1))


def load_network(run_dir: str | Path) -> PAACNetwork:
    """The network an Atari run trained, rebuilt from ``network.pt``."""
    saved = torch.load(Path(run_dir) / NETWORK, weights_only=True)
    network = PAACNetwork(**saved["arguments"])
    network.load_state_dict(saved["state_dict"])
    return network
