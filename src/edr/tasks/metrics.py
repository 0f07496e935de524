"""Classification metrics the recognition and DVS-transfer tasks report."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np


def confusion_matrix(predicted: np.ndarray, true: np.ndarray, classes: int) -> np.ndarray:
    """(classes, classes) counts, rows = true class, columns = predicted class."""
    matrix = np.zeros((classes, classes), np.int64)
    np.add.at(matrix, (true, predicted), 1)
    return matrix


def classification_metrics(
    predicted: np.ndarray, true: np.ndarray, classes: Sequence[str]
) -> tuple[dict[str, float], dict[str, Any]]:
    """(flat metrics: accuracy, chance, per-class accuracy; the confusion file's content)."""
    matrix = confusion_matrix(predicted, true, len(classes))
    per_class = matrix.diagonal() / np.maximum(matrix.sum(1), 1)
    metrics = {
        "eval/accuracy": float((predicted == true).mean()),
        "eval/chance": 1.0 / len(classes),
        **{f"eval/per_class/{c}": float(a) for c, a in zip(classes, per_class, strict=True)},
    }
    return metrics, {"classes": list(classes), "rows": "true class", "matrix": matrix.tolist()}
