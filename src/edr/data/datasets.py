"""The video lists of UCF-101 and KTH, read from their official on-disk layouts.

UCF-101::

    <root>/<ClassName>/v_<ClassName>_gXX_cYY.avi
    <root>/ucfTrainTestlist/classInd.txt          "1 ApplyEyeMakeup" per line
    <root>/ucfTrainTestlist/trainlist0{1,2,3}.txt "ApplyEyeMakeup/v_ApplyEyeMakeup_g08_c01.avi 1"
    <root>/ucfTrainTestlist/testlist0{1,2,3}.txt  "ApplyEyeMakeup/v_ApplyEyeMakeup_g01_c01.avi"

(``ucfTrainTestlist/`` may also sit beside ``<root>``, where the official zip unpacks it.)

KTH::

    <root>/<action>/personXX_<action>_dY_uncomp.avi   6 actions, persons 01-25, scenarios d1-d4
    00sequences.txt (optional, any path)              each video's four sub-sequences

Either set can also be split in time (``protocol="time"``, not the paper's protocol): every
video serves both, its first part for training and its last part for testing (:class:`TimeSplit`);
UCF-101 then needs no ``ucfTrainTestlist/``, only ``<root>/<ClassName>/*.avi``.
"""

from __future__ import annotations

import inspect
import logging
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import numpy as np

from edr.checks.config import (
    ConfigError,
    Distinct,
    Fraction,
    NonEmpty,
    NonNegativeInt,
    OpenFraction,
    Range,
    check_memory,
    mismatch,
)
from edr.data.fingerprint import files_fingerprint, relative_name, shared_files
from edr.data.synthetic import KTH_ACTIONS
from edr.data.video import UnreadableVideo, check_video_file
from edr.store.identity import digest

UCF_LAYOUT = (
    "<root>/<ClassName>/v_<ClassName>_gXX_cYY.avi plus <root>/ucfTrainTestlist/ with "
    "classInd.txt, trainlist0{1,2,3}.txt, testlist0{1,2,3}.txt"
)
KTH_LAYOUT = (
    f"<root>/<action>/personXX_<action>_dY_uncomp.avi for the actions {', '.join(KTH_ACTIONS)}"
)
log = logging.getLogger(__name__)
UCF_GROUP = re.compile(r"_g(\d+)_c\d+")
VIDEO_SUFFIX = ".avi"  # either data set's, in any case (.AVI where a tool wrote upper case)
KTH_NAME = re.compile(r"person(\d\d)_([a-z]+)_d(\d)_uncomp\.(?i:avi)$")  # .AVI too
KTH_SEQUENCE = re.compile(r"^(person\d\d_[a-z]+_d\d)\s+frames\s+(\d.*)$")
# Schuldt et al. (2004): training + validation persons, and the test persons.
KTH_TRAIN_PERSONS = (11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 23, 24, 25, 1, 4)
KTH_TEST_PERSONS = (22, 2, 3, 5, 6, 7, 8, 9, 10)


@dataclass(frozen=True)
class Video:
    """One labelled video file."""

    path: Path
    label: int  # 0-based class index
    group: str  # what must not straddle train and test: UCF group, KTH person
    segments: tuple[tuple[int, int], ...] = ()  # where the action is: [start, stop) frames


@dataclass(frozen=True)
class TimeSplit:
    """The split in time of every video: its first ``train_fraction`` (of the frames left once a
    gap of one clip is taken out) trains, its last part tests. Not the paper's protocol: for
    sets too small to hold every class in both a train and a test video."""

    train: bool  # which part this split's clips come from
    train_fraction: float

    def window(self, length: int, clip: int, name: str) -> range:
        """The frames of a video of ``length`` frames (``name``) that this part's clips of
        ``clip`` frames may use: ``[0, cut)`` or ``[cut + clip, length)``, so that between the
        last training frame and the first test frame lie ``clip`` frames."""
        cut = int(self.train_fraction * (length - clip))
        part = range(0, cut) if self.train else range(cut + clip, length)
        if len(part) < clip:
            raise ConfigError(
                f"{name}: its {length} frames leave {max(len(part), 0)} to the "
                f"{'training' if self.train else 'test'} part of the split in time, less than a "
                f"clip ({clip} frames, task.frames): use shorter clips or another "
                "task.videos.train_fraction"
            )
        return part


