"""Event camera vs frame camera (the paper's Table 3): what each representation of the same
clip costs to transmit, and how sparse it is.

For every representation: ``events_per_s`` (the number of events: for outputs that count events
— the DVS simulator, a hard-thresholded EDR — their sum, for graded outputs — a soft EDR — the
non-zero entries), ``bits_per_s`` and ``sparsity`` (the fraction of zero outputs). Events are
priced as an address-event stream: each carries its address (x, y and channel, i.e. polarity
and timescale) and a timestamp, and a graded event also its value. Frames (``FDR``) are priced
as a frame camera sends them: every pixel of every frame at 8 bits per channel.

With ``events=<file>`` (any format :mod:`edr.data.events` reads), a real camera's recording
is measured too, as the row ``camera``: its events/s; its bits/s in the paper's model (address
+ timestamp, as above) and in the file's own bytes per event (``file_bits_per_s``); its events
per pixel per frame interval and its sparsity, binned at ``fps`` (at most one frame a µs, the
finest time an event file holds). The file is streamed in chunks: memory stays bounded whatever
its length; where it states no sensor, the sensor is the span of all its events.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import torch

from edr.checks.config import ExistingFile, PositiveInt, Range
from edr.data.events import (
    check_writable,
    detect_format,
    iter_recording,
    recording_sensor_size,
    sensor_of,
    write_recording,
)
from edr.data.events.checks import MAX_SIDE
from edr.data.synthetic import FrameSide, video_or_scene
from edr.representations import FDR, DVSCamera, Representation
from edr.representations.base import check_enough_frames, to_gray
from edr.representations.dvs import EVENT_DTYPE

log = logging.getLogger(__name__)

MAX_FPS = 1e6  # one frame a µs: event files hold no finer time
FrameRate = Annotated[float, Range(0, MAX_FPS, open=True)]  # frames per second
# (polarity, y, x) bins of the largest sensor read: a pixel's key while a recording that states
# no sensor is still being read (its sensor is the span of all its events)
PIXEL_BINS = 2 * MAX_SIDE * MAX_SIDE


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
        "events_per_pixel_frame": events / (out.shape[0] * out.shape[-2] * out.shape[-1]),
        "sparsity": float((out == 0).float().mean()),
    }


def events_path(out_dir: Path, name: str, suffix: str) -> Path:
    """Where ``save_events`` writes representation ``name``'s events: ``<name>_events<suffix>``."""
    return out_dir / f"{name}_events{suffix}"


def events_of_output(
    rep: Representation, clip: torch.Tensor, out: torch.Tensor, fps: float
) -> np.ndarray | None:
    """The events a representation's output stands for (EVENT_DTYPE), or None where it holds
    no ON/OFF events: the DVS simulator's own (timed within the frame interval), or a counting
    [ON, OFF] output's (a hard EDR: each count an event at its frame's time)."""
    if isinstance(rep, DVSCamera):
        return rep.simulator.simulate(to_gray(clip.unsqueeze(0), channel_dim=2)[0, :, 0].numpy())
    counts = out.detach().cpu()  # (T', 2, H, W)
    if isinstance(rep, FDR) or counts.shape[1] != 2 or not torch.equal(counts, counts.round()):
        return None
    k, channel, y, x = (c.numpy() for c in torch.nonzero(counts > 0, as_tuple=True))
    repeats = counts[counts > 0].long().numpy()
    listed = np.zeros(int(repeats.sum()), EVENT_DTYPE)
    first = clip.shape[0] - counts.shape[0]  # frames the output starts after
    listed["t"] = np.repeat(np.floor((k + first) * 1e6 / fps).astype(np.int64), repeats)
    listed["x"], listed["y"] = np.repeat(x, repeats), np.repeat(y, repeats)
    listed["p"] = np.repeat(1 - channel, repeats)  # [ON, OFF] -> p 1 ON
    return np.sort(listed, order="t", kind="stable")


def _new_bins(frame: np.ndarray, pixel: np.ndarray, carried: np.ndarray) -> tuple[int, np.ndarray]:
    """One chunk's (frame interval, pixel) bins: how many are new, and the pixels of its last
    interval. ``frame`` (N,) its events' intervals (sorted), ``pixel`` (N,) their keys below
    PIXEL_BINS, ``carried`` the pixels of its first interval seen in the chunk before."""
    step = np.concatenate([[0], np.cumsum(frame[1:] != frame[:-1])])  # (N,) < 2^20: no overflow
    keys = np.unique(np.concatenate([carried, step * PIXEL_BINS + pixel]))
    last = int(step[-1]) * PIXEL_BINS
    return len(keys) - len(carried), keys[keys >= last] - last


