"""Table 1's readings of the training curves (each run's ``history.json``): the env steps each
run took to reach a score, Figure 5a's "1.7x faster" on Pong, and Figure 5b's "1.8x higher
reward" on Centipede at equal env steps, each judged with the runs' spread."""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from edr.report.published import lookup
from edr.report.runs import run_history

# A record's task.env.inputs as Table 1 names it (events alone, "edr", is beyond the paper).
INPUT_NAMES = {"fdr": "FDR", "fdr_edr": "FDR+EDR", "edr": "EDR"}
# Scores whose first crossing in training Table 1 reports per run, per game. Pong: Figure 5a's
# 18 the last (the paper's env steps to it: published.yaml's figure5_atari.pong_env_steps_to_18);
# Centipede: above random play's reach (about 2,000 a game; a mean of 20 early games reaches
# 3,500 by chance, seen at 0.11M env steps) up to Figure 5b's 8,300 (FDR+EDR's best);
# Breakout: random play is 1.7, the paper's FDR at 80M 422.5.
TARGET_SCORES = {
    "Pong": (-10.0, 0.0, 10.0, 18.0),
    "Centipede": (4000.0, 5000.0, 6500.0, 8300.0),
    "Breakout": (10.0, 50.0, 100.0, 400.0),
}
# Games whose curves of both inputs are compared at equal env steps (Figure 5b).
EQUAL_STEPS_GAMES = ("Centipede",)
M = 1_000_000


def first_reaching(history: list[dict[str, Any]], target: float) -> int | None:
    """The env steps of the first ``history`` row whose training score (the mean of the last 20
    episodes, ``train/score``) is at least ``target``; None if none is."""
    return next(
        (int(r["env_steps"]) for r in history if (r.get("train/score") or -np.inf) >= target),
        None,
    )


def score_at(history: list[dict[str, Any]], env_steps: int) -> float | None:
    """The training score at ``env_steps``: that of the last ``history`` row at or before them;
    None where the history stops short of them or holds no score there."""
    if not history or history[-1]["env_steps"] < env_steps:
        return None
    scores = [
        r["train/score"]
        for r in history
        if r["env_steps"] <= env_steps and r.get("train/score") is not None
    ]
    return float(scores[-1]) if scores else None


def shared_prefix(first: list[dict[str, Any]], second: list[dict[str, Any]]) -> int:
    """The env steps up to which two runs' histories are identical (every value of each row but
    its timings, ``time/`` and ``train/fps``): where two runs started alike part; 0 where their
    first rows differ."""

    def kept(row: dict[str, Any]) -> dict[str, Any]:
        return {k: v for k, v in row.items() if not k.startswith(("time/", "train/fps"))}

    shared = 0
    for a, b in zip(first, second, strict=False):
        if kept(a) != kept(b):
            break
        shared = int(a["env_steps"])
    return shared


def _reached(steps: list[int | None]) -> str:
    """One cell: how many runs reached a score, and their env steps (mean ± std, min - max)."""
    got = [s / M for s in steps if s is not None]
    head = f"{len(got)} of {len(steps)}"
    if not got:
        return head
    spread = f" ± {np.std(got, ddof=1):.2f}" if len(got) > 1 else ""
    return f"{head}: {np.mean(got):.2f}M{spread} ({min(got):.2f} - {max(got):.2f})"


def millions(budget: str) -> float:
    """``"5M"`` -> 5.0, for ordering budgets; an unknown one (``"?"``) last."""
    return float(budget.removesuffix("M")) if budget != "?" else float("inf")


def _by_budget(done: pd.DataFrame, game: str) -> dict[str, dict[str, list[str]]]:
    """budget -> input -> the histories of ``game``'s finished runs (each read once, in the
    order of their records), budgets from the smallest."""
    rows = done[done["game"] == game]
    out: dict[str, dict[str, list[list[dict[str, Any]]]]] = {}
    for budget in sorted(rows["budget"].unique(), key=millions):
        at = rows[rows["budget"] == budget]
        out[budget] = {
            i: [run_history(r) for r in sorted(g["record"])] for i, g in at.groupby("input")
        }
    return out


