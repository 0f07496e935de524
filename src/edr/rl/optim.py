"""PAAC's optimizer as PyTorch lacks it, and the choice between it and Adam.

PAAC trained with TensorFlow 1's ``RMSPropOptimizer``, which differs from ``torch.optim.RMSprop``
in two ways that matter at PAAC's settings (eps 0.1, gradients ~1e-3):
- the step divides by ``sqrt(ms + eps)``, where torch divides by ``sqrt(ms) + eps``: with
  eps = 0.1 torch's denominator is eps itself and the update is plain SGD;
- the mean square ``ms`` starts at 1, not 0.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Literal

import torch

OptimizerName = Literal["rmsprop_tf", "adam"]


class TFRMSprop(torch.optim.Optimizer):
    """``ms <- decay * ms + (1 - decay) * g^2``; ``p <- p - lr * g / sqrt(ms + eps)``; ms_0 = 1."""

    def __init__(
        self,
        params: Iterable[torch.nn.Parameter],
        lr: float,
        decay: float = 0.99,
        eps: float = 0.1,
    ) -> None:
        if lr <= 0 or not 0 <= decay < 1 or eps <= 0:
            raise ValueError(
                f"TFRMSprop needs lr > 0, 0 <= decay < 1, eps > 0; got {lr}, {decay}, {eps}"
            )
        super().__init__(params, {"lr": lr, "decay": decay, "eps": eps})

    @torch.no_grad()
    def step(self, closure=None):  # torch's signature
        loss = None if closure is None else closure()
        for group in self.param_groups:
            for p in group["params"]:
                if p.grad is None:
                    continue
                state = self.state[p]
                if not state:
                    state["ms"] = torch.ones_like(p)
                ms = state["ms"]
                ms.mul_(group["decay"]).addcmul_(p.grad, p.grad, value=1 - group["decay"])
                p.addcdiv_(p.grad, (ms + group["eps"]).sqrt_(), value=-group["lr"])
        return loss


def make_optimizer(
    name: OptimizerName,
    params: Iterable[torch.nn.Parameter],
    lr: float,
    rmsprop_decay: float = 0.99,
    rmsprop_eps: float = 0.1,
    adam_eps: float = 1e-5,
) -> torch.optim.Optimizer:
    """``rmsprop_tf`` (PAAC's) or ``adam``."""
    if name == "rmsprop_tf":
        return TFRMSprop(params, lr=lr, decay=rmsprop_decay, eps=rmsprop_eps)
    if name == "adam":
        return torch.optim.Adam(params, lr=lr, eps=adam_eps)
    raise ValueError(f"optimizer must be rmsprop_tf or adam, got {name!r}")