@dataclass(frozen=True)
class VideoSet:
    """A split of a data set: its videos and the class names their labels index."""

    videos: tuple[Video, ...]
    classes: tuple[str, ...]
    index_files: tuple[Path, ...] = ()  # files that define the split (UCF-101's lists)
    time_split: TimeSplit | None = None  # split in time: which part of each video to use
    person_fold: tuple[int, int] | None = None  # split by person: (this fold, of how many)

    def __len__(self) -> int:
        return len(self.videos)


class DataLayoutError(ConfigError, FileNotFoundError):
    """A data root that is missing or not in its data set's official layout."""


def _missing(root: Path, what: str, layout: str) -> DataLayoutError:
    return DataLayoutError(f"{what} not found under {root}; expected the layout {layout}")


def _checked_video(path: Path, where: str) -> Path:
    """``path`` if it is a video file with bytes in it; else a :class:`DataLayoutError` naming
    it and ``where`` it was listed."""
    try:
        return check_video_file(path)
    except UnreadableVideo as error:
        raise DataLayoutError(f"{where}: {error}") from None


def _visible(folder: Path) -> list[Path]:
    """What ``folder`` holds, sorted, but hidden names (``.DS_Store``, an editor's swap file):
    a class folder's every other entry is one of its videos, or refused by name, never skipped
    unsaid (a video converted to .mp4 would leave its class silently smaller)."""
    return sorted(p for p in folder.iterdir() if not p.name.startswith("."))


def one_class_each(videos: Sequence[Video], classes: Sequence[str]) -> None:
    """Refuse, naming both files, a video filed under two classes (:func:`shared_files`: the
    same file, a link to it, or a copy): it would be both actions at once."""
    for first, second in shared_files([(v.path, v.label) for v in videos]):
        raise DataLayoutError(
            f"{first[0]} ({classes[first[1]]}) and {second[0]} ({classes[second[1]]}) are the "
            "same video filed under two classes: keep it under one"
        )


def _class_index(class_file: Path) -> dict[str, int]:
    """classInd.txt's ``1 ApplyEyeMakeup`` lines -> {name: 0-based label}: every index from 1
    to the number of classes once, every name once (else one line naming file and line)."""
    classes: dict[str, int] = {}
    lines: dict[int, int] = {}  # index -> the line that gave it
    for n, line in enumerate(class_file.read_text(errors="replace").splitlines(), start=1):
        if not line.strip():
            continue
        parts = line.split()
        if len(parts) != 2 or not parts[0].isdigit():
            raise DataLayoutError(f"{class_file}:{n}: expected '<index> <ClassName>', got {line!r}")
        index, name = int(parts[0]), parts[1]
        if index in lines:
            raise DataLayoutError(
                f"{class_file}:{n}: index {index} is given already on line {lines[index]}; "
                "each class needs its own index"
            )
        same = next((c for c in classes if c.lower() == name.lower()), None)
        if same is not None:  # one folder, on a file system that ignores case
            again = "twice" if same == name else f"twice (as {same} before)"
            raise DataLayoutError(f"{class_file}:{n}: class {name} is listed {again}")
        classes[name], lines[index] = index - 1, n
    if sorted(lines) != list(range(1, len(lines) + 1)):
        gaps = sorted(set(range(1, max(lines, default=0) + 1)) - set(lines))
        raise DataLayoutError(
            f"{class_file}: expected the indices 1 to {len(lines)}, each once"
            + (f" (missing: {', '.join(map(str, gaps[:5]))})" if gaps else "")
        )
    if not classes:
        raise DataLayoutError(f"{class_file} lists no classes")
    return classes