def steps_to_targets_block(done: pd.DataFrame, published: dict[str, Any]) -> str:
    """Markdown: per game with targets and input, the env steps its runs took to reach each
    score in training (a table per game), then the sentences on Figure 5a and 5b."""
    paper = lookup(published, "figure5_atari") or {}
    blocks = []
    for game, targets in TARGET_SCORES.items():
        by_budget = _by_budget(done, game)
        if not by_budget:
            continue
        lines = [
            f"| Game | Input | Budget | {' | '.join(f'{t:g}' for t in targets)} |",
            "|---|---|---|" + "---|" * len(targets),
        ]
        steps: dict[tuple[str, str], dict[float, list[int | None]]] = {}
        for budget, by_input in by_budget.items():
            for inputs, histories in by_input.items():
                steps[budget, inputs] = {t: [first_reaching(h, t) for h in histories]
                                         for t in targets}  # fmt: skip
                cells_ = " | ".join(_reached(s) for s in steps[budget, inputs].values())
                lines.append(
                    f"| {game} | {INPUT_NAMES.get(inputs, inputs)} | {budget} | {cells_} |"
                )
        for budget, by_input in by_budget.items():
            if not {"fdr", "fdr_edr"} <= by_input.keys():
                continue
            if game == "Pong":
                said = faster_verdict(steps[budget, "fdr"], steps[budget, "fdr_edr"],
                                      paper.get("pong_env_steps_to_18") or {})  # fmt: skip
                lines += ["", f"At {budget} env steps: {said}"]
            if game in EQUAL_STEPS_GAMES:
                random_play = lookup(published, "atari_reference_scores", game, "random")
                lines += ["", equal_steps_block(game, budget, by_input,
                                                paper.get("centipede_reward_ratio"),
                                                random_play)]  # fmt: skip
        blocks.append("\n".join(lines))
    if not blocks:
        return ""
    head = (
        "Env steps to a training score (the mean of the last 20 episodes) per run: how many "
        "runs reached it within their budget, and when (mean ± std over those runs, min - max):"
    )
    return "\n\n".join([head, *blocks])


def faster_verdict(
    fdr: dict[float, list[int | None]],
    fdr_edr: dict[float, list[int | None]],
    paper: dict[str, float],
) -> str:
    """One sentence on Figure 5a's "1.7x faster" (``paper``: input -> the env steps after which
    its Pong score reached 18, published.yaml's: FDR+EDR 3M, FDR 5M): judged at the highest
    score every run of both inputs reached, supported when every FDR+EDR run got there before
    every FDR run, contradicted when none did, undecided otherwise."""
    claim = "Figure 5a's claim (FDR+EDR reaches Pong's score 18 sooner than FDR)"
    if paper.get("fdr") and paper.get("fdr_edr"):
        claim = (
            f"Figure 5a's \"{paper['fdr'] / paper['fdr_edr']:.1f}x faster\" (Pong's score 18 at "
            f"{paper['fdr_edr'] / M:g}M env steps with FDR+EDR, {paper['fdr'] / M:g}M with FDR)"
        )
    common = [t for t in fdr if all(s is not None for s in (*fdr[t], *fdr_edr[t]))]
    if not common or min(len(fdr[common[-1]]), len(fdr_edr[common[-1]])) < 2:
        return f"{claim}: undecided: no score that at least 2 runs of each input all reached."
    target = common[-1]
    ours, theirs = [s / M for s in fdr_edr[target]], [s / M for s in fdr[target]]
    ratio = np.mean(theirs) / np.mean(ours)
    if max(ours) < min(theirs):
        verdict = "supported"
    elif min(ours) >= max(theirs):
        verdict = "contradicted"
    else:
        verdict = "undecided at this spread (the runs' ranges overlap)"
    at = "" if target == 18 else f" (judged at {target:g}, the highest score every run reached)"
    return (
        f"{claim}: {verdict}{at}: FDR+EDR took {min(ours):.2f} - {max(ours):.2f}M env steps "
        f"({len(ours)} runs), FDR {min(theirs):.2f} - {max(theirs):.2f}M ({len(theirs)} runs), "
        f"{ratio:.1f}x by the means."
    )


