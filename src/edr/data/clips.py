"""From video files to training clips: decode once, cache on disk, crop like the paper.

The paper's Appendix D: videos resized to 89x67; training clips are random volumes of 60
frames, cropped at a random scale in (1, .875, .75, .66) of the short side and resized to
58x58, flipped at random; testing takes the first 60 frames and 10 crops (4 corners and the
centre, each also flipped) and averages the softmax over them. Split in time (not the paper's
protocol), the same from each video's training part and its test part (:class:`ClipDataset`).
"""

from __future__ import annotations

import hashlib
import zlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Literal

import numpy as np
import torch
import torch.nn.functional as F
from torch.utils.data import Dataset
from tqdm import tqdm

from edr.checks import interrupts
from edr.data.datasets import Video, VideoSet
from edr.data.video import read_video
from edr.store.atomic import atomic_path

PAPER_SCALES = (1.0, 0.875, 0.75, 0.66)
# What a control does to the frames' order (None: nothing; the records' ``data/frame_order``
# words are FRAME_ORDER's): shuffled within each clip once it is cut (the frames stay near one
# another, so the motion statistics of neighbouring frames survive), shuffled within the whole
# video before clips are cut (within each sub-sequence where the video has them), or one frame
# of the clip repeated (appearance alone: no motion at all).
FrameControl = Literal["shuffled_in_clip", "shuffled_in_video", "one_frame"]
FRAME_ORDER = {
    None: "in order",
    "shuffled_in_clip": "shuffled within each clip",
    "shuffled_in_video": "shuffled within the video",
    "one_frame": "one frame repeated",
}


class ArrayCache:
    """Arrays computed once per file and kept as ``.npy`` under ``root/<key>/``.

    An entry is keyed by the file's resolved path, size and modification time (a replaced video
    gets a new entry) and, through ``key``, by the settings that made it. Entries are written
    atomically, so an interrupted run leaves no half file and processes that fill the same cache
    at once all succeed (a loser keeps the winner's entry). ``root=None`` keeps arrays in memory.
    """

    def __init__(self, root: str | Path | None, key: str) -> None:
        self.dir = Path(root).resolve() / key if root is not None else None
        self._memory: dict[Path, np.ndarray] = {}

    def _file(self, path: Path) -> Path:
        stat = Path(path).stat()
        identity = f"{Path(path).resolve()}|{stat.st_size}|{stat.st_mtime_ns}"
        return (
            self.dir / f"{Path(path).stem}_{hashlib.sha1(identity.encode()).hexdigest()[:12]}.npy"
        )

    def get(self, path: Path, compute: Callable[[Path], np.ndarray]) -> np.ndarray:
        if path in self._memory:
            return self._memory[path]
        if self.dir is None:
            array = compute(path)
        else:
            file = self._file(path)
            if not file.is_file():
                array = compute(path)
                if not file.is_file():  # another process may have finished it meanwhile
                    with atomic_path(file) as tmp:
                        np.save(tmp, array)
            array = np.load(file, mmap_mode="r")
        self._memory[path] = array
        return array

    def fill(self, paths: Sequence[Path], compute: Callable[[Path], np.ndarray], desc: str) -> None:
        """Compute every missing entry, with a progress bar."""
        for path in tqdm(paths, desc=desc, unit="video", leave=False):
            interrupts.raise_if_stopping()
            self.get(path, compute)


class VideoSource:
    """Decoded videos as (T, C, H, W) uint8 at ``size`` (width, height), gray (C=1) or RGB."""

    def __init__(
        self,
        cache_dir: str | Path | None,
        size: tuple[int, int] = (89, 67),
        gray: bool = False,
        max_frames: int | None = None,
    ) -> None:
        self.size, self.gray, self.max_frames = (int(size[0]), int(size[1])), gray, max_frames
        key = f"frames_{self.size[0]}x{self.size[1]}_{'gray' if gray else 'rgb'}_{max_frames or 'all'}"
        self.cache = ArrayCache(cache_dir, key)

    @property
    def channels(self) -> int:
        return 1 if self.gray else 3

    def decode(self, path: Path) -> np.ndarray:
        frames = read_video(path, max_frames=self.max_frames, size=self.size)  # (T, 3, H, W)
        if self.gray:
            frames = frames.float().mean(1, keepdim=True).round().to(torch.uint8)
        return frames.numpy()

    def __call__(self, path: Path) -> np.ndarray:
        return self.cache.get(path, self.decode)


