"""MPEG flow: the motion vectors a video codec already stored, rasterized to a dense field.

FFmpeg exports them as frame side data when decoding with ``flags2=+export_mvs`` (PyAV). A
vector says where in the reference frame a macroblock came from, so for a past reference the
forward flow of the block is ``-(motion / motion_scale)``; intra blocks and I-frames get 0.
"""

from __future__ import annotations

import io
from pathlib import Path

import av
import numpy as np
import torch

from edr.checks.config import check_arguments
from edr.representations.base import Features, FlowRepresentation, check_clip, to_float


def rasterize_motion_vectors(mvs: np.ndarray, height: int, width: int) -> np.ndarray:
    """FFmpeg ``AVMotionVector`` records -> (2, H, W) float32 forward flow (dx, dy)."""
    flow = np.zeros((2, height, width), np.float32)
    if mvs is None or len(mvs) == 0:
        return flow
    scale = np.maximum(mvs["motion_scale"].astype(np.float32), 1.0)
    # source < 0: the block comes from a past frame; > 0 from a future one (B-frames).
    sign = np.where(mvs["source"] < 0, -1.0, 1.0).astype(np.float32)
    dx = sign * mvs["motion_x"] / scale
    dy = sign * mvs["motion_y"] / scale
    x0 = np.clip(mvs["dst_x"].astype(np.int64) - mvs["w"] // 2, 0, width)
    y0 = np.clip(mvs["dst_y"].astype(np.int64) - mvs["h"] // 2, 0, height)
    x1 = np.clip(x0 + mvs["w"], 0, width)
    y1 = np.clip(y0 + mvs["h"], 0, height)
    for i in range(len(mvs)):
        flow[0, y0[i] : y1[i], x0[i] : x1[i]] = dx[i]
        flow[1, y0[i] : y1[i], x0[i] : x1[i]] = dy[i]
    return flow


def decode_motion_vectors(source: str | Path | io.BytesIO) -> np.ndarray:
    """A compressed video (path or bytes) -> (T, 2, H, W) float32 MPEG flow, one per frame."""
    name = source if isinstance(source, str | Path) else "<in-memory video>"
    try:
        with av.open(source) as container:
            stream = container.streams.video[0]
            stream.codec_context.options = {"flags2": "+export_mvs"}
            fields = []
            for frame in container.decode(stream):
                mvs = frame.side_data.get("MOTION_VECTORS")
                array = mvs.to_ndarray() if mvs is not None else None
                fields.append(rasterize_motion_vectors(array, frame.height, frame.width))
    except (av.error.FFmpegError, IndexError) as err:
        raise ValueError(f"cannot decode motion vectors from {name}: {err}") from err
    if not fields:
        raise ValueError(f"{name} holds no video frames")
    return np.stack(fields)


def encode_clip(frames: np.ndarray, codec: str = "mpeg4", gop: int = 250) -> io.BytesIO:
    """(T, H, W, 3) uint8 RGB -> an in-memory AVI, P-frames only after the first (no B-frames)."""
    t, h, w, _ = frames.shape
    buffer = io.BytesIO()
    with av.open(buffer, "w", format="avi") as container:
        stream = container.add_stream(codec, rate=25)
        stream.width, stream.height, stream.pix_fmt = w, h, "yuv420p"
        stream.options = {"g": str(gop), "bf": "0"}
        for i in range(t):
            container.mux(stream.encode(av.VideoFrame.from_ndarray(frames[i], format="rgb24")))
        container.mux(stream.encode())
    buffer.seek(0)
    return buffer


class MPEGFlow(FlowRepresentation):
    """Codec motion vectors as flow: (B, T, C, H, W) -> (B, T-1, 2, H, W).

    A clip of raw frames is first encoded (``codec``, P-frames only), then decoded with its
    vectors; for video already on disk, ``decode_motion_vectors(path)`` reads the vectors the
    file was stored with, which is what the paper timed.
    """

    features = Features(
        "2 frames (the codec's reference)", "no", "no", "no", "yes (block motion vectors)", "no"
    )

    def __init__(self, codec: str = "mpeg4") -> None:
        super().__init__()
        check_arguments(self, locals())
        self.codec = codec

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        check_clip(frames, min_frames=2, name="frames")
        b, t, c, h, w = frames.shape
        rgb = to_float(frames.detach().cpu()).round().clamp(0, 255).to(torch.uint8)
        rgb = rgb.expand(b, t, 3, h, w) if c == 1 else rgb
        # yuv420p needs even sizes: pad by replication, crop the flow back.
        pad_h, pad_w = h % 2, w % 2
        clips = rgb.permute(0, 1, 3, 4, 2).numpy()  # (B, T, H, W, 3)
        flows = []
        for clip in clips:
            clip = np.pad(clip, ((0, 0), (0, pad_h), (0, pad_w), (0, 0)), mode="edge")
            flows.append(decode_motion_vectors(encode_clip(clip, self.codec))[1:, :, :h, :w])
        return torch.from_numpy(np.stack(flows)).to(frames.device)
