"""The representation demo: every representation on one video, drawn side by side.

Writes ``representations.png`` (one frame of each, like the paper's Figure 3a) and
``pixel_response.png`` (one pixel's intensity and each representation's channels over time,
like Figure 3b) into the run directory.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Annotated, Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import torch
from tqdm import tqdm

from edr.checks.config import ConfigError, Range
from edr.data.synthetic import FrameSide, video_or_scene
from edr.data.video import VideoFile
from edr.representations import Representation
from edr.representations.base import check_enough_frames
from edr.store.atomic import save_figure

log = logging.getLogger(__name__)


def representation_demo(
    *,
    out_dir: Path,
    seed: int,
    representations: dict[str, Representation],
    video: VideoFile | None = None,
    frames: Annotated[int, Range(2)] = 48,  # the demo draws a change: two frames at least
    height: FrameSide = 120,
    width: FrameSide = 160,
    show_frame: int | None = None,
    pixel: tuple[int, int] | None = None,
) -> dict[str, Any]:
    """Run each representation on the clip and draw them; returns timings and figure paths."""
    check_enough_frames(frames, representations)
    if pixel is not None and not (0 <= pixel[0] < height and 0 <= pixel[1] < width):
        raise ConfigError(
            f"task.pixel={list(pixel)}: expected (y, x) inside the {height}x{width} frame"
        )
    if show_frame is not None and not 0 <= show_frame < frames:
        raise ConfigError(f"task.show_frame={show_frame}: expected 0 to {frames - 1}")
    # ---- the clip ----------------------------------------------------------------------------
    widest = max((rep.out_channels(3) for rep in representations.values()), default=0)
    clip, data = video_or_scene(video, frames, height, width, seed, widest)  # (T, 3, H, W)
    source = data["data/video"] if video else f"the generated scene of seed {seed}"
    t_count = clip.shape[0]
    if t_count < 2:  # a container that did not say its count: known once decoded
        raise ConfigError(
            f"task.video={video}: expected a video of at least 2 frames, which the demo draws a "
            f"change between; it decodes {t_count}"
        )
    gray = clip.float().mean(1)  # (T, H, W)
    if pixel is None:
        flat = int(gray.std(0).argmax())
        pixel = (flat // clip.shape[3], flat % clip.shape[3])
    y, x = int(pixel[0]), int(pixel[1])
    shown = t_count // 2 if show_frame is None else int(show_frame)

    # ---- every representation ----------------------------------------------------------------
    outputs: dict[str, torch.Tensor] = {}
    metrics: dict[str, Any] = dict(data)
    for name, rep in (bar := tqdm(representations.items(), desc="representations", unit="rep")):
        bar.set_postfix_str(name)
        start = time.perf_counter()
        with torch.no_grad():
            outputs[name] = rep(clip.unsqueeze(0))[0]  # (T', C_out, H, W)
        seconds = time.perf_counter() - start
        metrics[f"fps/{name}"] = round(t_count / seconds, 1)

    picture_path = _draw_frames(clip, outputs, representations, shown, (y, x), source, out_dir)
    response_path = _draw_pixel(gray, outputs, (y, x), out_dir)
    log.info("figures: %s, %s", picture_path, response_path)
    # files of the run, named from its folder
    metrics.update(
        {
            "figure/representations": str(picture_path.relative_to(out_dir)),
            "figure/pixel": str(response_path.relative_to(out_dir)),
        }
    )
    return metrics


def _draw_frames(
    clip: torch.Tensor, outputs: dict[str, torch.Tensor],
    representations: dict[str, Representation], shown: int, pixel: tuple[int, int], source: str,
    out_dir: Path,
) -> Path:  # fmt: skip
    """Figure 3a: frame ``shown`` of ``clip`` (T, 3, H, W) and each output there, the pixel
    marked; the figure's path."""
    t_count = clip.shape[0]
    panels = [("video", clip[shown].permute(1, 2, 0).numpy() / 255.0)]
    for name, out in outputs.items():
        # Outputs of T-1 frames describe the step into frame t at index t-1.
        index = min(max(shown - (t_count - out.shape[0]), 0), out.shape[0] - 1)
        panels.append((name, representations[name].preview(out[index])))
    fig, axes = plt.subplots(1, len(panels), figsize=(2.4 * len(panels), 2.4))
    for ax, (title, picture) in zip(axes, panels, strict=True):
        ax.imshow(picture.clip(0, 1))
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    axes[0].plot([pixel[1]], [pixel[0]], "c+", markersize=10)
    fig.suptitle(f"frame {shown} of {source}", fontsize=9)
    fig.tight_layout()
    path = out_dir / "representations.png"
    save_figure(fig, path, dpi=120)
    return path


def _draw_pixel(
    gray: torch.Tensor, outputs: dict[str, torch.Tensor], pixel: tuple[int, int], out_dir: Path
) -> Path:
    """Figure 3b: one pixel over time, its intensity (``gray``: (T, H, W)) above each output's
    channels (the first 6); the figure's path."""
    y, x = pixel
    t_count = gray.shape[0]
    fig, axes = plt.subplots(
        len(outputs) + 1, 1, figsize=(7, 1.3 * (len(outputs) + 1)), sharex=True
    )
    axes[0].plot(range(t_count), gray[:, y, x].numpy(), "k")
    axes[0].set_ylabel("intensity", fontsize=8)
    for ax, (name, out) in zip(axes[1:], outputs.items(), strict=True):
        steps = range(t_count - out.shape[0], t_count)
        for c in range(min(out.shape[1], 6)):
            ax.plot(steps, out[:, c, y, x].numpy(), label=f"ch{c}")
        ax.set_ylabel(name, fontsize=8)
        ax.legend(fontsize=6, loc="upper right", ncol=6)
    axes[-1].set_xlabel("frame")
    fig.suptitle(f"pixel (y={y}, x={x})", fontsize=9)
    fig.tight_layout()
    path = out_dir / "pixel_response.png"
    save_figure(fig, path, dpi=120)
    return path
