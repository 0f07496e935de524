"""edr.report.training_course: the critic's value a clipped-reward rate implies, and the course of
training read from a history."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd

from edr.report.training_course import course_rows, implied_value, mean_before


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
