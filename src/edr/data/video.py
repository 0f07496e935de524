"""Decoding and writing video files with OpenCV; every failure names the file."""

from __future__ import annotations

import errno
import shutil
from pathlib import Path
from typing import Annotated, Any

import cv2
import numpy as np
import torch

from edr.checks.config import Check, ConfigError, path_problem


class UnreadableVideo(ConfigError):
    """A video file that cannot be decoded (empty, text, corrupt): one line naming it."""


class MissingVideo(UnreadableVideo, FileNotFoundError):
    """A video path with no file behind it (or a link that leads nowhere, or in a loop)."""


def check_video_file(path: str | Path) -> Path:
    """``path`` if it is a file with bytes in it; else :class:`MissingVideo` (nothing there, a
    dangling link, a symlink loop, a folder) or :class:`UnreadableVideo` (0 bytes), naming it."""
    path = Path(path)
    try:
        size = path.stat().st_size
    except OSError as error:  # missing, a dangling link, a symlink loop, a name too long
        raise MissingVideo(f"video not found: {path} ({error.strerror or error})") from None
    if not path.is_file():
        raise MissingVideo(f"video not found: {path} is not a file")
    if size == 0:
        raise UnreadableVideo(f"video {path} is empty (0 bytes): replace or remove it")
    return path


def frame_count(path: str | Path) -> int:
    """The frames a video's container says it holds (0 where it does not say): cheap, no decoding."""
    capture = cv2.VideoCapture(str(path))
    try:
        return max(int(capture.get(cv2.CAP_PROP_FRAME_COUNT)), 0)
    finally:
        capture.release()


def read_video(
    path: str | Path,
    *,
    max_frames: int | None = None,
    size: tuple[int, int] | None = None,
) -> torch.Tensor:
    """Decode a video to (T, 3, H, W) uint8 RGB; ``size=(width, height)`` resizes each frame.

    A file that decodes clearly fewer frames than its container declares (truncated, or
    corrupt part way) is a ``ValueError`` naming it and both counts, not a shorter clip."""
    path = check_video_file(path)
    capture = cv2.VideoCapture(str(path))
    if not capture.isOpened():
        raise UnreadableVideo(f"cannot open video {path}: not a video OpenCV can decode")
    declared = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))  # 0 or less: not stated
    frames = []
    try:
        while max_frames is None or len(frames) < max_frames:
            ok, bgr = capture.read()
            if not ok:
                break
            if size is not None:
                bgr = cv2.resize(bgr, size, interpolation=cv2.INTER_AREA)
            frames.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
    finally:
        capture.release()
    if not frames:
        raise UnreadableVideo(f"video {path} has no decodable frames (corrupt or empty file)")
    wanted = declared if max_frames is None else min(declared, max_frames)
    # Containers' counts can be estimates off by a frame or two; half a file is not that.
    if declared > 0 and len(frames) < 0.95 * wanted - 1:
        raise UnreadableVideo(
            f"video {path} decodes {len(frames)} of the {declared} frames its container declares "
            "(truncated or corrupt part way): replace the file"
        )
    return torch.from_numpy(np.stack(frames)).permute(0, 3, 1, 2).contiguous()  # (T, 3, H, W)


def write_video(path: str | Path, frames: np.ndarray | torch.Tensor, fps: float = 25.0) -> Path:
    """Write (T, 3, H, W) or (T, H, W) uint8 frames as an MJPG .avi (the UCF-101/KTH container)."""
    path = Path(path)
    array = frames.numpy() if isinstance(frames, torch.Tensor) else np.asarray(frames)
    if array.dtype != np.uint8 or array.ndim not in (3, 4) or len(array) == 0:
        raise ValueError(
            f"frames must be non-empty uint8 (T, 3, H, W) or (T, H, W), got {array.shape}"
        )
    if array.ndim == 3:
        array = np.repeat(array[:, None], 3, axis=1)
    t, _, h, w = array.shape
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.partial{path.suffix}")
    writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"MJPG"), fps, (w, h))
    if not writer.isOpened():
        raise ValueError(f"cannot write video {path}")
    try:
        for i in range(t):
            writer.write(
                cv2.cvtColor(np.ascontiguousarray(array[i].transpose(1, 2, 0)), cv2.COLOR_RGB2BGR)
            )
    finally:
        writer.release()
    _check_written(tmp, path)
    tmp.replace(path)
    return path


def _check_written(tmp: Path, path: Path) -> None:
    """OpenCV's writer fails without a word (a full disk leaves an empty or no file): refuse
    such a file, with the disk's free space, before it takes ``path``'s name."""
    size = tmp.stat().st_size if tmp.is_file() else 0
    if size == 0:
        tmp.unlink(missing_ok=True)
        free = shutil.disk_usage(path.parent).free
        raise OSError(
            errno.ENOSPC if free < 2**20 else errno.EIO,
            f"writing the video {path} left an empty file (the disk holding it has "
            f"{free / 2**20:.1f} MiB free: full?); nothing was kept",
        )


def video_problem(path: Any, min_frames: int = 2) -> str | None:
    """What makes ``path`` no video to read, found before decoding it: no file there (a link
    in a loop, a folder), 0 bytes, a file OpenCV cannot open (text, a cut container), or fewer
    than ``min_frames`` frames by its container's count. A video cut part way past its header is
    found as it decodes (``read_video``)."""
    if problem := path_problem(path):
        return problem
    try:
        check_video_file(path)
    except UnreadableVideo as error:
        return f"a video file ({error})"
    count = frame_count(path)
    if count == 0:  # not said: OpenCV could not open the container
        capture = cv2.VideoCapture(str(path))
        opened = capture.isOpened()
        capture.release()
        if not opened:
            return (
                "a video OpenCV can decode (it cannot open this file: corrupt, cut or not a video)"
            )
    if 0 < count < min_frames:
        return f"a video of at least {min_frames} frames (its container holds {count})"
    return None


VideoFile = Annotated[str, Check(video_problem)]  # a video of two frames or more, checked unread
