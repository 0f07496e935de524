"""Recurrent heads over per-frame feature maps (B, T, F, h, w) -> (B, num_classes).

- LRCN (Donahue et al.): an LSTM over the flattened feature maps.
- GRU-RCN (Ballas et al.): a convolutional GRU — the recurrence at each location mixes all
  channels through 3x3 convolutions.
- FT-RCN (feature tracking): a GRU whose recurrent term is, for each channel on its own, a
  full map from every location to every location of that channel (a (h*w) x (h*w) matrix per
  channel and gate); no recurrent weight couples two channels. The input term may mix channels.

Each classifies from its final hidden state (spatially averaged for the two convolutional ones).
"""

from __future__ import annotations

import math

import torch
from torch import nn


def feature_tracking_weights(gates: int, channels: int, locations: int) -> nn.Parameter:
    """The recurrent weights of a feature-tracking cell, (gate, channel, from location, to
    location): each channel a full map from every location of its own to every other."""
    return nn.Parameter(torch.randn(gates, channels, locations, locations) / math.sqrt(locations))


def track_features(state: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """The feature-tracking recurrence: state (B, C, P) through weights (G, C, P, P) ->
    (B, G, C, P), each gate's recurrent term; within each channel every location reaches every
    location, and no channel reads another (FT-RCN here, FT-LSTM in :mod:`edr.models.paac`)."""
    return torch.einsum("bcp,gcpq->bgcq", state, weights)


class LRCN(nn.Module):
    def __init__(
        self, channels: int, height: int, width: int, num_classes: int, hidden: int = 256
    ) -> None:
        super().__init__()
        self.lstm = nn.LSTM(channels * height * width, hidden, batch_first=True)
        self.classifier = nn.Linear(hidden, num_classes)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        b, t = features.shape[:2]
        _, (h, _) = self.lstm(features.reshape(b, t, -1))  # h: (1, B, hidden)
        return self.classifier(h[-1])


class _GatedRecurrentHead(nn.Module):
    """A GRU over feature maps; subclasses give the recurrent term of each gate (z, r, n)."""

    def __init__(self, channels: int, num_classes: int, hidden: int, kernel: int) -> None:
        super().__init__()
        self.hidden = hidden
        self.input_gates = nn.Conv2d(channels, 3 * hidden, kernel, padding=kernel // 2)  # z, r, n
        self.classifier = nn.Linear(hidden, num_classes)

    def recurrent_term(self, state: torch.Tensor, gate: int) -> torch.Tensor:
        """(B, hidden, h, w) -> (B, hidden, h, w): what the previous state adds to ``gate``."""
        raise NotImplementedError

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        b, t, _, h, w = features.shape
        state = features.new_zeros(b, self.hidden, h, w)
        inputs = self.input_gates(features.flatten(0, 1)).view(b, t, 3, self.hidden, h, w)
        for step in range(t):
            xz, xr, xn = inputs[:, step].unbind(1)
            z = torch.sigmoid(xz + self.recurrent_term(state, 0))
            r = torch.sigmoid(xr + self.recurrent_term(state, 1))
            candidate = torch.tanh(xn + self.recurrent_term(r * state, 2))
            state = (1 - z) * candidate + z * state  # (B, hidden, h, w)
        return self.classifier(state.mean(dim=(2, 3)))


class GRURCN(_GatedRecurrentHead):
    def __init__(
        self,
        channels: int,
        height: int,
        width: int,
        num_classes: int,
        hidden: int = 64,
        kernel: int = 3,
    ) -> None:
        super().__init__(channels, num_classes, hidden, kernel)
        self.recurrent = nn.ModuleList(
            nn.Conv2d(hidden, hidden, kernel, padding=kernel // 2, bias=False) for _ in range(3)
        )

    def recurrent_term(self, state: torch.Tensor, gate: int) -> torch.Tensor:
        return self.recurrent[gate](state)  # every channel at every neighbouring location


class FTRCN(_GatedRecurrentHead):
    def __init__(
        self,
        channels: int,
        height: int,
        width: int,
        num_classes: int,
        hidden: int = 64,
        kernel: int = 3,
    ) -> None:
        super().__init__(channels, num_classes, hidden, kernel)
        self.recurrent = feature_tracking_weights(3, hidden, height * width)  # z, r, n

    def recurrent_term(self, state: torch.Tensor, gate: int) -> torch.Tensor:
        """Within each channel, every location to every location; no channel reads another."""
        term = track_features(state.flatten(2), self.recurrent[gate : gate + 1])  # (B, 1, C, P)
        return term[:, 0].view_as(state)
