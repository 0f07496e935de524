"""The screenings' reports, written by ``python -m edr.report.screening DIR`` to
``DIR/screening.md`` from the records under DIR.

Table 1's screening (``experiment=table1_screen``): which network and optimizer leave random
play in Pong fastest, judged by learning: the training score over env steps, the env steps to
reach -15 and 0, and, as diagnostics, the policy's entropy, the logits' spread across states and
conv1's dead units. One row per run.

The own-game screening (``experiment=own_game_screen``): which candidate defaults for a user's
own game (``task.env.preset=none``) learn the suite's four games (``edr.rl.games``) best, judged
by the worst game: each run's evaluation mean normalised by the game's random and expert scores,
(score - random) / (expert - random), so 0 is random play and 1 the scripted expert; per
candidate and input, each game's mean and min over seeds, and candidates ranked by the worst
game's mean, then the worst game's min.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from edr.report.atari_curves import first_reaching, score_at
from edr.report.runs import load_runs, run_history
from edr.rl.games.scores import load_scores
from edr.store.atomic import write_text_atomic
from edr.store.checkpoints import CHECKPOINT, load_checkpoint
from edr.store.identity import ADDED_DEFAULTS

MILESTONES = (250_000, 500_000, 1_000_000, 1_500_000)  # env steps at which the score is shown
TARGETS = (-15.0, 0.0)  # training scores whose first env step is shown
RANDOM_PLAY = -20.7  # Pong's random play (the paper's reference scores)


def _precision(run: pd.Series) -> str:
    """The precision a run trained in; a record from before the setting: float32."""
    for key in ("metrics.train/precision", "config.task.network.precision"):
        if pd.notna(run.get(key)):
            return str(run[key])
    return ADDED_DEFAULTS["edr.rl.settings.NetworkSettings"]["precision"]


def _steps(steps: int | None) -> str:
    return f"{steps / 1e6:.2f}M" if steps is not None else "—"


def _last(history: list[dict], key: str) -> float:
    values = [r[key] for r in history if key in r]
    return float(np.mean(values[-5:])) if values else np.nan  # the last 5 rows (50 updates)


def _history(record: str) -> list[dict]:
    """A run's history: its history.json once finished, else its checkpoint's (in progress)."""
    checkpoint = Path(record).parent / CHECKPOINT
    if history := run_history(record):
        return history
    return load_checkpoint(checkpoint)["history"] if checkpoint.is_file() else []


def _own_game(runs: pd.DataFrame, yardsticks: dict[str, dict[str, float]]) -> pd.Series:
    """Which of ``runs`` play one of the screening games (by their env id)."""
    if "config.task.env.env_id" not in runs:
        return pd.Series(False, index=runs.index)
    return (runs["task"] == "atari") & runs["config.task.env.env_id"].isin(list(yardsticks))


def screening_rows(runs: pd.DataFrame) -> pd.DataFrame:
    """One row per Atari run of ``runs`` but the own-game screening's (finished or not: a run in
    progress shows how far it got)."""
    rows = []
    atari = (runs["task"] == "atari") & ~_own_game(runs, load_scores())
    for _, run in runs[atari].iterrows():
        history = _history(run["record"])
        if not history:
            continue
        get = run.get
        optimizer = get("config.task.optim.name")
        lr = get("config.task.optim.lr")
        rows.append({
            "Network": get("config.task.network.core"),
            "Input norm": get("config.task.network.input_norm", "raw") or "raw",
            "Init": get("config.task.network.init"),
            "Optimizer": f"{optimizer} {lr:g}" if pd.notna(lr) and lr else f"{optimizer} (default lr)",
            "Entropy weight": get("config.task.loss.entropy_coeff"),
            "Critic weight": get("config.task.loss.critic_coeff"),
            "Precision": _precision(run),
            "Input": get("config.task.env.inputs"),
            "Seed": get("seed"),
            "Status": get("status"),
            "Env steps": f"{history[-1]['env_steps'] / 1e6:.2f}M",
            **{f"Score @{m / 1e6:g}M": score_at(history, m) for m in MILESTONES},
            **{f"Steps to {t:g}": _steps(first_reaching(history, t)) for t in TARGETS},
            "Entropy": _last(history, "train/entropy"),
            "Logit spread": _last(history, "train/logit_spread"),
            "conv1 dead": _last(history, "dead/trunk.1"),
            "Env steps/s": _last(history, "train/fps"),
            "Eval mean": get("metrics.eval/mean"),
        })  # fmt: skip
    return pd.DataFrame(rows)


def screening_markdown(runs: pd.DataFrame, source: Path) -> str:
    frame = screening_rows(runs)
    if frame.empty:
        return f"No Atari runs with a history under {source}.\n"
    frame = frame.sort_values(["Input", "Network", "Optimizer", "Seed"])
    text = frame.to_markdown(index=False, floatfmt=".2f", missingval="—")
    return "\n".join([
        f"# Table 1's screening: Pong, {len(frame)} runs under `{source}`",
        "",
        "Training score: the mean of the last 20 training episodes (random play "
        f"{RANDOM_PLAY}). Entropy (ln 6 = 1.79 is a uniform policy), logit spread (the "
        "logits' std across a rollout's states, averaged over actions; near 0 when the policy "
        "ignores the frames), conv1 dead and env steps/s: means of the last 50 updates (env "
        "steps/s depends on what else ran on the machine meanwhile). A run still in progress "
        "shows how far it got (Status). Machine: see each run.json.",
        "",
        text,
        "",
    ])  # fmt: skip


def own_game_rows(
    runs: pd.DataFrame, yardsticks: dict[str, dict[str, float]] | None = None
) -> pd.DataFrame:
    """One row per finished run of ``runs`` on a screening game (``yardsticks``: env id ->
    random and expert score, ``scores.yaml``'s by default): its candidate (the
    ``own_game_candidate`` choice), game, input, seed, evaluation mean and that mean normalised,
    (score - random) / (expert - random); a run that diverged (no evaluation) scores as random
    play, so that a failed seed counts against its candidate rather than dropping out."""
    yardsticks = yardsticks or load_scores()
    done = runs[_own_game(runs, yardsticks) & (runs["status"] == "finished")]
    rows = []
    for _, run in done.iterrows():
        game = yardsticks[run["config.task.env.env_id"]]
        score = float(run["metrics.eval/mean"])
        if np.isnan(score):  # a run that diverged played no game: no better than random play
            score = game["random"]
        candidate = run.get("choices.own_game_candidate")
        rows.append({
            "candidate": candidate if isinstance(candidate, str) else "—",
            "game": run["config.task.env.env_id"],
            "input": run["config.task.env.inputs"],
            "seed": run["seed"],
            "score": score,
            "normalised": (score - game["random"]) / (game["expert"] - game["random"]),
        })  # fmt: skip
    columns = ["candidate", "game", "input", "seed", "score", "normalised"]
    return pd.DataFrame(rows, columns=columns)


def candidate_ranking(rows: pd.DataFrame, games: list[str], min_seeds: int = 3) -> pd.DataFrame:
    """Per input and candidate of ``rows`` (:func:`own_game_rows`): each game's normalised score,
    mean and min over seeds; the worst game's mean (``worst mean``) and the lowest of the games'
    mins (``worst min``); ranked within each input by the worst mean, then the worst min. A
    candidate with a game of ``games`` missing, or one with fewer than ``min_seeds`` seeds, is
    ``complete`` False and ranked after every complete one."""
    out = []
    for (inputs, candidate), runs in rows.groupby(["input", "candidate"]):
        per_game = runs.groupby("game")["normalised"].agg(["mean", "min", "count"])
        per_game = per_game.reindex(games)
        row = {"input": inputs, "candidate": candidate}
        for game, stats in per_game.iterrows():
            row[f"{game} mean"], row[f"{game} min"] = stats["mean"], stats["min"]
        complete = bool(per_game["count"].ge(min_seeds).all())
        row.update({"worst mean": per_game["mean"].min(skipna=False),
                    "worst min": per_game["min"].min(skipna=False),
                    "runs": len(runs), "complete": complete})  # fmt: skip
        out.append(row)
    frame = pd.DataFrame(out)
    if frame.empty:
        return frame
    frame = frame.sort_values(
        ["input", "complete", "worst mean", "worst min"], ascending=[True, False, False, False],
        na_position="last", kind="stable",
    )  # fmt: skip
    frame.insert(2, "rank", frame.groupby("input").cumcount() + 1)
    return frame.reset_index(drop=True)


def _two(value: float) -> str:
    return "—" if np.isnan(value) else f"{value:.2f}"


def own_game_markdown(runs: pd.DataFrame, source: Path) -> str:
    """The own-game screening's report: the yardsticks, the ranking for each input, the winner
    of each, and every run's score."""
    yardsticks = load_scores()
    rows = own_game_rows(runs, yardsticks)
    if rows.empty:
        return f"No finished own-game screening runs under {source}.\n"
    ranking = candidate_ranking(rows, list(yardsticks))
    lines = [
        f"# Defaults for your own game: the screening, {len(rows)} runs under `{source}`",
        "",
        "Each run's score is its evaluation mean (30 games), normalised by the game's random "
        "and expert scores (`src/edr/rl/games/scores.yaml`): (score - random) / (expert - "
        "random), so 0 is random play, 1 the scripted expert. Per candidate and game, the mean "
        "and the min over seeds; candidates ranked within each input by the worst game's mean "
        "(`worst mean`), then the lowest min (`worst min`): a default must learn every game on "
        "every seed. `complete`: every game with at least 3 seeds.",
        "",
        "| Game | Random | Expert |",
        "|---|---:|---:|",
        *(f"| {g} | {s['random']:g} | {s['expert']:g} |" for g, s in yardsticks.items()),
    ]
    for inputs, ranked in ranking.groupby("input", sort=True):
        best = ranked.iloc[0]
        shown = ranked.drop(columns="input").astype(object).where(ranked.notna(), None)
        lines += [
            "",
            f"## Input {inputs}: {best['candidate']} first (worst game's mean "
            f"{_two(best['worst mean'])}, min {_two(best['worst min'])}"
            f"{'' if best['complete'] else '; incomplete'})",
            "",
            shown.to_markdown(index=False, floatfmt=".2f", missingval="—"),
        ]
    runs_table = rows.sort_values(["input", "candidate", "game", "seed"])
    lines += ["", "## Every run", "", runs_table.to_markdown(index=False, floatfmt=".2f"), ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m edr.report.screening", description=__doc__)
    parser.add_argument("folder", type=Path, help="the screening's sweep folder")
    args = parser.parse_args(argv)
    out = args.folder / "screening.md"
    runs = load_runs([args.folder])
    own = _own_game(runs, load_scores())
    parts = [own_game_markdown(runs, args.folder)] if own.any() else []
    if (~own & (runs["task"] == "atari")).any() or not parts:
        parts.append(screening_markdown(runs[~own], args.folder))
    write_text_atomic(out, "\n".join(parts))
    print(out.read_text())


if __name__ == "__main__":
    main()