def equal_steps_block(
    game: str,
    budget: str,
    histories: dict[str, list[list[dict[str, Any]]]],
    paper_ratio: float | None,
    random_play: float | None = None,
) -> str:
    """Markdown: ``game``'s training score of each input at equal env steps (every million up to
    the most that every run reached: mean ± std over runs, and FDR+EDR's over FDR's by the
    means), then the sentence on Figure 5b's "1.8x higher reward" at the last of them (with
    ``random_play``, the game's random-play score, where no run beats it)."""
    histories = {i: histories[i] for i in ("fdr", "fdr_edr")}  # (runs of each input)
    reached = min(h[-1]["env_steps"] if h else 0 for hs in histories.values() for h in hs)
    points = [*range(M, reached, M), reached] if reached else []
    lines = [
        f"{game} at {budget} env steps, the training score at equal env steps (mean ± std over "
        "runs; the ratio is FDR+EDR's mean over FDR's):",
        "",
        "| Env steps | FDR | FDR+EDR | Ratio |",
        "|---|---|---|---:|",
    ]
    at_points = {
        i: [[s for h in hs if (s := score_at(h, at)) is not None] for at in points]
        for i, hs in histories.items()
    }
    for at, a, b in zip(points, at_points["fdr"], at_points["fdr_edr"], strict=True):
        ratio = f"{np.mean(b) / np.mean(a):.2f}x" if a and b and np.mean(a) > 0 else "—"
        lines.append(f"| {at / M:.2f}M | {_spread(a)} | {_spread(b)} | {ratio} |")
    last = {i: scores[-1] if scores else [] for i, scores in at_points.items()}
    said = ratio_verdict(last["fdr"], last["fdr_edr"], paper_ratio, points[-1] if points else 0,
                         random_play)  # fmt: skip
    return "\n".join([*lines, "", said])


def _spread(scores: list[float]) -> str:
    if not scores:
        return "—"
    std = f" ± {np.std(scores, ddof=1):,.0f}" if len(scores) > 1 else ""
    return f"{np.mean(scores):,.0f}{std} ({len(scores)})"


def ratio_verdict(
    fdr: list[float], fdr_edr: list[float], paper_ratio: float | None, env_steps: int,
    random_play: float | None = None,
) -> str:  # fmt: skip
    """One sentence on Figure 5b's "FDR+EDR reaches 1.8x higher reward than FDR" (``paper_ratio``)
    from each run's training score at the same ``env_steps``: supported when every FDR+EDR run
    scored at least that many times every FDR run, contradicted when none did (the highest
    FDR+EDR score below that many times the lowest FDR one), undecided otherwise; no evidence
    either way where no run of either input scores above ``random_play`` (two policies that play
    the game worse than chance), the reading by the numbers alone said beside."""
    target = paper_ratio or 1.8
    claim = f'Figure 5b\'s "{target:g}x higher reward" (Centipede, FDR+EDR over FDR)'
    where = f"at {env_steps / M:.2f}M env steps (the most every run reached)"
    if min(len(fdr), len(fdr_edr)) < 2:
        return f"{claim}: undecided {where}: fewer than 2 runs of each input."
    if min(fdr) <= 0:
        return f"{claim}: undecided {where}: an FDR score at or below 0 has no ratio."
    low, high = min(fdr_edr) / max(fdr), max(fdr_edr) / min(fdr)
    if low >= target:
        verdict = "supported"
    elif high < target:
        verdict = "contradicted"
    else:
        verdict = "undecided at this spread (the runs' ratios span it)"
    if random_play is not None and max(fdr + fdr_edr) < random_play:
        verdict = (
            f"no evidence either way {where}: no run of either input scores above random play "
            f"({random_play:,.0f} a game) there, so this compares two policies that play the "
            f"game worse than chance, not what EDR adds to one that plays it (why they do: "
            f"docs/atari.md, 'Centipede: why the score falls'); by the numbers alone, {verdict}"
        )
    else:
        verdict = f"{verdict} {where}"
    return (
        f"{claim}: {verdict}: FDR+EDR's training score {min(fdr_edr):,.0f} - "
        f"{max(fdr_edr):,.0f} ({len(fdr_edr)} runs), FDR's {min(fdr):,.0f} - {max(fdr):,.0f} "
        f"({len(fdr)} runs): {np.mean(fdr_edr) / np.mean(fdr):.2f}x by the means, "
        f"{low:.2f} - {high:.2f}x run against run."
    )
