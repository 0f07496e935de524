"""Table 1's "Avg. gain" rows judged on the paper's six games: per game the gain of FDR+EDR over
FDR as the paper computes it, its spread over seeds and a paired per-seed comparison (seed s of
one input against seed s of the other), the games still missing, the paper's worst-case claim,
and each game's random play (the suite's own, measured by ``edr-eval --random-play``)."""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from edr.report.atari_curves import millions
from edr.report.published import cite, lookup
from edr.report.runs import run_json

COLUMNS = {"avg": "metrics.eval/mean", "best": "metrics.eval/max", "worst": "metrics.eval/min"}
# The folder, beside the sweeps' folders (results/learning/), of random-play records for games
# whose runs hold none: one JSON per run of `edr-eval RUN --random-play` (its random/ metrics).
RANDOM_PLAY = "table1_random_play"
# Records of a run scored again with --random-play (edr-eval writes them beside the run:
# network_eval.json before 2026-12-07, network_eval_seed<S>_plays<N>.json since).
NETWORK_EVAL = "network_eval*.json"


def gain(fdr: float, fdr_edr: float) -> float | None:
    """The paper's gain of FDR+EDR over FDR in %: (EDR - FDR) / |FDR|; None where FDR is 0."""
    return 100 * (fdr_edr - fdr) / abs(fdr) if fdr else None


def average_gains(games: dict[str, dict[str, dict[str, float]]]) -> dict[str, float | None]:
    """Table 1's "Avg. gain" row: per column (avg, best, worst), the mean over games of FDR+EDR's
    :func:`gain` over FDR, in %. ``games``: game -> input (``fdr``, ``fdr_edr``) -> column ->
    score. On the paper's own rows it gives its +23.8 / +20.9 / +70.2 (tested)."""
    gains: dict[str, float | None] = {}
    for column in ("avg", "best", "worst"):
        changes = [
            g
            for by_input in games.values()
            if {"fdr", "fdr_edr"} <= set(by_input)
            and (g := gain(by_input["fdr"][column], by_input["fdr_edr"][column])) is not None
        ]
        gains[column] = float(np.mean(changes)) if changes else None
    return gains


def paired_seeds(runs: pd.DataFrame, column: str) -> list[tuple[int, float, float]]:
    """(seed, FDR, FDR+EDR) for every seed both inputs ran, of one game and budget."""
    by = {
        i: dict(zip(rows["seed"].astype(int), rows[COLUMNS[column]], strict=True))
        for i, rows in runs.groupby("input")
    }
    fdr, edr = by.get("fdr", {}), by.get("fdr_edr", {})
    return [(s, float(fdr[s]), float(edr[s])) for s in sorted(fdr.keys() & edr.keys())]


def game_gains(runs: pd.DataFrame) -> dict[str, dict[str, Any]]:
    """Per column, one game's gain at one budget: that of the seed means (``gain``, the paper's
    per-game term), the per-seed gains of the seed pairs (``pairs``: seed s vs seed s) and how
    many pairs FDR+EDR leads (``ahead``), ties count as not ahead."""
    out = {}
    for column, metric in COLUMNS.items():
        means = runs.groupby("input")[metric].mean()
        pairs = paired_seeds(runs, column)
        out[column] = {
            "gain": gain(means["fdr"], means["fdr_edr"]) if {"fdr", "fdr_edr"} <= set(means.index)
            else None,
            "pairs": [(s, gain(f, e)) for s, f, e in pairs],
            "ahead": sum(e > f for _, f, e in pairs),
            "behind": sum(e < f for _, f, e in pairs),
        }  # fmt: skip
    return out