def ucf101(
    root: str | Path,
    *,
    split: Literal[1, 2, 3] = 1,
    train: bool = True,
    protocol: Literal["official", "time"] = "official",
    train_fraction: Fraction = 0.75,
    lists: str | Path | None = None,
    subset: bool = False,
) -> VideoSet:
    """The train or test videos of official split 1, 2 or 3, as its lists name them: the lists
    of ``lists`` (a folder holding classInd.txt, trainlist0N.txt, testlist0N.txt), else of
    ``ucfTrainTestlist/`` in ``<root>`` or beside it, as UCF-101 ships. ``subset``: the root
    holds part of UCF-101 (a sample of its clips): list entries whose file is absent are left
    out (and counted in the log) instead of refused. ``protocol="time"``: every video of
    ``<root>/<ClassName>/*.avi``, split in time (:class:`TimeSplit`, ``train_fraction``)."""
    root = Path(root)
    if split not in (1, 2, 3):
        raise ValueError(f"UCF-101 has splits 1, 2 and 3, not {split}")
    if not root.is_dir():
        raise _missing(root, "UCF-101 root", UCF_LAYOUT)
    if protocol == "time":
        return _ucf101_in_time(root, TimeSplit(train, train_fraction))
    if protocol != "official":
        raise ValueError(f"protocol must be 'official' or 'time', got {protocol!r}")
    if lists is not None:
        lists = Path(lists)
        if not lists.is_dir():
            raise DataLayoutError(
                f"task.videos.lists={lists}: no such folder; expected one holding classInd.txt, "
                "trainlist0{1,2,3}.txt and testlist0{1,2,3}.txt (UCF-101's ucfTrainTestlist/)"
            )
    else:
        lists = next(
            (
                d
                for d in (root / "ucfTrainTestlist", root.parent / "ucfTrainTestlist")
                if d.is_dir()
            ),
            None,
        )
    if lists is None:
        raise _missing(root, "ucfTrainTestlist/", UCF_LAYOUT)
    class_file = lists / "classInd.txt"
    list_file = lists / f"{'train' if train else 'test'}list0{split}.txt"
    for f in (class_file, list_file):
        if not f.is_file():
            raise _missing(root, f.name, UCF_LAYOUT)
    classes = _class_index(class_file)
    videos, absent = [], 0
    for n, line in enumerate(list_file.read_text(errors="replace").splitlines(), start=1):
        if not line.strip():
            continue
        rel = line.split()[0]
        if Path(rel).is_absolute() or ".." in Path(rel).parts:
            raise DataLayoutError(
                f"{list_file}:{n}: {rel!r} leaves the data root; an entry names "
                "<ClassName>/v_<ClassName>_gXX_cYY.avi under it"
            )
        name = rel.split("/")[0]
        if name not in classes:
            raise DataLayoutError(f"{list_file}:{n}: class {name!r} is not in {class_file.name}")
        if subset and not (root / rel).exists():
            absent += 1
            continue
        path = _checked_video(root / rel, f"{list_file}:{n} lists {rel}")
        group = UCF_GROUP.search(rel)
        videos.append(Video(path, classes[name], group.group(1) if group else rel))
    if not videos:
        held = f": none of its {absent} clips is under {root}" if absent else ""
        raise DataLayoutError(f"{list_file} lists no videos{held}")
    if absent:
        log.info("%s: %d of its %d clips are under %s (subset=true: the others are left out)",
                 list_file.name, len(videos), len(videos) + absent, root)  # fmt: skip
    names = tuple(sorted(classes, key=classes.get))
    empty = [name for name in names if all(v.label != classes[name] for v in videos)]
    if empty and not subset:  # a part of UCF-101 (subset=true) holds some of its classes
        raise DataLayoutError(
            f"{list_file} lists no video of the classes {', '.join(empty[:5])}"
            f"{' ...' if len(empty) > 5 else ''} that {class_file.name} names: every class needs "
            f"videos; list them, or remove those classes from {class_file.name}"
        )
    one_class_each(videos, names)
    return VideoSet(tuple(videos), names, (class_file, list_file))


