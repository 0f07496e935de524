"""What an Atari game's training histories say over training (issue 69: Centipede's decline):
per input and point in training, the training score (the game's raw points, the mean of the
last 20 episodes) beside the critic's mean value, the policy's entropy, the value loss and the
logits' spread; and, at the end, the evaluation's game length and clipped return beside random
play's (``network_eval.json``, from ``edr-eval RUN --random-play``).

The critic's mean value tracks the return training maximises (discounted, rewards clipped to
their sign): where the score falls while that value rises, the policy is getting better at its
objective and worse at the game. :func:`implied_value` ties the two: the value a constant
clipped-reward rate and game length predict, to hold against the critic's.

Across games, :func:`score_value_agreement` says per run whether the two go together: the rank
correlation of the training score with the critic's mean value from 1M env steps on (positive
on every control game, negative on every Centipede run).

``python -m edr.report.training_course results/learning/table1_centipede`` prints the tables
(it writes nothing); several folders compare games, ``--per-run`` shows each seed, ``--points
1 5`` chooses the points (millions of env steps).
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
AGREEMENT_FROM = 1_000_000  # env steps from which the score's agreement with the value is read
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


def score_value_agreement(history: list[dict[str, Any]], start: int = AGREEMENT_FROM) -> float:
    """Spearman's rank correlation of the training score with the critic's mean value over the
    ``history`` rows from ``start`` env steps on that hold both: near +1 where the return training
    maximises rises with the game's score, negative where they part; NaN under 3 such rows."""
    rows = [r for r in history if r["env_steps"] >= start and "train/score" in r
            and "train/value_mean" in r]  # fmt: skip
    if len(rows) < 3:
        return float("nan")
    pair = pd.DataFrame({"score": [r["train/score"] for r in rows],
                         "value": [r["train/value_mean"] for r in rows]}).rank()  # fmt: skip
    return float(pair["score"].corr(pair["value"]))


def implied_value(clipped: float, steps: float, discount: float = 0.99) -> float:
    """The critic's value averaged over a game's states for a policy that earns ``clipped``
    clipped reward in a game of ``steps`` agent steps at a constant rate ρ = clipped / steps:
    the mean over t < L of ρ (1 - γ^(L-t)) / (1 - γ), i.e.
    ρ / (1 - γ) (1 - γ (1 - γ^L) / (L (1 - γ)))."""
    rate, horizon = clipped / steps, 1.0 - discount
    return rate / horizon * (1.0 - discount * (1.0 - discount**steps) / (steps * horizon))


def _labels(run: pd.Series) -> dict[str, Any]:
    """A run's game, input as Table 1 names it, and seed."""
    inputs = run["config.task.env.inputs"]
    return {"game": run.get("config.task.env.game", "?"), "input": INPUT_NAMES.get(inputs, inputs),
            "seed": run["seed"]}  # fmt: skip


