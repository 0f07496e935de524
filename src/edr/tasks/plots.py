"""Figures the tasks save beside their run records."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from edr.store.atomic import save_figure


def save_learning_curve(history: Sequence[dict[str, float]], path: Path) -> Path:
    """Training loss and accuracy, and test accuracy where measured, against epochs."""
    fig, (ax_loss, ax_acc) = plt.subplots(1, 2, figsize=(8, 3))
    epochs = [row["epoch"] for row in history]
    ax_loss.plot(epochs, [row["train/loss"] for row in history], "k.-")
    ax_loss.set(xlabel="epoch", ylabel="train loss")
    ax_acc.plot(epochs, [row["train/accuracy"] for row in history], ".-", label="train clips")
    tested = [row for row in history if "eval/accuracy" in row]
    ax_acc.plot(
        [r["epoch"] for r in tested],
        [r["eval/accuracy"] for r in tested],
        "o-",
        label="test videos",
    )
    ax_acc.set(xlabel="epoch", ylabel="accuracy", ylim=(0, 1))
    ax_acc.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path, dpi=100)
    return path


def save_confusion(matrix: np.ndarray, classes: Sequence[str], path: Path) -> Path:
    """Row-normalized confusion matrix (true class per row)."""
    shown = matrix / np.maximum(matrix.sum(1, keepdims=True), 1)
    size = max(3.0, 0.45 * len(classes) + 1.5)
    fig, ax = plt.subplots(figsize=(size, size))
    ax.imshow(shown, cmap="Blues", vmin=0, vmax=1)
    if len(classes) <= 30:
        ax.set_xticks(range(len(classes)), classes, rotation=90, fontsize=7)
        ax.set_yticks(range(len(classes)), classes, fontsize=7)
    ax.set(xlabel="predicted", ylabel="true")
    fig.tight_layout()
    save_figure(fig, path, dpi=100)
    return path


def save_score_curve(history: Sequence[dict[str, float]], path: Path, title: str = "") -> Path:
    """Mean score of recent training episodes against env steps (the paper's Figure 5), and
    beside it whether the network stays alive: the fraction of dead units per ReLU layer and
    the critic's mean value."""
    scored = [row for row in history if "train/score" in row]
    fig, (score, dead, value) = plt.subplots(1, 3, figsize=(13, 3))
    score.plot([r["env_steps"] for r in scored], [r["train/score"] for r in scored], "k-")
    score.set(xlabel="env steps", ylabel="mean score (last 20 episodes)", title=title)
    steps = [r["env_steps"] for r in history]
    for layer in sorted({k for row in history for k in row if k.startswith("dead/")}):
        dead.plot(steps, [r.get(layer, float("nan")) for r in history], label=layer[5:])
    dead.set(xlabel="env steps", ylabel="dead units (fraction)", ylim=(-0.02, 1.02))
    if dead.lines:
        dead.legend(fontsize=7)
    value.plot(steps, [r.get("train/value_mean", float("nan")) for r in history], "b-")
    value.set(xlabel="env steps", ylabel="critic's mean value")
    fig.tight_layout()
    save_figure(fig, path, dpi=100)
    return path