def _ucf101_in_time(root: Path, time_split: TimeSplit) -> VideoSet:
    """Every ``<root>/<ClassName>/*.avi``, classes in sorted order, split in time: every folder
    under ``root`` (but hidden ones and ``ucfTrainTestlist/``) is a class, and needs videos."""
    folders = [d for d in _visible(root) if d.is_dir() and d.name != "ucfTrainTestlist"]
    if not folders:
        raise _missing(root, "class folders with .avi files", "<root>/<ClassName>/*.avi")
    videos = []
    for label, folder in enumerate(folders):
        found = _visible(folder)
        if not found:
            raise DataLayoutError(
                f"{folder}: an empty class folder: every class needs videos; add its videos or "
                "remove the folder"
            )
        for path in found:
            if path.suffix.lower() != VIDEO_SUFFIX:
                raise DataLayoutError(
                    f"{path}: not a video of the layout <root>/<ClassName>/*.avi: rename, "
                    "convert or remove it"
                )
            group = UCF_GROUP.search(path.name)
            videos.append(
                Video(
                    _checked_video(path, str(folder)), label, group.group(1) if group else path.stem
                )
            )
    names = tuple(d.name for d in folders)
    one_class_each(videos, names)
    return VideoSet(tuple(videos), names, time_split=time_split)


# KTH classes to train: each once (one listed twice would be two classes of the same videos)
KthActions = Annotated[Sequence[str], NonEmpty, Distinct]