def course_rows(runs: pd.DataFrame, points: tuple[int, ...] = POINTS) -> pd.DataFrame:
    """One row per finished Atari run of ``runs`` and point of ``points`` its history reached:
    game, input, seed, env steps, training score there and the diagnostics averaged over the
    ``WINDOW`` before it."""
    rows = []
    for _, run in finished(runs, "atari").iterrows():
        history = run_history(run["record"])
        for at in points:
            score = score_at(history, at)
            if score is None:
                continue
            rows.append({
                **_labels(run), "env steps": at, "score": score,
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
        row = {**_labels(run),
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


def agreement_rows(runs: pd.DataFrame, start: int = AGREEMENT_FROM) -> pd.DataFrame:
    """One row per finished Atari run of ``runs`` with a history past ``start``: the training
    score and the critic's mean value at ``start`` and at the history's end, and
    :func:`score_value_agreement` between them."""
    rows = []
    for _, run in finished(runs, "atari").iterrows():
        history = run_history(run["record"])
        last = history[-1]["env_steps"] if history else 0
        if last <= start:
            continue
        rows.append({
            **_labels(run), "to env steps": last,
            "score from": score_at(history, start), "score to": score_at(history, last),
            "value from": mean_before(history, "train/value_mean", start),
            "value to": mean_before(history, "train/value_mean", last),
            "agreement": score_value_agreement(history, start),
        })  # fmt: skip
    return pd.DataFrame(rows)


def _spread(values: pd.Series) -> str:
    if values.isna().all():
        return "—"
    low, high, mean = values.min(), values.max(), values.mean()
    digits = 0 if abs(mean) >= 100 else 2
    return f"{mean:,.{digits}f} ({low:,.{digits}f} - {high:,.{digits}f})"


def _millions(steps: pd.Series) -> pd.Series:
    return steps.map(lambda s: f"{s / M:g}M")


def course_markdown(
    folders: list[Path], points: tuple[int, ...] = POINTS, per_run: bool = False
) -> str:
    """The course of training at ``points`` (mean (min - max) over seeds per game, input and
    point; each run's own with ``per_run``), each run's score against the critic's value from
    1M env steps on (:func:`agreement_rows`), and the end's evaluation beside random play, for
    the runs under ``folders``."""
    runs = load_runs(folders)
    course = course_rows(runs, points)
    named = ", ".join(f"`{folder}`" for folder in folders)
    if course.empty:
        return f"No finished Atari runs with a history under {named}.\n"
    columns = ["score", *DIAGNOSTICS.values()]
    keys = ["game", "input", "seed", "env steps"] if per_run else ["game", "input", "env steps"]
    table = course.sort_values(keys)[[*keys, *columns]] if per_run else (
        course.groupby(keys)[columns].agg(_spread).reset_index())  # fmt: skip
    table["env steps"] = _millions(table["env steps"])
    each = "Each run" if per_run else "Mean (min - max) over seeds"
    lines = [
        f"# The course of training under {named}",
        "",
        f"{each}; the diagnostics averaged over the {WINDOW / M:g}M env steps before each "
        "point, the score the training score there.",
        "",
        table.to_markdown(index=False, floatfmt=",.2f"),
    ]
    agreement = agreement_rows(runs)
    if not agreement.empty:
        agreement = agreement.sort_values(["game", "input", "seed"])
        agreement["to env steps"] = _millions(agreement["to env steps"])
        lines += [
            "",
            f"## The score against the critic's value, from {AGREEMENT_FROM / M:g}M env steps on",
            "",
            "agreement: Spearman's rank correlation of the training score with the critic's mean "
            "value over the history's rows (+1: they rise together; negative: the return "
            "training maximises rises as the score falls).",
            "",
            agreement.to_markdown(index=False, floatfmt=",.2f"),
        ]
    end = end_rows(runs)
    if not end.empty:
        summary = end.groupby(["game", "input"]).agg(_spread).drop(columns="seed").T
        summary.columns = [" ".join(pair) for pair in summary.columns]
        lines += ["", "## The end, scored beside random play (network_eval.json)", "",
                  summary.to_markdown()]  # fmt: skip
    return "\n".join([*lines, ""])


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m edr.report.training_course",
                                     description=__doc__)  # fmt: skip
    parser.add_argument("folders", type=Path, nargs="+", metavar="folder",
                        help="a sweep folder of Atari runs (several compare games)")  # fmt: skip
    parser.add_argument("--points", type=float, nargs="+", metavar="MILLIONS",
                        default=[p / M for p in POINTS],
                        help="the env steps shown, in millions (default: %(default)s)")  # fmt: skip
    parser.add_argument("--per-run", action="store_true", help="each seed's row, not the spread")
    args = parser.parse_args(argv)
    points = tuple(round(p * M) for p in args.points)
    print(course_markdown(args.folders, points, args.per_run))


if __name__ == "__main__":
    main()
