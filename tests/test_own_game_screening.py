"""The own-game screening: its experiment composes into the sweep it says, and its report ranks
candidates by the worst game's normalised score (fabricated records with a known ranking)."""

from __future__ import annotations

import pandas as pd
from hydra.core.hydra_config import HydraConfig

from edr.report.screening import candidate_ranking, own_game_markdown, own_game_rows
from edr.rl.games.scores import load_scores

YARDSTICKS = load_scores()
GAMES = list(YARDSTICKS)
# candidate -> game index -> normalised score per seed
FABRICATED = {
    "steady": {g: [0.6, 0.6, 0.6] for g in range(4)},
    "spiky": {
        0: [1.0] * 3,
        1: [1.0] * 3,
        2: [1.0] * 3,
        3: [0.1] * 3,
    },  # best average, one game lost
    "flaky": {g: [0.9, 0.9, 0.0] if g == 2 else [0.9] * 3 for g in range(4)},  # a seed collapsed
    "partial": {g: [1.0, 1.0] for g in range(4)},  # two seeds only
}


def _runs(inputs: tuple[str, ...] = ("fdr", "fdr_edr")) -> pd.DataFrame:
    rows = []
    for candidate, games in FABRICATED.items():
        for g, normalised in games.items():
            s = YARDSTICKS[GAMES[g]]
            for seed, n in enumerate(normalised):
                rows += [{
                    "record": f"{candidate}/{g}/{seed}/{i}/run.json", "task": "atari",
                    "status": "finished", "seed": seed, "choices.own_game_candidate": candidate,
                    "config.task.env.env_id": GAMES[g], "config.task.env.inputs": i,
                    "metrics.eval/mean": s["random"] + n * (s["expert"] - s["random"]),
                } for i in inputs]  # fmt: skip
    other = {"record": "pong/run.json", "task": "atari", "status": "finished", "seed": 0,
             "config.task.env.env_id": None, "metrics.eval/mean": 5.0}  # fmt: skip
    return pd.DataFrame([*rows, other])


def test_the_worst_game_ranks_candidates_then_the_worst_seed() -> None:
    rows = own_game_rows(_runs())
    assert len(rows) == 2 * (3 * 4 * 3 + 4 * 2)  # the Pong run is not one of them
    assert rows["normalised"].between(-1e-9, 1 + 1e-9).all()
    ranking = candidate_ranking(rows, GAMES)
    for inputs in ("fdr", "fdr_edr"):
        ranked = ranking[ranking["input"] == inputs]
        assert list(ranked["candidate"]) == ["steady", "flaky", "spiky", "partial"]
        assert list(ranked["rank"]) == [1, 2, 3, 4]
        flaky = ranked.set_index("candidate").loc["flaky"]
        assert abs(flaky["worst mean"] - 0.6) < 1e-9 and abs(flaky["worst min"]) < 1e-9
        assert list(ranked["complete"]) == [True, True, True, False]


def test_a_candidate_missing_a_game_has_no_worst_score() -> None:
    rows = own_game_rows(_runs(("fdr",)))
    rows = rows[~((rows["candidate"] == "steady") & (rows["game"] == GAMES[0]))]
    ranked = candidate_ranking(rows, GAMES)
    assert list(ranked["candidate"]) == ["flaky", "spiky", "partial", "steady"]
    assert pd.isna(ranked.iloc[-1]["worst mean"])


def test_the_report_names_each_inputs_winner(tmp_path) -> None:
    text = own_game_markdown(_runs(), tmp_path)
    assert text.count("steady first (worst game's mean 0.60, min 0.60)") == 2
    assert all(game in text for game in GAMES)


def test_the_screening_experiment_sweeps_candidates_games_inputs_and_seeds(compose_config) -> None:
    cfg = compose_config("experiment=own_game_screen", "own_game_candidate=lr_decay_in_run")
    assert cfg.task.env.preset == "none" and cfg.task.env.env_module == "edr.rl.games"
    assert cfg.task.env_steps == 300_000 == cfg.task.optim.lr_decay_env_steps
    compose_config("experiment=own_game_screen")
    params = HydraConfig.get().sweeper.params
    assert params["task.env.env_id"].split(",") == GAMES
    assert len(params["own_game_candidate"].split(",")) == 9
    assert params["seed"] == "0,1,2" and params["task.env.inputs"] == "fdr,fdr_edr"