class PrecomputedSource:
    """A representation of each whole decoded video, computed once (the paper's flows).

    Returns (T', C_out, H, W) float32; keyed by the representation's ``cache_key()``.
    """

    def __init__(
        self, frames: VideoSource, representation: torch.nn.Module, cache_dir: str | Path | None
    ) -> None:
        self.frames, self.representation = frames, representation
        key = f"{frames.cache.dir.name if frames.cache.dir else 'frames'}_{representation.cache_key()}"
        self.cache = ArrayCache(cache_dir, key)

    def compute(self, path: Path) -> np.ndarray:
        video = torch.from_numpy(np.array(self.frames(path))).unsqueeze(0)  # (1, T, C, H, W)
        with torch.no_grad():
            return self.representation(video)[0].numpy().astype(np.float32)

    def __call__(self, path: Path) -> np.ndarray:
        return self.cache.get(path, self.compute)


def take_frames(video: torch.Tensor, start: int, frames: int) -> torch.Tensor:
    """``frames`` frames from ``start``; a short video holds its last frame."""
    clip = video[start : start + frames]
    if clip.shape[0] < frames:
        clip = torch.cat([clip, clip[-1:].expand(frames - clip.shape[0], *clip.shape[1:])])
    return clip


def resize_clip(clip: torch.Tensor, size: int) -> torch.Tensor:
    """(T, C, h, w) -> (T, C, size, size) float32, bilinear."""
    clip = clip.float()
    if clip.shape[-2:] == (size, size):
        return clip
    return F.interpolate(clip, size=(size, size), mode="bilinear", align_corners=False)


def _flip(clip: torch.Tensor, negate: Sequence[int]) -> torch.Tensor:
    """Mirror left-right; channels in ``negate`` (a flow's dx) change sign."""
    clip = clip.flip(-1)
    if negate:
        clip[:, list(negate)] = -clip[:, list(negate)]
    return clip


def random_clip(
    video: torch.Tensor,
    frames: int,
    crop: int,
    scales: Sequence[float] = PAPER_SCALES,
    negate: Sequence[int] = (),
) -> torch.Tensor:
    """(T, C, H, W) -> one training clip (frames, C, crop, crop): random time, scale, place, flip."""
    t, _, h, w = video.shape
    start = int(torch.randint(0, max(t - frames, 0) + 1, ()))
    side = max(1, round(float(scales[int(torch.randint(0, len(scales), ()))]) * min(h, w)))
    y = int(torch.randint(0, h - side + 1, ()))
    x = int(torch.randint(0, w - side + 1, ()))
    clip = resize_clip(take_frames(video, start, frames)[:, :, y : y + side, x : x + side], crop)
    return _flip(clip, negate) if bool(torch.randint(0, 2, ())) else clip


