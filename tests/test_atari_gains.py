"""Table 1's gain rows on a small fabricated set of records whose answers are known: the paper's
formula per game and on average, the seed pairs, a missing game, the worst-case verdict and the
suite's random play."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from edr.report.atari_gains import (
    RANDOM_PLAY,
    average_gains,
    gains_block,
    game_gains,
    random_play,
    worst_case_verdict,
)
from edr.report.published import PUBLISHED, load_published

# (game, input, seed) -> (avg, best, worst)
SCORES = {
    ("Pong", "fdr", 0): (10.0, 20.0, 5.0),
    ("Pong", "fdr", 1): (20.0, 20.0, 5.0),
    ("Pong", "fdr_edr", 0): (15.0, 21.0, 10.0),
    ("Pong", "fdr_edr", 1): (15.0, 21.0, 10.0),
    ("Breakout", "fdr", 0): (10.0, 40.0, 2.0),
    ("Breakout", "fdr_edr", 0): (20.0, 40.0, 1.0),
    ("Centipede", "fdr", 0): (1000.0, 2000.0, 300.0),  # no FDR+EDR run: missing
}


def _records(root: Path) -> pd.DataFrame:
    rows = []
    for (game, inputs, seed), (avg, best, worst) in SCORES.items():
        folder = root / "table1_x" / f"{game}_{inputs}_{seed}"
        folder.mkdir(parents=True)
        rows.append({
            "game": game, "input": inputs, "seed": seed, "budget": "5M",
            "record": str(folder / "run.json"), "metrics.eval/mean": avg,
            "metrics.eval/max": best, "metrics.eval/min": worst,
        })  # fmt: skip
    return pd.DataFrame(rows)


def test_each_games_gain_is_the_papers_term_with_its_seed_pairs(tmp_path) -> None:
    done = _records(tmp_path)
    pong = game_gains(done[done["game"] == "Pong"])
    assert pong["avg"]["gain"] == 0.0  # 15 against 15 over seeds
    assert pong["avg"]["pairs"] == [(0, 50.0), (1, -25.0)]  # seed s against seed s
    assert (pong["avg"]["ahead"], pong["avg"]["behind"]) == (1, 1)
    assert pong["worst"]["gain"] == 100.0 and pong["worst"]["ahead"] == 2
    breakout = game_gains(done[done["game"] == "Breakout"])
    assert breakout["avg"]["gain"] == 100.0 and breakout["worst"]["gain"] == -50.0
    assert breakout["best"]["gain"] == 0.0 and breakout["best"]["ahead"] == 0  # a tie leads not
    games = {
        g: {i: {"avg": a, "best": b, "worst": w} for (gg, i, _), (a, b, w) in
            {k: v for k, v in SCORES.items() if k[2] == 0}.items() if gg == g}
        for g in ("Breakout", "Centipede")
    }  # fmt: skip
    assert average_gains(games) == {
        "avg": 100.0,
        "best": 0.0,
        "worst": -50.0,
    }  # Centipede: one input


def test_the_gain_block_averages_the_games_both_inputs_ran_and_names_the_missing(tmp_path) -> None:
    done = _records(tmp_path)
    text = gains_block(done, load_published(PUBLISHED))
    assert "| the paper, as printed | 6 of 6 | +23.8 | +20.9 | +70.2 |" in text
    # Avg: mean(0, +100); Best: mean(+5, 0); Worst: mean(+100, -50)
    assert (
        "| ours at 5M env steps | 2 of 6 (MsPacman, Centipede, Qbert, Seaquest missing) | +50.0 "
        "| +2.5 | +25.0 |"
    ) in text
    assert "| Pong | +0 % (-25 to +50), 1 of 2 ahead |" in text
    assert "| Centipede | missing (only fdr) | missing (only fdr) | missing (only fdr) |" in text
    assert "| Qbert | missing (no run) |" in text
    assert 'worst case": undecided (MsPacman, Centipede, Qbert, Seaquest missing)' in text
    assert "ahead in every seed pair in Pong, behind in every pair in Breakout" in text


def test_the_worst_case_claim_is_judged_once_every_game_ran() -> None:
    def game(ahead: int, behind: int, pairs: int = 3) -> dict:
        return {"worst": {"pairs": [(s, 0.0) for s in range(pairs)], "ahead": ahead,
                          "behind": behind}}  # fmt: skip

    assert worst_case_verdict({"A": game(3, 0), "B": game(2, 1)}, [], 30.0).startswith("supported")
    assert worst_case_verdict({"A": game(3, 0), "B": game(0, 3)}, [], 30.0).startswith("mixed")
    assert worst_case_verdict({"A": game(3, 0)}, [], -1.0).startswith("contradicted")
    assert worst_case_verdict({"A": game(0, 3)}, [], 5.0).startswith("contradicted")
    assert worst_case_verdict({"A": game(3, 0)}, ["B"], 30.0).startswith("undecided (B missing)")


def test_random_play_comes_from_the_runs_scored_again_else_from_the_stored_records(
    tmp_path,
) -> None:
    done = _records(tmp_path)
    pong = Path(done.loc[0, "record"]).parent
    (pong / "network_eval.json").write_text(json.dumps({"random/mean": -20.0}))
    stored = tmp_path / RANDOM_PLAY
    stored.mkdir()
    for name, game, mean in [("a", "Pong", -21.0), ("b", "Qbert", 150.0), ("c", "Qbert", 170.0)]:
        (stored / f"{name}.json").write_text(json.dumps({"game": game, "random/mean": mean}))
    assert random_play(done) == {"Pong": [-20.0], "Qbert": [150.0, 170.0]}
