"""Networks: the video recognition backbones (LTC, and per-frame ConvNets with a recurrent
head) and PAAC's actor-critic network for Atari (:mod:`edr.models.paac`)."""

from edr.models.convnets import LeNet, NiN
from edr.models.ltc import LTC
from edr.models.recognition import (
    ConvRecurrent,
    RecognitionModel,
    activation_sparsity,
    input_norm,
)
from edr.models.recurrent import FTRCN, GRURCN, LRCN

__all__ = [
    "FTRCN",
    "GRURCN",
    "LRCN",
    "LTC",
    "ConvRecurrent",
    "LeNet",
    "NiN",
    "RecognitionModel",
    "activation_sparsity",
    "input_norm",
]
