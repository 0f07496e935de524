"""Every backbone x head x representation builds, runs forward and backward; FT-RCN's structure."""

from __future__ import annotations

import functools

import pytest
import torch

from edr.models import (
    FTRCN,
    GRURCN,
    LRCN,
    LTC,
    ConvRecurrent,
    LeNet,
    NiN,
    RecognitionModel,
    activation_sparsity,
)
from edr.representations import EDR, FDR, GrayDiff, RGBDiff

FEATURES = {
    "lenet": functools.partial(LeNet, widths=(4, 6)),
    "nin": functools.partial(NiN, widths=(4, 6, 6)),
}
HEADS = {
    "lrcn": functools.partial(LRCN, hidden=8),
    "grurcn": functools.partial(GRURCN, hidden=4),
    "ftrcn": functools.partial(FTRCN, hidden=4),
}
REPRESENTATIONS = {
    "edr": EDR(),
    "edr_k3_learnable": EDR(half_lives=(1, 3.8, 8), learnable=True),
    "fdr": FDR(),
    "graydiff": GrayDiff(),
    "rgbdiff": RGBDiff(),
}


def _check(model: RecognitionModel, clip: torch.Tensor, classes: int) -> None:
    logits = model(clip)
    assert logits.shape == (clip.shape[0], classes)
    logits.logsumexp(-1).sum().backward()
    grads = [p.grad for p in model.backbone.parameters()]
    assert all(g is not None and torch.isfinite(g).all() for g in grads)
    assert any(g.abs().sum() > 0 for g in grads)


@pytest.mark.parametrize("rep_name", REPRESENTATIONS)
@pytest.mark.parametrize("features", FEATURES)
@pytest.mark.parametrize("head", HEADS)
def test_convnet_rcn_combinations(rep_name: str, features: str, head: str) -> None:
    rep = REPRESENTATIONS[rep_name]
    clip = torch.rand(2, 5, 3, 20, 20) * 255
    backbone = ConvRecurrent(
        rep.out_channels(3),
        4,
        FEATURES[features],
        HEADS[head],
        frames=rep.out_frames(5),
        height=20,
        width=20,
    )
    model = RecognitionModel(rep, backbone)
    _check(model, clip, 4)
    if getattr(rep, "learnable", False):
        assert rep.log_tau.grad is not None and rep.log_tau.grad.abs().sum() > 0


@pytest.mark.parametrize("channels", [1, 2, 3, 6])
def test_ltc_takes_any_channel_count(channels: int) -> None:
    ltc = LTC(channels, 5, frames=8, height=24, width=24, widths=(4, 4, 4, 4, 4), fc=8)
    _check(RecognitionModel(None, ltc), torch.rand(2, 8, channels, 24, 24), 5)


def test_ltc_paper_sizes() -> None:
    ltc = LTC(2, 101)  # 60 frames of 58x58, widths 64-128-256-256-256, FC 2048
    convs = [m for m in ltc.modules() if isinstance(m, torch.nn.Conv3d)]
    assert [c.out_channels for c in convs] == [64, 128, 256, 256, 256]
    assert all(c.kernel_size == (3, 3, 3) for c in convs)
    fcs = [m for m in ltc.modules() if isinstance(m, torch.nn.Linear)]
    assert [f.out_features for f in fcs] == [2048, 2048, 101]


def test_ft_rcn_has_no_cross_channel_recurrent_weights() -> None:
    head = FTRCN(channels=3, height=4, width=5, num_classes=2, hidden=6)
    assert head.recurrent.shape == (3, 6, 20, 20)  # (gate, channel, location, location)
    state = torch.zeros(1, 6, 4, 5, requires_grad=True)
    for gate in range(3):
        out = head.recurrent_term(state + 0.5, gate)
        for c in range(6):
            (grad,) = torch.autograd.grad(out[0, c].sum(), state, retain_graph=True)
            others = torch.ones(6, dtype=torch.bool)
            others[c] = False
            assert grad[0, others].abs().max() == 0  # channel c's recurrence reads only channel c
            assert grad[0, c].abs().max() > 0  # and reads every location of it
            assert (grad[0, c] != 0).all()


def test_gru_rcn_recurrence_mixes_channels() -> None:
    # The contrast FT-RCN is defined by: a conv GRU's recurrent weights couple channels.
    head = GRURCN(channels=3, height=4, width=4, num_classes=2, hidden=4)
    assert all(conv.weight.shape[:2] == (4, 4) for conv in head.recurrent)


def test_activation_sparsity_sees_representation_and_relus() -> None:
    backbone = ConvRecurrent(2, 3, FEATURES["lenet"], HEADS["ftrcn"], frames=4, height=20, width=20)
    sparsity = activation_sparsity(
        RecognitionModel(EDR(), backbone), torch.rand(1, 4, 1, 20, 20) * 255
    )
    assert (
        "representation" in sparsity
        and sum(k.startswith("backbone.features") for k in sparsity) == 2
    )
    assert all(0.0 <= v <= 1.0 for v in sparsity.values())