def worst_case_verdict(
    per_game: dict[str, dict[str, dict[str, Any]]], missing: list[str], average: float | None
) -> str:
    """The paper's "worst case performance for EDR + FDR is much better than that of FDR alone"
    at one budget: undecided while any of its games is missing; else supported where the mean
    Worst gain is positive and no game's Worst trails in every seed pair, contradicted where the
    mean is not positive or more games trail than lead in every pair, mixed otherwise."""
    lead = sorted(g for g, c in per_game.items() if _every_pair(c["worst"], "ahead"))
    trail = sorted(g for g, c in per_game.items() if _every_pair(c["worst"], "behind"))
    tally = (
        f"FDR+EDR's Worst ahead in every seed pair in {_names(lead)}, behind in every pair in "
        f"{_names(trail)}, mean Worst gain {cite(average, '+.1f')} %"
    )
    if missing:
        return f"undecided ({', '.join(missing)} missing); so far: {tally}"
    if average is None or average <= 0 or len(trail) > len(lead):
        return f"contradicted: {tally}"
    if not trail:
        return f"supported: {tally}"
    return f"mixed: {tally}"


def _every_pair(column: dict[str, Any], side: str) -> bool:
    return bool(column["pairs"]) and column[side] == len(column["pairs"])


def _names(games: list[str]) -> str:
    return ", ".join(games) if games else "no game"


def random_play(done: pd.DataFrame) -> dict[str, list[float]]:
    """Per game, the suite's random play: the ``random/mean`` (30 games each) of every run
    scored again with ``edr-eval --random-play`` (its ``network_eval.json``); for a game with no
    such run, that of the records in :data:`RANDOM_PLAY` beside the runs' sweep folders."""
    from_runs: dict[str, list[float]] = {}
    for game, record in zip(done["game"], done["record"], strict=True):
        folder = Path(record).parent
        for name in sorted(p.name for p in folder.glob(NETWORK_EVAL)):
            scored = run_json(folder, name) or {}
            if "random/mean" in scored:
                from_runs.setdefault(game, []).append(float(scored["random/mean"]))
    stored: dict[str, list[float]] = {}
    for folder in sorted({Path(r).parents[2] / RANDOM_PLAY for r in done["record"]}):
        for game, mean in _random_play_records(sorted(folder.glob("*.json"))):
            stored.setdefault(game, []).append(mean)
    return {**stored, **from_runs}


def _random_play_records(paths: Iterable[Path]) -> Iterable[tuple[str, float]]:
    for path in paths:
        record = json.loads(path.read_text())
        yield record["game"], float(record["random/mean"])


def _random_cell(means: list[float] | None) -> str:
    if not means:
        return "not measured"
    places = 1 if max(abs(m) for m in means) < 100 else 0  # Breakout's 1.2, Pong's -20.3
    spread = f" ({min(means):,.{places}f} to {max(means):,.{places}f})" if len(means) > 1 else ""
    return f"{np.mean(means):,.{places}f}{spread}, {len(means)} x 30 games"


def _pairs_cell(column: dict[str, Any]) -> str:
    """One column's per-seed gains, e.g. ``+12 % (-3 to +30), 2 of 3 ahead``."""
    gains = [g for _, g in column["pairs"] if g is not None]
    if not column["pairs"]:
        return "no seed pair"
    spread = f" ({min(gains):+.0f} to {max(gains):+.0f})" if len(gains) > 1 else ""
    return (
        f"{cite(column['gain'], '+.0f')} %{spread}, "
        f"{column['ahead']} of {len(column['pairs'])} ahead"
    )


