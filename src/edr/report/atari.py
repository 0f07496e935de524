"""Table 1: PAAC on Atari, FDR vs FDR+EDR — Avg / Best / Worst of the evaluation games, the
paper's average gain, and (beyond the paper) the interquartile mean of human-normalised scores
with stratified-bootstrap 95 % intervals (rliable)."""

from __future__ import annotations

import contextlib
import itertools
from collections.abc import Iterator
from typing import Any

import numpy as np
import pandas as pd

from edr.report.atari_curves import INPUT_NAMES, millions, shared_prefix, steps_to_targets_block
from edr.report.atari_gains import gains_block
from edr.report.published import cite, lookup
from edr.report.render import Table, mean_std
from edr.report.runs import cells, finished, placeable, run_attempts, run_history, unfinished
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
    trained on fewer env steps than the paper's says so in its ``scale``, which names Table 1's
    pinned settings (they are not the paper's)."""
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
        f"pinned settings (not the paper's), {steps / 1e6:g}M of its {full / 1e6:g}M env steps"
        for steps, full in zip(budget[cut], paper[cut], strict=True)
    ]
    return done


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
    games) human-normalised average scores — the games every label of its budget ran with the
    most seeds (a game still short of them waits: one seed does not pull the others down to
    one), the first n seeds where each game has at least n runs."""
    reference = published.get("atari_reference_scores", {})
    out = {}
    for _, at_budget in done.groupby("budget"):
        labels = at_budget.groupby("label")
        shared = sorted(set.intersection(*(set(g["game"]) for _, g in labels)) & reference.keys())
        seeds = {g: min(int((r["game"] == g).sum()) for _, r in labels) for g in shared}
        games = [g for g in shared if seeds[g] == max(seeds.values())]
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
        "every input of a budget ran with the most seeds (Games), 95 % stratified-bootstrap "
        "interval (rliable, "
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


# The settings every Table 1 row pins, as the notes name them, beside Appendix C's (the paper's
# PAAC: an FT-LSTM core under RMSprop at 0.0224; it names no input normalisation nor precision).
PINNED = {
    "config.task.network.core": ("core", "ftlstm (feature-tracking LSTM)"),
    "config.task.optim.name": ("optimizer", "RMSprop"),
    "config.task.optim.lr": ("learning rate", "0.0224"),
    "config.task.network.input_norm": ("input normalisation", "none stated"),
    "metrics.train/precision": ("precision", "not stated"),
}
DEFAULT_LR = {"adam": 7e-4, "rmsprop_tf": 0.0224}  # lr: null takes the optimizer's (atari.yaml)


def _pinned_note(done: pd.DataFrame) -> str:
    """What every row ran with where Appendix C says otherwise: the core, the optimizer and its
    learning rate, the input normalisation and the precision (chosen on Pong in Table 1's
    screening, results/learning/README.md)."""
    said = []
    for column, (name, paper) in PINNED.items():
        given = done.reindex(columns=[column]).iloc[:, 0]
        if column == "config.task.optim.lr":
            given = given.fillna(done.reindex(columns=["config.task.optim.name"]).iloc[:, 0]
                                 .map(DEFAULT_LR))  # fmt: skip
        if column == "metrics.train/precision":  # records from before the setting: float32
            given = given.fillna(NAMED_SETTINGS[column][1])
        values = sorted({_setting_text(v) for v in given.dropna()})
        said.append(f"{name} {' / '.join(values) or '?'} (Appendix C: {paper})")
    return (
        "Settings: Table 1's pinned experiment (conf/experiment/table1_atari.yaml), chosen on "
        "Pong in its screening, not the paper's: " + "; ".join(said) + ". The network is "
        "PAAC's feed-forward one (conv 16 8x8/4, conv 32 4x4/2, FC 256) on batch-normed frames; "
        "32 envs, 5-step rollouts, entropy 0.02, clip 3.0 and the linear decay are Appendix C's."
    )


def _budget_note(done: pd.DataFrame) -> str:
    """How the rows of several budgets relate: per pair of runs of one game, input and seed at
    two budgets, the env steps their histories share (identical rows) before they part."""
    shared = []
    for (game, inputs, seed), runs in done.groupby(["game", "input", "seed"]):
        if runs["budget"].nunique() < 2:
            continue
        ordered = runs.sort_values("budget", key=lambda b: b.map(millions))
        histories = [run_history(r) for r in ordered["record"]]
        for (b1, h1), (b2, h2) in itertools.combinations(
            zip(ordered["budget"], histories, strict=True), 2
        ):
            steps = shared_prefix(h1, h2)
            shared.append(f"{game} {INPUT_NAMES.get(inputs, inputs)} seed {int(seed)} {b1} and "
                          f"{b2}: {steps:,}")  # fmt: skip
    if not shared:
        return ""
    return (
        "Budgets: rows of two budgets of one game are separate runs per seed, started alike "
        "(same seed); each pair's histories are identical up to (env steps): "
        f"{'; '.join(shared)}; then they part. They are not independent samples, and the longer "
        "is not a continuation of the shorter."
    )


def _attempts_note(done: pd.DataFrame) -> str:
    """The runs trained in more than one attempt (``attempts.jsonl``): when each stopped and
    continued from its checkpoint, and the commit each attempt ran (the finishing attempt's from
    its record where the attempt line names none), with those that continue a run of another
    config (Table 1's screening, whose settings were chosen on those very runs)."""
    said, screened = [], []
    for g, i, b, seed, record, fingerprint, git in zip(
        done["game"], done["input"], done["budget"], done["seed"], done["record"],
        done["fingerprint"], done["git"], strict=True,
    ):  # fmt: skip
        attempts = [a for a in run_attempts(record) if a.get("outcome") != "skipped"]
        name = f"{g} {INPUT_NAMES.get(i, i)} seed {int(seed)} at {b}"
        if any(a.get("fingerprint") not in (None, fingerprint) for a in attempts):
            screened.append(name)
        if len(attempts) > 1:
            steps = [
                f"{a.get('outcome')} {str(a.get('at', '?'))[:16].replace('T', ' ')}"
                + (f" ({str(a['git'])[:7]})" if a.get("git") else "")
                for a in attempts
            ]
            said.append(f"{name}: {', '.join(steps)}, finished on {str(git)[:7]}")
    if not said:
        return ""
    text = (
        "Continued runs: a lane (sweeps/table1_lane.sh) continues a stopped run from its "
        "checkpoint, on whatever commit it then runs; each attempt's end (UTC) and commit "
        "(attempts.jsonl; lines from before attempts named theirs give only the finishing "
        f"commit, from run.json): {'; '.join(sorted(said))}."
    )
    if screened:
        text += (
            " These continue a run of another config (the screening that chose the settings, "
            f"on these very runs): {', '.join(sorted(screened))}."
        )
    return text


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
    parts = (extra, steps_to_targets_block(done, published), gains_block(done, published))
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
                _pinned_note(done),
                _evaluation_note(done),
                _budget_note(done),
                _attempts_note(done),
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
