"""Table 1: PAAC on Atari, FDR vs FDR+EDR — Avg / Best / Worst of the evaluation games, the
paper's average gain, and (beyond the paper) the interquartile mean of human-normalised scores
with stratified-bootstrap 95 % intervals (rliable)."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

import numpy as np
import pandas as pd

from edr.report.atari_curves import INPUT_NAMES, millions, steps_to_targets_block
from edr.report.published import cite, lookup
from edr.report.render import Table, mean_std
from edr.report.runs import cells, finished, placeable, run_attempts, unfinished
from edr.store.identity import ADDED_DEFAULTS

SCORES = {"Avg": "metrics.eval/mean", "Best": "metrics.eval/max", "Worst": "metrics.eval/min"}
FPS = "metrics.train/fps"  # the training loop's env steps/s over a run's last attempt
# Table 1's budget per game in env steps (Appendix C: Pong stops at 30M, the other games at 80M)
PAPER_ENV_STEPS = {"Pong": 30_000_000}
PAPER_ENV_STEPS_OTHERWISE = 80_000_000
# Settings Table 1's notes name wherever its rows differ in them (each row is one cell: runs that
# share every setting but the seed), and the value of a record that predates the setting.
NAMED_SETTINGS = {
    "config.task.loss.entropy_coeff": ("entropy weight", None),
    "config.task.optim.lr_decay_env_steps": ("learning rate decayed to 0 at (env steps)", None),
    "config.task.optim.lr_warmup_env_steps": (
        "learning-rate warmup (env steps)",
        ADDED_DEFAULTS["edr.rl.settings.OptimSettings"]["lr_warmup_env_steps"],
    ),
    "config.task.loss.advantage": (
        "advantage", ADDED_DEFAULTS["edr.rl.settings.LossSettings"]["advantage"],
    ),
    "config.task.env.num_envs": ("envs", None),
    "metrics.train/precision": (
        "precision", ADDED_DEFAULTS["edr.rl.settings.NetworkSettings"]["precision"],
    ),
}  # fmt: skip


def atari_runs(runs: pd.DataFrame) -> pd.DataFrame:
    """Finished Atari runs with ``game``, ``input``, ``budget`` (``"5M"``) and ``label`` columns:
    the label is the input's name, with its budget where runs of several budgets are shown
    together (``"FDR at 5M"``), so that no mean, curve or profile mixes budgets. A full-scale run
    trained on fewer env steps than the paper's says so in its ``scale``."""
    done = finished(runs, "atari").copy()
    if done.empty:
        return done.assign(game=[], input=[], budget=[], label=[])
    given = done.reindex(columns=["config.task.env.game", "config.task.env.inputs",
                                  "config.task.env_steps"])  # fmt: skip  # NaN where none says
    done["config.task.env_steps"] = given["config.task.env_steps"]
    done["game"] = given["config.task.env.game"]
    done["input"] = given["config.task.env.inputs"]
    budget = pd.to_numeric(given["config.task.env_steps"], errors="coerce")
    done["budget"] = [f"{b / 1e6:g}M" if pd.notna(b) else "?" for b in budget]
    several = done["budget"].nunique() > 1  # then every label names its budget
    done["label"] = [
        f"{INPUT_NAMES.get(i, i)} at {b}" if several else INPUT_NAMES.get(i, i)
        for i, b in zip(done["input"], done["budget"], strict=True)
    ]
    paper = done["game"].map(_paper_env_steps)
    cut = (done["scale"] == "full") & (budget < paper)
    done.loc[cut, "scale"] = [
        f"full settings, but {steps / 1e6:g}M of the paper's {full / 1e6:g}M env steps"
        for steps, full in zip(budget[cut], paper[cut], strict=True)
    ]
    return done