def recording_cost(path: str | Path, fps: float, timestamp_bits: int) -> dict[str, Any]:
    """A real recording's rates (``stream_cost``'s, plus the file's own bits per event) and its
    ``data/*`` entries. Sparsity: the share of (frame interval, polarity, y, x) bins without an
    event, counted chunk by chunk (a bin that spans two chunks is carried over); the sensor: the
    one the file states, else the span of all its chunks' events."""
    path = Path(path)
    frame_us = 1e6 / fps
    count, first, last, filled = 0, 0, 0, 0
    carry, carry_frame = np.zeros(0, np.int64), -1.0  # the last frame interval's pixels seen
    bounding = []  # each chunk's events of the largest x and y
    for chunk in iter_recording(path):
        if not len(chunk):
            continue
        if not count:
            first = int(chunk["t"][0])
        frame = (chunk["t"] - first) // frame_us  # (N,) float: never cast, however many
        pixel = (chunk["p"].astype(np.int64) * MAX_SIDE + chunk["y"]) * MAX_SIDE + chunk["x"]
        new, carry = _new_bins(frame, pixel, carry if frame[0] == carry_frame else carry[:0])
        filled, carry_frame = filled + new, frame[-1]
        bounding.append(chunk[[int(chunk["x"].argmax()), int(chunk["y"].argmax())]])
        count, last = count + len(chunk), int(chunk["t"][-1])
    height, width = sensor_of(path, np.concatenate(bounding))
    seconds = (last - first + 1) / 1e6
    frames = max(1, int(np.ceil((last - first + 1) / frame_us)))
    bits_per_event = math.ceil(math.log2(2 * height * width)) + timestamp_bits
    file_bits = 8 * path.stat().st_size / count
    return {
        "camera/events_per_s": count / seconds,
        "camera/bits_per_s": count * bits_per_event / seconds,
        "camera/bits_per_event": float(bits_per_event),
        "camera/file_bits_per_s": count * file_bits / seconds,
        "camera/file_bits_per_event": file_bits,
        "camera/events_per_pixel_frame": count / (frames * height * width),
        "camera/sparsity": 1 - filled / (frames * 2 * height * width),
        "data/events_file": path.name,
        "data/events_format": detect_format(path).name,
        "data/events_sensor": f"{width}x{height}",
        "data/events_sensor_stated": recording_sensor_size(path) is not None,
        "data/events_count": count,
        "data/events_seconds": seconds,
    }


def event_camera(
    *,
    out_dir: Path,
    seed: int,
    representations: dict[str, Representation],
    video: ExistingFile | None = None,
    frames: PositiveInt = 90,
    height: FrameSide = 120,
    width: FrameSide = 160,
    fps: FrameRate = 25.0,
    timestamp_bits: PositiveInt = 32,
    value_bits: PositiveInt = 16,
    events: ExistingFile | None = None,
    save_events: Literal[".raw", ".aedat4", ".aedat", ".npz"] | None = None,
) -> dict[str, Any]:
    """Run every representation on one clip, and measure a real recording (``events``) beside
    them; returns their data rates and sparsity. ``save_events`` (a format's suffix) writes the
    events of the DVS simulator and of a hard-threshold EDR into the run folder,
    ``<name>_events<suffix>``, for other event tools."""
    check_enough_frames(frames, representations)
    # said now, not after the work: a sensor the format cannot hold, a folder where a file goes
    for name in representations if save_events else ():
        check_writable(events_path(out_dir, name, save_events), (height, width))
    # ---- a real camera's recording, checked before the clip ------------------------------------
    camera = recording_cost(events, fps, timestamp_bits) if events else {}

    # ---- the clip ----------------------------------------------------------------------------
    widest = max((rep.out_channels(3) for rep in representations.values()), default=0)
    clip, data = video_or_scene(video, frames, height, width, seed, widest)  # (T, 3, H, W)

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
                "events_per_pixel_frame": float("nan"),
                "sparsity": float((clip == 0).float().mean()),
            }
        else:
            cost = stream_cost(out, out.shape[0] / fps, timestamp_bits, value_bits)
        metrics.update({f"{name}/{key}": value for key, value in cost.items()})
        if save_events and (listed := events_of_output(rep, clip, out, fps)) is not None:
            written = write_recording(
                events_path(out_dir, name, save_events), listed, (height, width)
            )
            log.info("%s: %d events written to %s", name, len(listed), written)
        log.info("%s: %.3g events/s, %.3g bits/s, sparsity %.3f", name, cost["events_per_s"],
                 cost["bits_per_s"], cost["sparsity"])  # fmt: skip
    if camera:
        log.info("camera (%s, %s): %.3g events/s, %.3g bits/s (file: %.3g)",
                 camera["data/events_file"], camera["data/events_sensor"],
                 camera["camera/events_per_s"], camera["camera/bits_per_s"],
                 camera["camera/file_bits_per_s"])  # fmt: skip
    return {**metrics, **camera}
