"""Whether a network stays alive: which units of its ReLU layers never fire."""

from __future__ import annotations

import torch
from torch import nn


class DeadUnits:
    """Which units of each ReLU layer of ``network`` output zero on every state it saw since
    :meth:`reset`: a conv unit is a channel (zero at every location), a linear one a feature.
    A layer whose units are all dead passes nothing on, and no gradient reaches what feeds it."""

    def __init__(self, network: nn.Module) -> None:
        self._fired: dict[str, torch.Tensor] = {}  # layer name -> (units,) bool
        for name, module in network.named_modules():
            if isinstance(module, nn.ReLU):
                module.register_forward_hook(self._hook(name))

    def _hook(self, name: str):
        def record(module: nn.Module, inputs: object, out: torch.Tensor) -> None:
            # (B, C, H, W) or (B, F): a unit fired if it was positive anywhere in the batch
            fired = (out.detach() > 0).transpose(0, 1).flatten(1).any(1)
            seen = self._fired.get(name)
            self._fired[name] = fired if seen is None else seen | fired

        return record

    def reset(self) -> None:
        self._fired.clear()

    def fractions(self) -> dict[str, float]:
        """``{"dead/<layer>": fraction of its units that never fired}`` since the reset."""
        return {f"dead/{k}": 1.0 - v.float().mean().item() for k, v in self._fired.items()}
