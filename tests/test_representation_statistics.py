"""The distribution of a representation's output per channel (``edr.studies.representation_statistics``)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from edr.studies.representation_statistics import channel_statistics, clips_of, measure


def test_scale_and_sparsity_per_channel() -> None:
    outputs = torch.zeros(2, 3, 2, 4, 4)  # (N, T, C, H, W)
    outputs[:, :, 1, :2] = -2.0  # channel 1: half its values -2, half exact zeros
    empty, half = channel_statistics(outputs)
    assert empty["rms"] == empty["max_abs"] == 0 and empty["zeros"] == 1
    assert half["zeros"] == half["below_1pct_rms"] == 0.5 and half["mean"] == -1.0
    assert half["rms"] == pytest.approx(2**0.5) and half["mean_abs_nonzero"] == 2.0
    assert half["max_abs"] == half["p999_abs"] == 2.0


def test_consecutive_clips_of_every_video_and_their_statistics() -> None:
    rng = np.random.default_rng(0)
    videos = [rng.integers(0, 255, (t, 1, 6, 8), dtype=np.uint8) for t in (10, 7)]
    clips = clips_of(videos, 4)
    assert clips.shape == (3, 4, 1, 6, 8)  # two of the first video, one of the second
    assert torch.equal(clips[1], torch.from_numpy(videos[0][4:8]))
    (fdr,) = measure(videos, ("fdr",), 4)
    assert fdr["clips"] == 3 and len(fdr["channels"]) == 1 and fdr["channels"][0]["zeros"] < 0.1
