"""The Table 2 baselines: shapes, known answers, and their errors."""

from __future__ import annotations

import io

import numpy as np
import pytest
import torch

from clips import ramp_clip, translating_clip
from edr.data import write_video
from edr.representations import (
    EDR,
    FDR,
    TVL1,
    DVSCamera,
    Farneback,
    GrayDiff,
    MPEGFlow,
    RGBDiff,
    decode_motion_vectors,
)
from edr.representations.mpeg_flow import encode_clip

ALL = [
    EDR(),
    EDR(half_lives=(1, 3.8), color="gray"),
    FDR(),
    FDR(color="gray"),
    GrayDiff(),
    RGBDiff(),
]
ALL += [Farneback(), TVL1(scales=2, warps=2), MPEGFlow(), DVSCamera()]


@pytest.mark.parametrize("rep", ALL, ids=lambda r: type(r).__name__)
@pytest.mark.parametrize("channels", [1, 3])
def test_output_shape_matches_declared_sizes(rep, channels: int) -> None:
    clip = translating_clip(frames=4, height=32, width=48)[:, :, :channels]
    with torch.no_grad():
        out = rep(clip)
    assert out.shape == (1, rep.out_frames(4), rep.out_channels(channels), 32, 48)
    assert out.dtype == torch.float32
    assert torch.isfinite(out).all()
    picture = rep.preview(out[0, -1])
    assert picture.shape == (32, 48, 3) and np.isfinite(picture).all()


@pytest.mark.parametrize("flow", [Farneback(), TVL1(), MPEGFlow()], ids=lambda r: type(r).__name__)
def test_translation_gives_flow_of_the_right_sign(flow, moving_right, moving_left) -> None:
    inner = (slice(None), slice(None), slice(8, -8), slice(8, -8))
    right = flow(moving_right)[0][inner]
    left = flow(moving_left)[0][inner]
    assert right[:, 0].mean() == pytest.approx(2.0, abs=0.5)
    assert left[:, 0].mean() == pytest.approx(-2.0, abs=0.5)
    assert right[:, 1].abs().mean() < 0.3
    down = flow(translating_clip(dx=0, dy=2))[0][inner]
    assert down[:, 1].mean() == pytest.approx(2.0, abs=0.5)


def test_gray_diff_known_values_and_fused_path() -> None:
    clip = ramp_clip([10, 60, 40], channels=3)
    out = GrayDiff(scale=1.0)(clip)
    torch.testing.assert_close(
        out[0, :, 0, 0, 0], torch.tensor([50.0, -20.0]), rtol=1e-5, atol=1e-4
    )
    video = translating_clip(frames=6).contiguous()
    with torch.no_grad():
        fused = GrayDiff(fast=True)(video)
    torch.testing.assert_close(fused, GrayDiff(fast=False)(video), rtol=1e-5, atol=1e-6)


def test_rgb_diff_and_fdr_values() -> None:
    clip = torch.zeros((1, 2, 3, 2, 2), dtype=torch.uint8)
    clip[0, 1, 2] = 255
    diff = RGBDiff()(clip)
    assert diff[0, 0, 2].eq(1).all() and diff[0, 0, :2].eq(0).all()
    assert FDR(offset=0.0)(clip).max() == 1.0
    assert FDR()(clip).min() == -0.5  # centred: fdr.yaml's and the default
    assert FDR(color="gray")(clip).shape == (1, 2, 1, 2, 2)


def test_mpeg_flow_from_a_file_and_a_corrupt_one(tmp_path, moving_right) -> None:
    frames = moving_right[0].permute(0, 2, 3, 1).numpy()
    path = tmp_path / "clip.avi"
    path.write_bytes(encode_clip(frames).getvalue())
    flow = decode_motion_vectors(path)
    assert flow.shape == (5, 2, 48, 64)
    assert np.abs(flow[0]).max() == 0  # the I-frame has no vectors
    assert flow[1:, 0, 8:-8, 8:-8].mean() == pytest.approx(2.0, abs=0.5)
    bad = tmp_path / "broken.avi"
    bad.write_bytes(b"RIFF not really a video")
    with pytest.raises(ValueError, match=r"broken\.avi"):
        decode_motion_vectors(bad)
    mjpg = write_video(tmp_path / "intra.avi", moving_right[0])
    assert np.abs(decode_motion_vectors(mjpg)).max() == 0  # intra-only codec: no motion vectors
    assert decode_motion_vectors(io.BytesIO(path.read_bytes())).shape == flow.shape
