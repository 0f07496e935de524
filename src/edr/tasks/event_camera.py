"""Event camera vs frame camera (the paper's Table 3): what each representation of the same
clip costs to transmit, and how sparse it is.

For every representation: ``events_per_s`` (the number of events: for outputs that count events
— the DVS simulator, a hard-thresholded EDR — their sum, for graded outputs — a soft EDR — the
non-zero entries), ``bits_per_s`` and ``sparsity`` (the fraction of zero outputs). Events are
priced as an address-event stream: each carries its address (x, y and channel, i.e. polarity
and timescale) and a timestamp, and a graded event also its value. Frames (``FDR``) are priced
as a frame camera sends them: every pixel of every frame at 8 bits per channel.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

import torch

from edr.data.synthetic import video_or_scene
from edr.representations import FDR, Representation
from edr.validate import ExistingFile, PositiveFloat, PositiveInt

log = logging.getLogger(__name__)


def stream_cost(
    out: torch.Tensor, seconds: float, timestamp_bits: int, value_bits: int
) -> dict[str, float]:
    """An event representation's output (T', C, H, W) as an address-event stream."""
    counts = bool(torch.equal(out, out.round())) and bool((out >= 0).all())
    events = float(out.sum()) if counts else float(torch.count_nonzero(out))
    address_bits = math.ceil(math.log2(out[0].numel()))  # channel, y, x
    bits_per_event = address_bits + timestamp_bits + (0 if counts else value_bits)
    return {
        "events_per_s": events / seconds,
        "bits_per_s": events * bits_per_event / seconds,
        "bits_per_event": float(bits_per_event),
        "sparsity": float((out == 0).float().mean()),
    }


def event_camera(
    *,
    out_dir: Path,
    seed: int,
    representations: dict[str, Representation],
    video: ExistingFile | None = None,
    frames: PositiveInt = 90,
    height: PositiveInt = 120,
    width: PositiveInt = 160,
    fps: PositiveFloat = 25.0,
    timestamp_bits: PositiveInt = 32,
    value_bits: PositiveInt = 16,
) -> dict[str, Any]:
    """Run every representation on one clip; returns its data rates and sparsity."""
    # ---- the clip ----------------------------------------------------------------------------
    clip, data = video_or_scene(video, frames, height, width, seed)  # (T, 3, H, W)

    # ---- every representation ----------------------------------------------------------------
    metrics: dict[str, Any] = {**data, "data/size": f"{width}x{height}", "data/fps": fps}
    for name, rep in representations.items():
        with torch.no_grad():
            out = rep(clip.unsqueeze(0))[0]  # (T', C_out, H, W)
        if isinstance(rep, FDR):  # a frame camera: every pixel, 8 bits a channel
            cost = {
                "events_per_s": float("nan"),
                "bits_per_s": out[0].numel() * 8 * fps,
                "bits_per_event": float("nan"),
                "sparsity": float((clip == 0).float().mean()),
            }
        else:
            cost = stream_cost(out, out.shape[0] / fps, timestamp_bits, value_bits)
        metrics.update({f"{name}/{key}": value for key, value in cost.items()})
        log.info("%s: %.3g events/s, %.3g bits/s, sparsity %.3f", name, cost["events_per_s"],
                 cost["bits_per_s"], cost["sparsity"])  # fmt: skip
    return metrics