def average_gains(games: dict[str, dict[str, dict[str, float]]]) -> dict[str, float | None]:
    """Table 1's "Avg. gain" row: per column (avg, best, worst), the mean over games of FDR+EDR's
    relative change over FDR, in %: mean((EDR - FDR) / |FDR|). ``games``: game -> input
    (``fdr``, ``fdr_edr``) -> column -> score. On the paper's own rows it gives its +23.8 /
    +20.9 / +70.2 (tested)."""
    gains: dict[str, float | None] = {}
    for column in ("avg", "best", "worst"):
        changes = [
            100
            * (by_input["fdr_edr"][column] - by_input["fdr"][column])
            / abs(by_input["fdr"][column])
            for by_input in games.values()
            if {"fdr", "fdr_edr"} <= set(by_input) and by_input["fdr"].get(column)
        ]
        gains[column] = float(np.mean(changes)) if changes else None
    return gains


def _our_games(grouped: pd.DataFrame) -> dict[str, dict[str, dict[str, float]]]:
    """game -> input -> column -> our seed-averaged score, for games with one cell per input (of
    one budget: ``grouped``'s cells are of one)."""
    games: dict[str, dict[str, dict[str, float]]] = {}
    for game, rows in grouped.groupby("game"):
        if rows["input"].is_unique:
            games[game] = {
                r["input"]: {c.lower(): r[f"{m}:mean"] for c, m in SCORES.items()}
                for _, r in rows.iterrows()
            }
    return games


def _gain_block(grouped: pd.DataFrame, published: dict[str, Any]) -> str:
    paper = lookup(published, "table1_atari", "games") or {}
    paper_games = {g: {i: dict(cols) for i, cols in by.items()} for g, by in paper.items()}
    printed = lookup(published, "table1_atari", "avg_gain_percent") or {}
    budgets = sorted(grouped["budget"].unique(), key=millions)
    rows = [
        ("the paper, as printed", printed),
        ("the paper, recomputed from its rows", average_gains(paper_games)),
        *(
            (f"ours at {budget} env steps (the games we ran with both inputs)",
             average_gains(_our_games(grouped[grouped["budget"] == budget])))
            for budget in budgets
        ),
    ]  # fmt: skip
    lines = [
        "Avg. gain of FDR+EDR over FDR: per column, the mean over games of (EDR - FDR) / |FDR|, %.",
        "",
        "| Avg. gain | Avg | Best | Worst |",
        "|---|---:|---:|---:|",
    ]
    for label, gains in rows:
        cells = [cite(gains.get(c), "+.1f") for c in ("avg", "best", "worst")]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _paper_rows(published: dict[str, Any]) -> pd.DataFrame:
    games = lookup(published, "table1_atari", "games") or {}
    return pd.DataFrame(
        [
            {"Game": game, "Input": INPUT_NAMES[i], **{c: cols[c.lower()] for c in SCORES},
             "Env steps": f"{_paper_env_steps(game) / 1e6:g}M"}
            for game, by_input in games.items()
            for i, cols in by_input.items()
        ]
    )  # fmt: skip


def _paper_env_steps(game: str) -> int:
    return PAPER_ENV_STEPS.get(game, PAPER_ENV_STEPS_OTHERWISE)


def normalised_scores(done: pd.DataFrame, published: dict[str, Any]) -> dict[str, np.ndarray]:
    """Per label (an input, and its budget where there are several: :func:`atari_runs`), (runs,
    games) human-normalised average scores — the games every label of its budget has, the
    first n seeds where each game has at least n runs."""
    reference = published.get("atari_reference_scores", {})
    out = {}
    for _, at_budget in done.groupby("budget"):
        labels = at_budget.groupby("label")
        games = sorted(set.intersection(*(set(g["game"]) for _, g in labels)) & reference.keys())
        for name, runs in labels:
            per_game = [
                runs[runs["game"] == g].sort_values("seed")[SCORES["Avg"]].to_numpy() for g in games
            ]
            n = min((len(s) for s in per_game), default=0)
            if n and games:
                ref = [reference[g] for g in games]
                scores = np.stack([s[:n] for s in per_game], axis=1)  # (runs, games)
                low = np.array([r["random"] for r in ref])
                high = np.array([r["human"] for r in ref])
                out[name] = (scores - low) / (high - low)
    return out


