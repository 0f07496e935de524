"""edr.report.training_course: the critic's value a clipped-reward rate implies, and the course of
training read from a history."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd

from edr.report.training_course import (
    agreement_rows,
    course_rows,
    implied_value,
    main,
    mean_before,
    score_value_agreement,
)


def test_the_implied_value_is_the_mean_discounted_return_over_a_games_states() -> None:
    rate, steps, discount = 0.2, 300, 0.99
    rewards = np.full(steps, rate)
    values = [sum(rewards[t + k] * discount**k for k in range(steps - t)) for t in range(steps)]
    assert abs(implied_value(rate * steps, steps, discount) - np.mean(values)) < 1e-9


def test_the_course_reads_the_score_and_the_diagnostics_before_each_point(tmp_path) -> None:
    history = [{"env_steps": s, "train/score": 10.0 * s / 1e6, "train/value_mean": s / 1e5,
                "train/entropy": 1.0} for s in range(100_000, 1_100_000, 100_000)]  # fmt: skip
    (tmp_path / "history.json").write_text(json.dumps(history))
    runs = pd.DataFrame([{"record": str(tmp_path / "run.json"), "task": "atari", "seed": 0,
                          "status": "finished", "fingerprint": "a",
                          "config.task.env.inputs": "fdr_edr"}])  # fmt: skip
    rows = course_rows(runs, points=(500_000, 1_000_000, 2_000_000))
    assert list(rows["env steps"]) == [500_000, 1_000_000]  # the history stops at 1M
    assert list(rows["score"]) == [5.0, 10.0] and set(rows["input"]) == {"FDR+EDR"}
    assert list(rows["critic's mean value"]) == [4.0, 9.0]  # rows in (0.25M before, the point]
    assert np.isnan(rows["value loss"]).all()  # not in this history
    assert np.isnan(mean_before(history, "train/entropy", 50_000))
    assert agreement_rows(runs).empty  # nothing after 1M to read the agreement over


def _history(score: list[float], value: list[float]) -> list[dict[str, float]]:
    """A history of one row per 0.5M env steps from 0.5M on."""
    return [{"env_steps": 500_000 * (i + 1), "train/score": s, "train/value_mean": v}
            for i, (s, v) in enumerate(zip(score, value, strict=True))]  # fmt: skip


def test_the_agreement_is_the_rank_correlation_of_score_and_value_from_its_start() -> None:
    parting = _history([9.0, 5.0, 4.0, 3.0, 2.0], [0.0, 1.0, 2.0, 3.0, 4.0])
    assert score_value_agreement(parting) == -1.0  # from 1M on: falling score, rising value
    together = _history([0.0, 1.0, 3.0, 2.0, 4.0], [5.0, 1.0, 3.0, 2.0, 4.0])
    assert score_value_agreement(together) == 1.0  # the 0.5M row, before 1M, is not read
    assert np.isnan(score_value_agreement(together[:3]))  # two rows from 1M on: too few


def test_the_command_prints_each_runs_course_and_agreement(tmp_path, capsys) -> None:
    for inputs, score in (("fdr", [3.0, 2.0, 1.0, 0.5]), ("fdr_edr", [1.0, 2.0, 3.0, 4.0])):
        run = tmp_path / "sweep" / inputs
        run.mkdir(parents=True)
        (run / "history.json").write_text(json.dumps(_history(score, [1.0, 2.0, 3.0, 4.0])))
        (run / "run.json").write_text(json.dumps({
            "status": "finished", "task": "atari", "seed": 0, "fingerprint": inputs, "cell": inputs,
            "data": {}, "metrics": {"eval/mean": 1.0},
            "config": {"task": {"env": {"game": "Centipede", "inputs": inputs}}},
        }))  # fmt: skip
    main([str(tmp_path / "sweep"), "--per-run", "--points", "1", "2"])
    text = capsys.readouterr().out
    assert "| Centipede | FDR     |      0 | 2M          |    0.50 |" in text
    assert "| Centipede | FDR+EDR |      0 | 2M             |         2.00 |       4.00 |" in text
    assert text.count("-1.00 |") == 1 and text.count(" 1.00 |") >= 1