def ten_crops(
    video: torch.Tensor, frames: int, crop: int, negate: Sequence[int] = ()
) -> torch.Tensor:
    """(T, C, H, W) -> (10, frames, C, crop, crop): the first frames, 4 corners + centre, and flips."""
    clip = take_frames(video, 0, frames)
    h, w = clip.shape[-2:]
    side = min(crop, h, w)
    corners = [
        (0, 0),
        (0, w - side),
        (h - side, 0),
        (h - side, w - side),
        ((h - side) // 2, (w - side) // 2),
    ]
    crops = [resize_clip(clip[:, :, y : y + side, x : x + side], crop) for y, x in corners]
    crops += [_flip(c, negate) for c in crops]
    return torch.stack(crops)


class ClipDataset(Dataset):
    """(clip, label) pairs: training clips (frames, C, crop, crop) or test stacks (10, ...).

    One item per video: a training clip drawn at random in time, or the test stack of its first
    frames. Split in time (``videos.time_split``), a training clip is drawn from the video's
    training part only, and its test part gives consecutive test stacks, one item each. A video
    with sub-sequences (``Video.segments``, KTH's 00sequences.txt) gives its training clips from
    within one of them (drawn in proportion to the clips each holds) and a test stack at the
    start of each that holds a clip, one item each; a video none of whose sub-sequences holds a
    clip is used whole.
    ``control`` (:data:`FrameControl`): ``shuffled_in_clip``, each clip's frames in a random
    order (a new one per training draw, a fixed one per test item; neighbouring frames stay
    neighbours in time, so motion statistics survive); ``shuffled_in_video``, each video's
    frames in one fixed random order (within each stretch clips come from) before any clip is
    cut; ``one_frame``, one frame of each clip repeated over all of its frames (a random one per
    training draw, a fixed one per test item): appearance alone, no motion.
    """

    def __init__(
        self,
        videos: VideoSet,
        source: Callable[[Path], np.ndarray],
        *,
        frames: int,
        crop: int,
        train: bool,
        scales: Sequence[float] = PAPER_SCALES,
        negate: Sequence[int] = (),
        control: FrameControl | None = None,
    ) -> None:
        self.videos, self.source = videos, source
        self.frames, self.crop, self.train = frames, crop, train
        self.scales, self.negate = tuple(scales), tuple(negate)
        self.control = control
        self._orders: dict[int, np.ndarray] = {}  # shuffled_in_video: each video's frame order
        self.items = self._items()  # (video index, first frame of a test stack or None)

    def _windows(self, video: Video, length: int) -> list[range]:
        """The stretches of ``video`` (``length`` frames) that this set's clips may come from."""
        if self.videos.time_split is not None:
            return [self.videos.time_split.window(length, self.frames, str(video.path))]
        parts = [range(a, min(b, length)) for a, b in video.segments]
        return [p for p in parts if len(p) >= self.frames] or [range(length)]

    def _items(self) -> list[tuple[int, int | None]]:
        if self.train or (self.videos.time_split is None and not self._segmented()):
            return [(i, None) for i in range(len(self.videos))]
        items = []
        for i, video in enumerate(self.videos.videos):
            for part in self._windows(video, len(self.source(video.path))):
                step = self.frames if self.videos.time_split is not None else len(part)
                items += [(i, s) for s in range(part.start, part.stop - self.frames + 1, step)]
        return items

    def _segmented(self) -> bool:
        return any(video.segments for video in self.videos.videos)

    def _training_window(self, video: Video, length: int) -> range:
        """One stretch to draw a training clip from: of several, each with the odds of the
        clips it holds."""
        parts = self._windows(video, length)
        if len(parts) == 1:
            return parts[0]
        weights = torch.tensor([max(len(p) - self.frames + 1, 1) for p in parts], dtype=torch.float)
        return parts[int(torch.multinomial(weights, 1))]

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, index: int) -> tuple[torch.Tensor, int]:
        i, start = self.items[index]
        video = self.videos.videos[i]
        array = self.source(video.path)  # (T, C, H, W), memory-mapped where cached on disk
        if start is not None:
            part = range(start, start + self.frames)
        elif self.train:
            part = self._training_window(video, len(array))
        else:
            part = range(len(array))
        if self.control == "shuffled_in_video":
            frames = torch.from_numpy(np.array(array[self._video_order(i, len(array))[part]]))
        else:
            frames = torch.from_numpy(np.array(array[part.start : part.stop]))
        if self.train:
            clip = random_clip(frames, self.frames, self.crop, self.scales, self.negate)
            return self._in_clip(clip, 0, None), video.label
        # (10, frames, C, crop, crop)
        crops = ten_crops(frames, self.frames, self.crop, self.negate)
        return self._in_clip(crops, 1, torch.Generator().manual_seed(index)), video.label

    def _video_order(self, i: int, length: int) -> np.ndarray:
        """Video ``i``'s frames (``length`` of them) in one random order, fixed by its file name:
        frames move only within the stretch they lie in (a sub-sequence), so a clip still shows
        the action, from moments far apart."""
        if i not in self._orders:
            video = self.videos.videos[i]
            rng = np.random.default_rng(zlib.crc32(video.path.name.encode()))
            order = np.arange(length)
            for part in self._windows(video, length):
                order[part.start : part.stop] = rng.permutation(order[part.start : part.stop])
            self._orders[i] = order
        return self._orders[i]

    def _in_clip(
        self, clip: torch.Tensor, dim: int, generator: torch.Generator | None
    ) -> torch.Tensor:
        """``clip`` with its frames (along ``dim``) in a random order, or one of them repeated,
        as the control asks (no draw from the generator without one)."""
        n = clip.shape[dim]
        if self.control == "shuffled_in_clip":
            return clip.index_select(dim, torch.randperm(n, generator=generator))
        if self.control == "one_frame":
            return clip.index_select(dim, torch.randint(n, (1,), generator=generator).expand(n))
        return clip