@contextlib.contextmanager
def seeded_bootstrap(seed: int = 0) -> Iterator[None]:
    """rliable's bootstraps draw from NumPy's global generator: seeded within, so that the same
    records render the same intervals, and restored after, so nothing else sees the seed."""
    state = np.random.get_state()
    np.random.seed(seed)
    try:
        yield
    finally:
        np.random.set_state(state)


def iqm_table(scores: dict[str, np.ndarray], reps: int = 2000) -> str:
    """Markdown: interquartile mean per input with its 95 % stratified-bootstrap interval."""
    from rliable import library as rly
    from rliable import metrics

    if not scores:
        return ""
    with seeded_bootstrap():
        points, intervals = rly.get_interval_estimates(
            scores, lambda x: np.array([metrics.aggregate_iqm(x)]), reps=reps
        )
    lines = [
        "Beyond the paper: interquartile mean of human-normalised average scores over the games "
        "every input of a budget ran (Games), 95 % stratified-bootstrap interval (rliable, "
        f"{reps} resamples):",
        "",
        "| Input | Games | Runs a game | IQM | 95 % interval |",
        "|---|---:|---:|---:|---|",
    ]
    for name, runs in scores.items():  # runs: (runs, games)
        low, high = intervals[name][:, 0]
        lines.append(
            f"| {name} | {runs.shape[1]} | {runs.shape[0]} | {points[name][0]:.3f} | "
            f"[{low:.3f}, {high:.3f}] |"
        )
    return "\n".join(lines)


def _budget_note(done: pd.DataFrame) -> str:
    """How the rows of several budgets relate, and which runs continue a run of another config
    (an attempt of theirs ran under another fingerprint: Table 1's screening, whose settings
    were chosen on those runs)."""
    said = (
        "Budgets: a lane (sweeps/table1_lane.sh) trains each run once to its budget, and the "
        "steps-to rows read its one curve at every score. Rows of two budgets of one game are "
        "separate runs per seed: started alike (same seed), they repeat each other for the "
        "first 1.5-2.6M env steps, then part; they are not independent samples, and the "
        "longer is not a continuation of the shorter."
    )
    continued = sorted(
        f"{g} {INPUT_NAMES.get(i, i)} seed {int(seed)} at {b}"
        for g, i, b, seed, record, fingerprint in zip(
            done["game"], done["input"], done["budget"], done["seed"], done["record"],
            done["fingerprint"], strict=True,
        )
        if any(a.get("fingerprint") not in (None, fingerprint) for a in run_attempts(record))
    )  # fmt: skip
    if continued:
        said += (
            " These runs continue a run of another config (the screening that chose the "
            f"settings, on these very runs): {', '.join(continued)}."
        )
    return said


def _evaluation_note(done: pd.DataFrame) -> str:
    """How the rows' games were played: in eval mode (running statistics), or, for records from
    before that fix (no ``eval/network_mode``), in training mode; and the policy."""
    mode = done.reindex(columns=["metrics.eval/network_mode"]).iloc[:, 0]
    old = done[mode.isna()]
    said = (
        "Evaluation: the network in eval mode (batch-normed frames by training's running "
        "statistics), each action sampled from the policy (greedy where a record's "
        "`eval/policy` says so)."
    )
    if old.empty:
        return said
    rows = sorted({f"{g} {INPUT_NAMES.get(i, i)} at {b}"
                   for g, i, b in zip(old["game"], old["input"], old["budget"], strict=True)})  # fmt: skip
    return (
        f"{said} Rows scored before that fix (2026-12-06), in training mode (each batch of games "
        "normalised by its own frames, the running statistics updated as they played), whose "
        f"networks were not kept and cannot be scored again: {', '.join(rows)}."
    )


