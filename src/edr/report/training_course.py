"""What an Atari game's training histories say over training (issue 69: Centipede's decline):
per input and point in training, the training score (the game's raw points, the mean of the
last 20 episodes) beside the critic's mean value, the policy's entropy, the value loss and the
logits' spread; and, at the end, the evaluation's game length and clipped return beside random
play's (``network_eval.json``, from ``edr-eval RUN --random-play``).

The critic's mean value tracks the return training maximises (discounted, rewards clipped to
their sign): where the score falls while that value rises, the policy is getting better at its
objective and worse at the game. :func:`implied_value` ties the two: the value a constant
clipped-reward rate and game length predict, to hold against the critic's.

``python -m edr.report.training_course results/learning/table1_centipede`` prints the tables
(it writes nothing).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from edr.report.atari_curves import INPUT_NAMES, M, score_at
from edr.report.runs import finished, load_runs, run_history, run_json

POINTS = (250_000, 1_000_000, 2_000_000, 3_000_000, 4_000_000, 5_000_000)  # env steps shown
WINDOW = 250_000  # env steps before each point that its diagnostics are averaged over
DIAGNOSTICS = {
    "train/value_mean": "critic's mean value",
    "train/entropy": "entropy (nats)",
    "train/loss_critic": "value loss",
    "train/logit_spread": "logit spread",
    "train/grad_norm": "gradient norm",
}


def mean_before(history: list[dict[str, Any]], key: str, end: int, window: int = WINDOW) -> float:
    """The mean of ``key`` over the ``history`` rows in (``end`` - ``window``, ``end``] env
    steps; NaN where none holds it."""
    values = [r[key] for r in history if end - window < r["env_steps"] <= end and key in r]
    return float(np.mean(values)) if values else float("nan")


def implied_value(clipped: float, steps: float, discount: float = 0.99) -> float:
    """The critic's value averaged over a game's states for a policy that earns ``clipped``
    clipped reward in a game of ``steps`` agent steps at a constant rate ρ = clipped / steps:
    the mean over t < L of ρ (1 - γ^(L-t)) / (1 - γ), i.e.
    ρ / (1 - γ) (1 - γ (1 - γ^L) / (L (1 - γ)))."""
    rate, horizon = clipped / steps, 1.0 - discount
    return rate / horizon * (1.0 - discount * (1.0 - discount**steps) / (steps * horizon))


def _input(run: pd.Series) -> str:
    """A run's input as Table 1 names it."""
    inputs = run["config.task.env.inputs"]
    return INPUT_NAMES.get(inputs, inputs)


def course_rows(runs: pd.DataFrame, points: tuple[int, ...] = POINTS) -> pd.DataFrame:
    """One row per finished Atari run of ``runs`` and point of ``points`` its history reached:
    input, seed, env steps, training score there and the diagnostics averaged over the
    ``WINDOW`` before it."""
    rows = []
    for _, run in finished(runs, "atari").iterrows():
        history = run_history(run["record"])
        for at in points:
            score = score_at(history, at)
            if score is None:
                continue
            rows.append({
                "input": _input(run),
                "seed": run["seed"], "env steps": at, "score": score,
                **{name: mean_before(history, key, at) for key, name in DIAGNOSTICS.items()},
            })  # fmt: skip
    return pd.DataFrame(rows)


def end_rows(runs: pd.DataFrame) -> pd.DataFrame:
    """One row per finished Atari run of ``runs`` scored beside random play (its
    ``network_eval.json`` with ``random/`` metrics): each side's score, game length, clipped
    return, and the critic's mean value that the clipped return and length imply, beside the
    critic's own over the history's last ``WINDOW``."""
    rows = []
    for _, run in finished(runs, "atari").iterrows():
        scored = run_json(Path(run["record"]).parent, "network_eval.json") or {}
        if "random/mean" not in scored:
            continue
        history = run_history(run["record"])
        last = history[-1]["env_steps"] if history else 0
        discount = run.get("config.task.loss.discount", 0.99)
        row = {"input": _input(run),
               "seed": run["seed"],
               "critic's value (last)": mean_before(history, "train/value_mean", last)}  # fmt: skip
        for side, prefix in (("agent", "eval/"), ("random", "random/")):
            clipped, steps = scored[f"{prefix}clipped_mean"], scored[f"{prefix}steps_mean"]
            row |= {
                f"{side} score": scored[f"{prefix}mean"],
                f"{side} steps": steps,
                f"{side} clipped": clipped,
                f"{side} points a reward": scored[f"{prefix}mean"] / clipped,
                f"{side} implied value": implied_value(clipped, steps, discount),
            }
        rows.append(row)
    return pd.DataFrame(rows)


def _spread(values: pd.Series) -> str:
    if values.isna().all():
        return "—"
    low, high, mean = values.min(), values.max(), values.mean()
    digits = 0 if abs(mean) >= 100 else 2
    return f"{mean:,.{digits}f} ({low:,.{digits}f} - {high:,.{digits}f})"


def course_markdown(folder: Path) -> str:
    """The course of training (mean (min - max) over seeds per input and point) and the end's
    evaluation beside random play, for the runs under ``folder``."""
    runs = load_runs([folder])
    course = course_rows(runs)
    if course.empty:
        return f"No finished Atari runs with a history under {folder}.\n"
    columns = ["score", *DIAGNOSTICS.values()]
    table = course.groupby(["input", "env steps"])[columns].agg(_spread).reset_index()
    table["env steps"] = table["env steps"].map(lambda s: f"{s / M:g}M")
    lines = [
        f"# The course of training under `{folder}`",
        "",
        f"Mean (min - max) over seeds; the diagnostics averaged over the {WINDOW / M:g}M env "
        "steps before each point, the score the training score there.",
        "",
        table.to_markdown(index=False),
    ]
    end = end_rows(runs)
    if not end.empty:
        summary = end.groupby("input").agg(_spread).drop(columns="seed").T
        lines += ["", "## The end, scored beside random play (network_eval.json)", "",
                  summary.to_markdown()]  # fmt: skip
    return "\n".join([*lines, ""])


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m edr.report.training_course",
                                     description=__doc__)  # fmt: skip
    parser.add_argument("folder", type=Path, help="a sweep folder of one game's Atari runs")
    print(course_markdown(parser.parse_args(argv).folder))


if __name__ == "__main__":
    main()
