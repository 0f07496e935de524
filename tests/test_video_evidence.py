"""Recognition as evidence counted in videos: per-video predictions (``predictions.json``) and
their soft vote, the controls of the frames (``task.frame_control``, ``task.shuffle_frames``)
and the combinations refused, Table 4's by-person statistics (bootstrap interval over videos,
exact sign-flip test, class-scenario confounds), and UCF-101's official lists against the real
clips; on generated data and on the real clips of ``../shared/real-video`` (skipped where that
folder is absent)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from edr.checks.config import ConfigError
from edr.data.clips import ClipDataset, VideoSource
from edr.data.datasets import TimeSplit, Video, VideoSet, kth, kth_person_scenario, ucf101
from edr.report.recognition import UCF101_SPLITS_NOTE
from edr.report.video_statistics import (
    bootstrap_interval,
    by_person_block,
    confounds,
    sign_flip_p,
)
from edr.representations import FDR, Farneback
from edr.tasks.predictions import video_accuracy, video_predictions
from edr.tasks.recognition import _frame_control
from real_video import REAL_VIDEO

CLASSES = ("boxing", "running", "walking")
KTH_REAL = REAL_VIDEO / "kth"


def _real(what: Path) -> None:
    if not what.exists():
        pytest.skip(f"no real clips at {what} (../shared/real-video is absent)")


# ---- per-video predictions -------------------------------------------------------------------


def test_a_video_is_voted_by_its_items_mean_scores_not_their_majority() -> None:
    videos = VideoSet(
        (Video(Path("person01_boxing_d4_uncomp.avi"), 0, "01"),
         Video(Path("person02_running_d1_uncomp.avi"), 1, "02")), CLASSES,
    )  # fmt: skip
    # video 0: two items lean to running a little, one is sure of boxing: the mean says boxing
    scores = np.array([[0.45, 0.55, 0], [0.45, 0.55, 0], [1.0, 0, 0], [0, 0.2, 0.8]])
    entries = video_predictions(videos, [0, 0, 0, 1], scores)
    first, second = entries
    assert first["items"] == ["running", "running", "boxing"] and first["predicted"] == "boxing"
    assert first["soft_vote"] == pytest.approx([0.633333, 0.366667, 0], abs=1e-6)
    assert (first["video"], first["person"], first["scenario"]) == (
        "person01_boxing_d4",
        "01",
        "d4",
    )
    assert second["predicted"] == "walking" and video_accuracy(entries) == 0.5


def test_the_real_kth_names_give_person_and_scenario() -> None:
    _real(KTH_REAL)
    videos = kth(KTH_REAL, protocol="person_folds", actions=list(CLASSES), folds="persons",
                 train=False, fold=0).videos  # fmt: skip
    assert [kth_person_scenario(v.path) for v in videos] == [("01", "d1"), ("01", "d1")]
    every = [kth_person_scenario(p) for p in sorted(KTH_REAL.glob("*/*.avi"))]
    assert all(person and scenario in ("d1", "d2", "d3", "d4") for person, scenario in every)


# ---- controls of the frames ------------------------------------------------------------------


def _numbered(length: int):
    """A source whose every frame holds its own index: (length, 1, 4, 4) float32."""
    return lambda path: np.broadcast_to(
        np.arange(length, dtype=np.float32)[:, None, None, None], (length, 1, 4, 4)
    )


def _frames_of(dataset: ClipDataset, index: int) -> np.ndarray:
    clip = dataset[index][0]
    clip = clip if dataset.train else clip[0]  # a test stack: its first crop
    return clip[:, 0, 0, 0].round().int().numpy()  # (frames,) the frame numbers shown


def test_the_controls_do_what_their_names_say() -> None:
    segments = ((0, 40), (50, 90))
    videos = VideoSet((Video(Path("person01_boxing_d1_uncomp.avi"), 0, "01", segments),), CLASSES)
    torch.manual_seed(0)
    made = {c: ClipDataset(videos, _numbered(100), frames=8, crop=4, train=True, scales=(1.0,),
                           control=c) for c in (None, "shuffled_in_clip", "shuffled_in_video",
                                                "one_frame")}  # fmt: skip
    for _ in range(30):
        in_order = _frames_of(made[None], 0)
        assert (np.diff(in_order) == 1).all()
        in_clip = _frames_of(made["shuffled_in_clip"], 0)  # neighbours stay neighbours
        assert in_clip.max() - in_clip.min() == 7 and len(set(in_clip)) == 8
        one = _frames_of(made["one_frame"], 0)
        assert len(set(one)) == 1
        in_video = _frames_of(made["shuffled_in_video"], 0)  # far apart, in one sub-sequence
        assert len(set(in_video)) == 8 and any(a <= in_video.min() and in_video.max() < b
                                               for a, b in segments)  # fmt: skip
    spans = [np.ptp(_frames_of(made["shuffled_in_video"], 0)) for _ in range(30)]
    assert np.mean(spans) > 20  # 8 frames drawn across a 40-frame sub-sequence, not 7 apart
    tests = [ClipDataset(videos, _numbered(100), frames=8, crop=4, train=False, control=c)
             for c in ("shuffled_in_video", "one_frame")]  # fmt: skip
    for test in tests:  # a test item is the same on every read
        assert (_frames_of(test, 1) == _frames_of(test, 1)).all()


def test_the_controls_that_make_no_sense_are_refused() -> None:
    split = VideoSet((), CLASSES)
    in_time = VideoSet((), CLASSES, time_split=TimeSplit(False, 0.75))
    assert _frame_control(True, None, FDR(), split) == "shuffled_in_clip"
    assert _frame_control(False, "one_frame", FDR(), in_time) == "one_frame"
    with pytest.raises(ConfigError, match=r"task\.shuffle_frames=true with task\.frame_control"):
        _frame_control(True, "one_frame", FDR(), split)
    with pytest.raises(ConfigError, match=r"frame_control=one_frame with Farneback, computed"):
        _frame_control(False, "one_frame", Farneback(), split)
    with pytest.raises(ConfigError, match=r"shuffled_in_video with videos split in time"):
        _frame_control(False, "shuffled_in_video", FDR(), in_time)


def test_one_frame_and_a_video_shuffle_on_a_real_kth_video(tmp_path) -> None:
    _real(KTH_REAL)
    video = kth(KTH_REAL, actions=["boxing"], protocol="person_folds", folds="persons", fold=0,
                train=False,
                sequences=REAL_VIDEO / "splits/kth/00sequences.txt").videos[0]  # fmt: skip
    videos = VideoSet((video,), ("boxing",))
    source = VideoSource(None, size=(40, 30), gray=True)
    clips = {c: ClipDataset(videos, source, frames=8, crop=24, train=False, control=c)[0][0][0]
             for c in (None, "one_frame", "shuffled_in_video")}  # fmt: skip  # (8, 1, 24, 24)
    moved = lambda clip: float((clip[1:] - clip[:-1]).abs().mean())  # noqa: E731
    assert moved(clips["one_frame"]) == 0 < moved(clips[None])  # no motion at all
    assert moved(clips["shuffled_in_video"]) > moved(clips[None])  # frames from far apart


# ---- statistics of Table 4's by-person rows ----------------------------------------------------


def test_the_sign_flip_test_is_exact() -> None:
    assert sign_flip_p(np.ones(5)) == pytest.approx(2 / 32)  # 5 of 5 videos: not below 0.05
    assert sign_flip_p(np.ones(6)) == pytest.approx(2 / 64)
    assert sign_flip_p(np.array([1.0, -1.0, 0.0])) == 1.0
    assert sign_flip_p(np.zeros(4)) == 1.0
    d = np.array([1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, -1.0])  # 17: two chunks
    assert sign_flip_p(d) == pytest.approx(2 * (1 + 18) / 2**18)  # sums of 16 or more
    low, high = bootstrap_interval(np.array([1.0] * 10 + [0.0] * 4))
    assert low < 10 / 14 < high and (low, high) == bootstrap_interval(
        np.array([1.0] * 10 + [0.0] * 4)
    )


def _runs(tmp_path: Path, rows: dict[str, list[list[bool]]], videos: pd.DataFrame) -> pd.DataFrame:
    """Records of by-person runs: per row, per seed, which videos it got right."""
    records = []
    for name, seeds in rows.items():
        for seed, right in enumerate(seeds):
            run_dir = tmp_path / f"{name}-{seed}"
            run_dir.mkdir(parents=True)
            entries = [{"video": v.video, "person": v.person, "scenario": v.scenario,
                        "true": v.true, "predicted": v.true if ok else "other", "items": [v.true]}
                       for v, ok in zip(videos.itertuples(), right, strict=True)]  # fmt: skip
            (run_dir / "predictions.json").write_text(json.dumps({"videos": entries}))
            records.append({"data.split": "by person, cross-validated", "data.label": "kth",
                            "data.fingerprint": "f", "input": name, "cell": name, "seed": seed,
                            "run_dir": str(run_dir)})  # fmt: skip
    return pd.DataFrame(records)


def test_the_by_person_block_claims_above_only_where_the_paired_test_shows_it(tmp_path) -> None:
    names = [f"person{p:02d}_{c}_d{d}" for p, c, d in
             [(1, "boxing", 4), (2, "boxing", 4), (3, "boxing", 1), (4, "running", 1),
              (5, "running", 3), (6, "walking", 2), (7, "walking", 2), (8, "walking", 1)]]  # fmt: skip
    videos = pd.DataFrame([{"video": n, "person": n[6:8], "scenario": n[-2:],
                            "true": n.split("_")[1]} for n in names])  # fmt: skip
    rows = {"edr": [[True] * 8] * 3, "fdr": [[False] * 6 + [True] * 2] * 3,
            "graydiff": [[True] * 7 + [False]] * 2}  # fmt: skip
    block = by_person_block(_runs(tmp_path, rows, videos))
    assert (
        "| edr              | 8        | 3 (0, 1, 2)    | 100.0                | 100.0–100.0"
        in block
    )
    assert "edr above fdr" in block  # 6 videos, all one way: p = 2/64
    assert "graydiff above fdr" not in block  # 6 videos one way, 1 the other: p = 0.125
    assert block.count("| no difference shown |") == 2
    assert "Confounds: d2 only in walking, d3 only in running, d4 only in boxing" in block
    assert confounds(videos.set_index("video"))[0] == (
        "boxing d1 (1), d4 (2); running d1 (1), d3 (1); walking d1 (1), d2 (2)"
    )
    old = _runs(tmp_path / "old", {"edr": [[True] * 8]}, videos)
    Path(old["run_dir"][0], "predictions.json").unlink()
    assert "keep no per-video predictions" in by_person_block(old)


def test_the_real_kth_confounds() -> None:
    _real(KTH_REAL)
    videos = pd.DataFrame(
        [{"true": p.parent.name, "scenario": kth_person_scenario(p)[1]}
         for c in CLASSES for p in sorted((KTH_REAL / c).glob("*.avi"))]
    )  # fmt: skip
    assert len(videos) == 14
    assert confounds(videos)[1] == ["d2 only in walking", "d4 only in boxing"]


# ---- UCF-101's official lists -------------------------------------------------------------------


def test_ucf101_official_lists_leave_too_few_real_test_clips_as_table2_says() -> None:
    root = REAL_VIDEO / "ucf101"
    _real(root)
    lists = REAL_VIDEO / "splits" / "ucf101"
    found = {}
    for split in (1, 2, 3):
        sides = [
            ucf101(root, split=split, train=t, lists=lists, subset=True) for t in (True, False)
        ]
        named = [[side.classes[v.label] for v in side.videos] for side in sides]  # (train, test)
        both = set(named[0]) & set(named[1])
        found[split] = (sorted(both), sum(c in both for c in named[1]),
                        sum(c in both for c in named[0]))  # fmt: skip
    assert found == {1: (["Biking", "Rowing"], 3, 7), 2: (["PlayingViolin", "Rowing"], 4, 6),
                     3: (["Biking", "PlayingViolin", "Rowing"], 5, 8)}  # fmt: skip
    assert "24 real UCF-101 clips of 13 classes" in UCF101_SPLITS_NOTE
    assert len({p.parent.name for p in root.glob("*/*.avi")}) == 13