def kth(
    root: str | Path,
    *,
    train: bool = True,
    protocol: Literal["random", "person", "person_folds", "time"] = "random",
    train_fraction: OpenFraction = 0.75,
    seed: int = 0,
    actions: KthActions | None = None,
    folds: Annotated[int, Range(2)] | Literal["persons"] = 2,
    fold: NonNegativeInt = 0,
    sequences: str | Path | None = None,
) -> VideoSet:
    """KTH's videos; ``protocol="random"``: the paper's seeded 75/25 random split of the videos,
    ``"person"``: the standard split by person (Schuldt et al. 2004), ``"person_folds"``: the
    persons dealt into ``folds`` folds (:func:`person_folds`), fold ``fold``'s persons testing
    and the others training, so that over the folds every video is tested once by a network
    that never saw its person (``folds="persons"``: a fold per person, leave one person out);
    ``"time"``: every video, split in time (:class:`TimeSplit`;
    ``train_fraction`` of each video's frames trains). ``actions``: the classes (default all
    six, in KTH's order). ``sequences``: KTH's ``00sequences.txt``, whose sub-sequences then
    bound where clips are taken (the frames between them show no action)."""
    root = Path(root)
    if actions is not None and (expected := mismatch(actions, KthActions)):
        raise ConfigError(f"task.videos.actions={list(actions)}: expected {expected}")
    actions = KTH_ACTIONS if actions is None else tuple(actions)
    unknown = sorted(set(actions) - set(KTH_ACTIONS))
    if unknown:
        raise ConfigError(f"task.videos.actions: {unknown} are not KTH actions ({KTH_ACTIONS})")
    if not root.is_dir():
        raise _missing(root, "KTH root", KTH_LAYOUT)
    absent = [a for a in actions if not (root / a).is_dir()]
    if absent:
        raise _missing(root, f"action folders {absent}", KTH_LAYOUT)
    segments = read_kth_sequences(Path(sequences)) if sequences else {}
    videos = []
    for label, action in enumerate(actions):
        found = _visible(root / action)
        if not any(p.suffix.lower() == VIDEO_SUFFIX for p in found):
            raise DataLayoutError(
                f"{root / action} holds no .avi video: every action needs videos ({KTH_LAYOUT})"
            )
        for path in found:
            match = KTH_NAME.search(path.name)
            if match is None or match.group(2) != action:
                raise DataLayoutError(
                    f"{path}: not a KTH video file name ({KTH_LAYOUT}): rename, convert or "
                    "remove it"
                )
            name = video_name(path)
            if segments and name not in segments:
                raise DataLayoutError(f"{sequences} has no line for {name} ({path})")
            checked = _checked_video(path, str(root / action))
            videos.append(Video(checked, label, match.group(1), segments.get(name, ())))
    one_class_each(videos, actions)
    index = (Path(sequences),) if sequences else ()
    if protocol == "time":
        return VideoSet(tuple(videos), actions, index, time_split=TimeSplit(train, train_fraction))
    if protocol == "person_folds":
        persons = len({v.group for v in videos})
        if problem := folds_problem(folds, persons, f"the persons whose videos are under {root}"):
            raise ConfigError(f"task.{problem}")
        if folds == "persons":  # leave one person out: a fold per person, in sorted order
            dealt = {p: k for k, p in enumerate(sorted({v.group for v in videos}))}
        else:
            dealt = person_folds(videos, folds)
        count = len(dealt) if folds == "persons" else folds
        if fold >= count:
            raise ConfigError(f"task.videos.fold={fold}: the folds are 0 to {count - 1}")
        chosen = [v for v in videos if (dealt[v.group] == fold) != train]
        return VideoSet(tuple(chosen), actions, index, person_fold=(fold, count))
    if protocol == "person":
        persons = {f"{p:02d}" for p in (KTH_TRAIN_PERSONS if train else KTH_TEST_PERSONS)}
        chosen = [v for v in videos if v.group in persons]
    elif protocol == "random":
        order = np.random.default_rng(seed).permutation(len(videos))
        cut = round(train_fraction * len(videos))
        keep = order[:cut] if train else order[cut:]
        chosen = [videos[i] for i in sorted(keep)]
    else:
        raise ValueError(
            f"protocol must be 'random', 'person', 'person_folds' or 'time', got {protocol!r}"
        )
    if not chosen:
        how = (
            f"train_fraction={train_fraction} of the {len(videos)} videos"
            if protocol == "random"
            else "split by person"
        )
        raise ConfigError(
            f"task.videos: the {how} under {root} leaves no {'train' if train else 'test'} "
            "video: change task.videos.train_fraction or protocol, or add videos"
        )
    return VideoSet(tuple(chosen), actions, index)


def video_name(path: Path) -> str:
    """A video's name as its data set's lists give it: ``person01_boxing_d1`` (KTH, without
    ``_uncomp.avi``), ``v_Biking_g01_c01`` (UCF-101)."""
    stem = path.name.removesuffix(path.suffix)  # .avi or .AVI
    return stem.removesuffix("_uncomp")


def kth_person_scenario(path: Path) -> tuple[str | None, str | None]:
    """(person, scenario) of a KTH file name: ``("01", "d1")``; (None, None) for any other."""
    match = KTH_NAME.search(path.name)
    return (match.group(1), f"d{match.group(3)}") if match else (None, None)


def read_kth_sequences(path: Path) -> dict[str, tuple[tuple[int, int], ...]]:
    """KTH's ``00sequences.txt``: video name (``person01_boxing_d1``) -> its sub-sequences as
    0-based ``[start, stop)`` frame ranges (the file's are 1-based and inclusive). Lines that
    are not a video's (the header) are skipped; a video line that does not read is refused."""
    if not path.is_file():
        raise DataLayoutError(f"{path}: no such file (KTH's 00sequences.txt)")
    table = {}
    for n, line in enumerate(path.read_text(errors="replace").splitlines(), start=1):
        match = KTH_SEQUENCE.match(line.strip())
        if match is None:
            continue
        ranges = []
        for part in match.group(2).split(","):
            bounds = part.strip().split("-")
            if len(bounds) != 2 or not all(b.isdigit() for b in bounds):
                raise DataLayoutError(
                    f"{path}:{n}: expected ranges like '1-95, 96-185', got {line!r}"
                )
            first, last = map(int, bounds)
            if not 1 <= first <= last:
                raise DataLayoutError(
                    f"{path}:{n}: the range {part.strip()!r} is empty or before 1"
                )
            ranges.append((first - 1, last))
        table[match.group(1)] = tuple(ranges)
    if not table:
        raise DataLayoutError(
            f"{path}: no line of KTH's form 'person01_boxing_d1  frames  1-95, ...'"
        )
    return table


