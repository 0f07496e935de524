"""Whether training has diverged: its loss, or a parameter of the network, is no longer a finite
number. Every training task stops there and records it as a result, with the step and this
reason (``train/diverged_step``, ``train/diverged_reason``), rather than crash or go on."""

from __future__ import annotations

import math

import torch
from torch import nn


def divergence(module: nn.Module, loss: torch.Tensor | float | None = None) -> str | None:
    """Why training cannot go on, or None: ``loss`` is not a finite number, or a parameter of
    ``module`` holds NaN or inf (the first such is named)."""
    value = (
        float(loss.detach() if isinstance(loss, torch.Tensor) else loss)
        if loss is not None
        else 0.0
    )
    if not math.isfinite(value):
        return f"the loss is {value}"
    parameters = [p.detach() for p in module.parameters()]
    if not parameters:
        return None
    # One reduction per tensor and one sync: NaN or inf anywhere makes the sum so.
    if math.isfinite(float(torch.stack([p.sum(dtype=torch.float64) for p in parameters]).sum())):
        return None
    for name, p in module.named_parameters():
        if not bool(torch.isfinite(p.detach()).all()):
            return f"parameter {name} holds NaN or inf"
    return "the parameters sum to NaN or inf"  # finite ones too large to add up
