"""Generated video that needs no download: the demo's default scene."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Any

import cv2
import numpy as np
import torch

from edr.checks.config import PositiveInt, Range, check_memory
from edr.data.fingerprint import files_fingerprint
from edr.data.video import frame_count, read_video, write_video
from edr.store.atomic import publish_dir

FrameSide = Annotated[int, Range(16)]  # a frame's side: the generated scene draws at least 16


def _texture(rng: np.random.Generator, height: int, width: int, blur: float) -> np.ndarray:
    noise = cv2.GaussianBlur(rng.random((height, width)).astype(np.float32), (0, 0), blur)
    return (noise - noise.min()) / max(float(noise.max() - noise.min()), 1e-6)  # 0..1


def synthetic_scene(
    frames: int = 48, height: int = 120, width: int = 160, seed: int = 0
) -> torch.Tensor:
    """A scene with the cases a temporal representation must tell apart, (T, 3, H, W) uint8.

    A textured background that stays still (no events expected), a bright square moving right
    (ON at its leading edge, OFF at its trailing edge), a dark disk moving down, and a patch
    whose brightness oscillates in place (ON and OFF in turn, no motion).
    """
    if frames < 1 or height < 16 or width < 16:
        raise ValueError(
            f"need frames >= 1 and a frame of at least 16x16, got {frames}x{height}x{width}"
        )
    rng = np.random.default_rng(seed)
    background = 70 + 60 * _texture(rng, height, width, blur=max(height, width) / 40)
    tint = np.array([1.0, 0.9, 0.8], np.float32)
    side = max(4, height // 6)
    radius = max(3, height // 10)
    yy, xx = np.mgrid[0:height, 0:width]
    out = np.empty((frames, 3, height, width), np.uint8)
    for t in range(frames):
        phase = t / max(frames - 1, 1)
        img = background.copy()
        x0 = int(phase * (width - side))
        y0 = height // 5
        img[y0 : y0 + side, x0 : x0 + side] = 220.0
        cy, cx = int(radius + phase * (height - 2 * radius - 1)), (2 * width) // 3
        img[(yy - cy) ** 2 + (xx - cx) ** 2 <= radius**2] = 25.0
        ph, pw = height - height // 4, width // 8
        img[ph : ph + side // 2, pw : pw + side // 2] = 128 + 90 * np.sin(2 * np.pi * t / 12)
        rgb = np.clip(img[None] * tint[:, None, None], 0, 255)
        out[t] = rgb.astype(np.uint8)
    return torch.from_numpy(out)


def video_or_scene(
    video: str | None, frames: int, height: int, width: int, seed: int, out_channels: int = 0
) -> tuple[torch.Tensor, dict[str, Any]]:
    """(clip (T, 3, H, W) uint8, its ``data/*`` entries for the run record): ``video`` read and
    resized to ``width`` x ``height``, or, without one, the generated scene drawn from ``seed``.
    Refused first if the clip, and with ``out_channels`` (the widest representation the caller
    computes of it whole) its float32 copy and that output too, cannot fit in memory: a clip
    too large for a representation would otherwise decode, then fail or swap in an uninterruptible
    kernel call."""
    per_pixel = 3 + (4 * 3 + 4 * out_channels if out_channels else 0)  # bytes a pixel-frame
    held = min(frames, frame_count(video) or 1) if video else frames  # a video may hold fewer
    check_memory(
        f"task.frames={frames}, task.height={height}, task.width={width}",
        f"a clip of {held} frames at {width}x{height} (RGB, uint8)"
        + (f", its float32 copy and a {out_channels}-channel float32 representation of it"
           if out_channels else ""),
        held * height * width * per_pixel,
    )  # fmt: skip
    if video:
        clip = read_video(video, max_frames=frames, size=(width, height))
        label, fingerprint = str(video), files_fingerprint([Path(video)], Path(video).parent)
    else:
        clip = synthetic_scene(frames, height, width, seed=seed)
        label, fingerprint = "generated scene (the seed draws it)", "generated"
    return clip, {
        "data/source": "real video" if video else "generated",
        "data/video": label,
        "data/fingerprint": fingerprint,
        "data/frames": clip.shape[0],
    }


# ---- generated action videos in the UCF-101 and KTH layouts ----------------------------------
KTH_ACTIONS = ("boxing", "handclapping", "handwaving", "jogging", "running", "walking")
# The same six motions under names no one will mistake for real UCF-101 classes.
SYNTHETIC_UCF_CLASSES = (
    "SynthBoxing",
    "SynthClapping",
    "SynthWaving",
    "SynthJogging",
    "SynthRunning",
    "SynthWalking",
)
_MOTION = dict(zip(SYNTHETIC_UCF_CLASSES, KTH_ACTIONS, strict=True))


def action_video(
    action: str, rng: np.random.Generator, frames: int, height: int, width: int
) -> np.ndarray:
    """(T, H, W) uint8 gray video of one of the six KTH motions, as a blob figure.

    Every class shares the figure and the background statistics; they differ by motion only:
    walking, jogging and running translate the body at 1, 2 and 3.5 px/frame (direction random),
    boxing jabs a "fist" sideways, handclapping brings two "hands" together and apart,
    handwaving moves a "hand" up and down — each with its own rhythm.
    """
    if action not in KTH_ACTIONS:
        raise ValueError(f"unknown action {action!r}; expected one of {KTH_ACTIONS}")
    scale = height / 120
    background = 90 + 70 * _texture(rng, height, width, blur=4 * scale)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    body_h, body_w = 40 * scale, 12 * scale
    limb = 5 * scale
    cy = height * rng.uniform(0.45, 0.6)
    direction = rng.choice([-1.0, 1.0])
    speed = {"walking": 1.0, "jogging": 2.0, "running": 3.5}.get(action, 0.0) * scale
    x_start = (
        width * (0.15 if direction > 0 else 0.85) if speed else width * rng.uniform(0.35, 0.65)
    )
    period = {"boxing": 6, "handclapping": 8, "handwaving": 12}.get(action, 10) * rng.uniform(
        0.85, 1.15
    )
    phase0 = rng.uniform(0, 2 * np.pi)
    body_level, limb_level = rng.uniform(25, 60), rng.uniform(190, 240)
    out = np.empty((frames, height, width), np.uint8)
    for t in range(frames):
        img = background.copy()
        cx = x_start + direction * speed * t
        if speed:
            cx = (cx - 0.1 * width) % (0.8 * width) + 0.1 * width  # wrap inside the frame
        bob = 2 * scale * np.sin(2 * np.pi * t / 8) if speed else 0.0
        body = (np.abs(xx - cx) < body_w / 2) & (np.abs(yy - cy - bob) < body_h / 2)
        img[body] = body_level
        phase = phase0 + 2 * np.pi * t / period
        hands = []
        if action == "boxing":
            hands = [
                (
                    cx + direction * (body_w / 2 + limb + 10 * scale * max(np.sin(phase), 0)),
                    cy - 8 * scale,
                )
            ]
        elif action == "handclapping":
            gap = limb + 8 * scale * (1 + np.sin(phase)) / 2
            hands = [(cx - gap, cy - 10 * scale), (cx + gap, cy - 10 * scale)]
        elif action == "handwaving":
            hands = [(cx + body_w, cy - body_h / 2 - 10 * scale * (1 + np.sin(phase)) / 2)]
        else:  # legs swing with the gait
            swing = 4 * scale * np.sin(phase * speed)
            hands = [(cx - swing, cy + body_h / 2 + limb), (cx + swing, cy + body_h / 2 + limb)]
        for hx, hy in hands:
            img[(xx - hx) ** 2 + (yy - hy) ** 2 <= limb**2] = limb_level
        noise = rng.normal(0, 3, img.shape)
        out[t] = np.clip(img + noise, 0, 255).astype(np.uint8)
    return out


def write_synthetic_kth(
    root: str | Path,
    *,
    persons: PositiveInt = 25,
    scenarios: PositiveInt = 4,
    frames: PositiveInt = 90,
    height: PositiveInt = 120,
    width: PositiveInt = 160,
    seed: int = 0,
) -> Path:
    """Generate the six KTH actions in KTH's layout: ``root/<action>/personXX_<action>_dY_uncomp.avi``.

    Gray 160x120 video at 25 fps, like KTH's; an existing ``root`` is left as it is.
    """

    def write(tmp: Path) -> None:
        rng = np.random.default_rng(seed)
        for action in KTH_ACTIONS:
            for person in range(1, persons + 1):
                for scenario in range(1, scenarios + 1):
                    video = action_video(action, rng, frames, height, width)
                    name = f"person{person:02d}_{action}_d{scenario}_uncomp.avi"
                    write_video(tmp / action / name, video)

    return publish_dir(root, write)


def write_synthetic_ucf101(
    root: str | Path,
    *,
    groups: PositiveInt = 25,
    clips: PositiveInt = 2,
    frames: PositiveInt = 60,
    height: PositiveInt = 240,
    width: PositiveInt = 320,
    seed: int = 0,
) -> Path:
    """Generate six motion classes in UCF-101's layout, with its three official splits.

    ``root/<Class>/v_<Class>_gXX_cYY.avi`` (RGB) and ``root/ucfTrainTestlist/`` with
    ``classInd.txt``, ``trainlist0{1,2,3}.txt`` and ``testlist0{1,2,3}.txt``: split k tests on
    groups 7(k-1)+1 .. 7k, as the official lists do. Class names start with "Synth".
    """

    def write(tmp: Path) -> None:
        rng = np.random.default_rng(seed)
        entries = []
        tint = np.array([1.0, 0.85, 0.7], np.float32)[:, None, None]
        for label, name in enumerate(SYNTHETIC_UCF_CLASSES, start=1):
            for group in range(1, groups + 1):
                for clip in range(1, clips + 1):
                    gray = action_video(_MOTION[name], rng, frames, height, width)
                    rgb = np.clip(gray[:, None].astype(np.float32) * tint, 0, 255).astype(np.uint8)
                    rel = ucf101_name(name, group, clip)
                    write_video(tmp / rel, rgb)
                    entries.append((rel, label, group))
        write_ucf101_lists(tmp, SYNTHETIC_UCF_CLASSES, entries)

    return publish_dir(root, write)


def ucf101_name(name: str, group: int, clip: int) -> str:
    """A clip's path in UCF-101's layout: ``<Class>/v_<Class>_gXX_cYY.avi``."""
    return f"{name}/v_{name}_g{group:02d}_c{clip:02d}.avi"


def write_ucf101_lists(
    root: Path, classes: Sequence[str], entries: Sequence[tuple[str, int, int]]
) -> None:
    """``root/ucfTrainTestlist/``: ``classInd.txt`` and the three official splits of the clips
    ``entries`` ((path, 1-based label, group)); split k tests on groups 7(k-1)+1 .. 7k."""
    lists = root / "ucfTrainTestlist"
    lists.mkdir(parents=True, exist_ok=True)
    (lists / "classInd.txt").write_text(
        "".join(f"{i} {name}\n" for i, name in enumerate(classes, start=1))
    )
    for split in (1, 2, 3):
        test_groups = range(7 * (split - 1) + 1, 7 * split + 1)
        train = [f"{rel} {label}\n" for rel, label, g in entries if g not in test_groups]
        test = [f"{rel}\n" for rel, _, g in entries if g in test_groups]
        (lists / f"trainlist0{split}.txt").write_text("".join(train))
        (lists / f"testlist0{split}.txt").write_text("".join(test))