def folds_problem(folds: int | str, persons: int, whose: str) -> str | None:
    """``videos.folds=<n>: expected ...`` where a split by person into ``folds`` folds would leave
    a fold without a person, which would test nothing (``persons`` of them, ``whose``: where
    they come from); None where it would not."""
    if folds == "persons" or folds <= persons:
        return None
    return (
        f"videos.folds={folds}: expected at most {persons}, {whose}: each fold tests persons of "
        "its own (or folds=persons)"
    )


def person_folds(videos: Sequence[Video], folds: int) -> dict[str, int]:
    """Each person (``Video.group``) -> a fold in ``range(folds)``, all of a person's videos in
    one fold, dealt so that each class's videos spread as evenly as they can over the folds:
    persons with the most videos first, each into the fold where its classes have the fewest
    videos so far (then the fold with the fewest videos, then the lowest). Deterministic: the
    same videos give the same folds on every machine."""
    by_person: dict[str, list[int]] = {}
    for video in videos:
        by_person.setdefault(video.group, []).append(video.label)
    counts = np.zeros((folds, max((v.label for v in videos), default=0) + 1), int)
    dealt = {}
    for person in sorted(by_person, key=lambda p: (-len(by_person[p]), p)):
        labels = by_person[person]
        fold = min(range(folds), key=lambda f: (counts[f, labels].sum(), counts[f].sum(), f))
        dealt[person] = fold
        np.add.at(counts[fold], labels, 1)
    return dealt


def resolve_root(
    data_root: str | None,
    synthetic: Callable[..., Path],
    cache_dir: str | Path,
    where: str = "task",
) -> Path:
    """``data_root`` when given; else the data set ``synthetic`` (a partial of one of the writers
    of ``edr.data.synthetic`` or ``edr.data.from_videos``) writes once under ``cache_dir``, named
    by its settings, once a video of its size is known to fit in memory (each is made whole;
    ``where``: the config's section that holds ``synthetic``)."""
    if data_root:
        return Path(data_root)
    size = {k: p.default for k, p in inspect.signature(synthetic).parameters.items()
            if k in ("frames", "height", "width")}  # fmt: skip
    check_memory(
        ", ".join(f"{where}.synthetic.{k}={v}" for k, v in size.items()),
        f"a generated video of {size['frames']} frames at {size['width']}x{size['height']}",
        math.prod(size.values()),
    )
    settings = {"fn": synthetic.func.__name__, **synthetic.keywords}
    root = Path(cache_dir).resolve() / f"{synthetic.func.__name__}_{digest(settings, 10)}"
    if not root.exists():
        log.info("no data_root given: %s writes a data set in %s", synthetic.func.__name__, root)
    return synthetic(root)


def videos_fingerprint(root: Path, splits: Sequence[VideoSet]) -> str:
    """The content fingerprint of the videos of ``splits`` with their labels, and of the files
    that define the splits; not of which video a seeded random split put where (the seed is in
    the run's config), so that the seeds of one cell share their data's fingerprint."""
    videos = {v.path: v.label for split in splits for v in split.videos}
    index = {f for split in splits for f in split.index_files}
    labels = sorted((relative_name(p, root), label) for p, label in videos.items())
    return files_fingerprint([*videos, *index], root, extra=labels)