def gains_block(done: pd.DataFrame, published: dict[str, Any]) -> str:
    """Markdown: the paper's Avg. gain rows, ours per budget over the games both inputs ran,
    each game's gain with its seed pairs and random play, and the worst-case claim judged."""
    paper = lookup(published, "table1_atari", "games") or {}
    reference = published.get("atari_reference_scores", {})
    randoms = random_play(done) if not done.empty else {}
    printed = lookup(published, "table1_atari", "avg_gain_percent") or {}
    lines = [
        "Avg. gain of FDR+EDR over FDR, as the paper computes it: per column, the mean over games "
        "of (FDR+EDR - FDR) / |FDR| on the scores of Table 1 (ours: each input's mean over "
        "seeds), %.",
        "",
        "| Avg. gain | Games | Avg | Best | Worst |",
        "|---|---|---:|---:|---:|",
        _gain_row("the paper, as printed", len(paper), len(paper), printed),
        _gain_row(
            "the paper, recomputed from its rows", len(paper), len(paper), average_gains(paper)
        ),
    ]
    budgets = sorted(done["budget"].unique(), key=millions) if not done.empty else []
    per_budget = {}
    for budget in budgets:
        at = done[done["budget"] == budget]
        both = sorted(g for g, r in at.groupby("game") if {"fdr", "fdr_edr"} <= set(r["input"]))
        per_game = {g: game_gains(at[at["game"] == g]) for g in both}
        mean = {c: _mean([per_game[g][c]["gain"] for g in both]) for c in COLUMNS}
        missing = [g for g in paper if g not in both]
        per_budget[budget] = (per_game, mean, missing)
        lines.append(_gain_row(f"ours at {budget} env steps", len(both), len(paper), mean, missing))
    for budget, (per_game, mean, missing) in per_budget.items():
        lines += [
            "",
            f"At {budget} env steps, per game: the gain of the seed means (the paper's term), "
            "the seed pairs' gains (seed s of FDR+EDR against seed s of FDR, min to max) and "
            "in how many pairs FDR+EDR scores higher; the suite's random play (edr-eval "
            "--random-play, mean over runs of 30 games each, min-max) and Mnih et al.'s "
            "random / human (the paper gives none):",
            "",
            "| Game | Avg gain | Best gain | Worst gain | Random play (ours) | Random / human "
            "(Mnih et al.) | Paper's gains (Avg / Best / Worst) |",
            "|---|---|---|---|---|---|---|",
        ]
        for game in [*paper, *sorted(set(per_game) - set(paper))]:
            cells = (
                [_pairs_cell(per_game[game][c]) for c in COLUMNS]
                if game in per_game
                else [_missing(done, budget, game)] * 3
            )
            ref = reference.get(game, {})
            lines.append(
                f"| {game} | {' | '.join(cells)} | {_random_cell(randoms.get(game))} | "
                f"{cite(ref.get('random'))} / {cite(ref.get('human'))} | "
                f"{_paper_gains(paper.get(game, {}))} |"
            )
        verdict = worst_case_verdict(per_game, missing, mean["worst"])
        lines += ["", f'At {budget} env steps: the paper\'s "much better worst case": {verdict}.']
    return "\n".join(lines)


def _paper_gains(theirs: dict[str, dict[str, float]]) -> str:
    """The paper's own gains of one game, Avg / Best / Worst; ``-`` where it gives no pair."""
    if not {"fdr", "fdr_edr"} <= set(theirs):
        return "-"
    return (
        " / ".join(cite(gain(theirs["fdr"][c], theirs["fdr_edr"][c]), "+.0f") for c in COLUMNS)
        + " %"
    )


def _missing(done: pd.DataFrame, budget: str, game: str) -> str:
    """Why a game has no gain at ``budget``: no run, or one input only."""
    ran = sorted(set(done.loc[(done["game"] == game) & (done["budget"] == budget), "input"]))
    return f"missing (only {', '.join(ran)})" if ran else "missing (no run)"


def _mean(values: list[float | None]) -> float | None:
    kept = [v for v in values if v is not None]
    return float(np.mean(kept)) if kept else None


def _gain_row(
    label: str,
    games: int,
    of: int,
    gains: dict[str, float | None],
    missing: list[str] | None = None,
) -> str:
    named = f"{games} of {of}" + (f" ({', '.join(missing)} missing)" if missing else "")
    cells = " | ".join(cite(gains.get(c), "+.1f") for c in COLUMNS)
    return f"| {label} | {named} | {cells} |"