def _setting_text(value: Any) -> str:
    """A setting's value as the notes write it: ``30M`` for 30,000,000, ``0.02``, ``bfloat16``."""
    if isinstance(value, str | bool) or not np.isscalar(value):
        return str(value)
    return f"{value / 1e6:g}M" if abs(value) >= 1e6 else f"{value:g}"


def _settings_note(done: pd.DataFrame) -> str:
    """The :data:`NAMED_SETTINGS` in which the rows differ, each value with the rows that ran
    it; empty where every row ran the same."""
    said = []
    for column, (name, before) in NAMED_SETTINGS.items():
        given = done.reindex(columns=[column]).iloc[:, 0]
        rows: dict[str, set[str]] = {}
        for value, game, inputs, budget in zip(
            given, done["game"], done["input"], done["budget"], strict=True
        ):
            shown = before if pd.isna(value) else value
            if shown is not None:
                text = _setting_text(shown)
                rows.setdefault(text, set()).add(
                    f"{game} {INPUT_NAMES.get(inputs, inputs)} at {budget}"
                )
        if len(rows) > 1:
            values = "; ".join(f"{v}: {', '.join(sorted(r))}" for v, r in sorted(rows.items()))
            said.append(f"{name} (`{column.split('.', 1)[1]}`) {values}")
    return "Settings that differ between rows: " + ". ".join(said) + "." if said else ""


def table1_atari(runs: pd.DataFrame, published: dict[str, Any]) -> Table:
    done, unplaced = placeable(atari_runs(runs), ["game", "input"])
    grouped = cells(done, [*SCORES.values(), FPS], ["game", "input", "budget"])
    frame, extra = pd.DataFrame(), ""
    if not grouped.empty:
        frame = pd.DataFrame(
            {
                "Game": grouped["game"],
                "Input": [INPUT_NAMES.get(i, i) for i in grouped["input"]],
                "Data": grouped["data.source"],
                "Scale": grouped["scale"],
                **{
                    col: [
                        mean_std(grouped[f"{m}:mean"][i], grouped[f"{m}:std"][i])
                        for i in grouped.index
                    ]
                    for col, m in SCORES.items()
                },
                "Env steps/s": [
                    mean_std(grouped[f"{FPS}:mean"][i], grouped[f"{FPS}:std"][i], fmt=",.0f")
                    for i in grouped.index
                ],
                "Runs": grouped["runs"],
                **{
                    f"Published {col}": [
                        cite(lookup(published, "table1_atari", "games", g, i, col.lower()))
                        for g, i in zip(grouped["game"], grouped["input"], strict=True)
                    ]
                    for col in SCORES
                },
                "Cell": grouped["cell"].str[:8],
            }
        )
        extra = iqm_table(normalised_scores(done, published))
    parts = (extra, steps_to_targets_block(done, published), _gain_block(grouped, published))
    extra = "\n\n".join(part for part in parts if part)
    return Table(
        "table1_atari",
        "Table 1: PAAC on Atari, frames (FDR) vs frames + EDR, ours beside the paper's",
        frame,
        done,
        notes=[
            note
            for note in (
                "Avg / Best / Worst: mean, max and min raw score of the evaluation games of a "
                "run (30 full games at full scale), each then averaged over seeds (± std).",
                _evaluation_note(done),
                _budget_note(done),
                _settings_note(done),
                "Env steps/s: the training loop's throughput (`train/fps`, from the start of a "
                "run's last attempt), on the machine named, with whatever else ran beside it.",
            )
            if note
        ],
        unfinished=unfinished(runs, "atari", unplaced),
        extra=extra,
        paper=_paper_rows(published),
        paper_notes=[
            f"Source: {lookup(published, 'table1_atari', 'source')}; 30 evaluation games per "
            "agent, one agent per game and input (the paper gives no seeds).",
            *(lookup(published, "table1_atari", "notes") or []),
        ],
    )
