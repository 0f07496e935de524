"""UCF-101's official split lists: read from ``ucfTrainTestlist/`` or a folder given, on a copy
that holds part of the data set (``subset``), with entries that would leave the data root
refused; on the real clips of ``../shared/real-video`` each clip lands on the side split 1's
official lists put it (skipped where that folder is absent)."""

from __future__ import annotations

import pytest

from edr.data.datasets import DataLayoutError, ucf101
from edr.data.synthetic import write_synthetic_ucf101
from real_video import REAL_VIDEO


def test_every_real_clip_is_on_the_side_the_official_split_1_lists_put_it() -> None:
    root, lists = REAL_VIDEO / "ucf101", REAL_VIDEO / "splits" / "ucf101"
    if not root.is_dir():
        pytest.skip(f"no real UCF-101 clips at {root} (../shared/real-video is absent)")
    official = {
        side: {line.split()[0].split("/")[1] for line in (lists / f"{side}list01.txt")
               .read_text().splitlines() if line.strip()}
        for side in ("train", "test")
    }  # fmt: skip
    clips = {p.name for p in root.glob("*/*.avi")}
    assert len(clips) == 24
    sides = {
        side: ucf101(root, split=1, train=side == "train", lists=lists, subset=True)
        for side in ("train", "test")
    }
    for side, videos in sides.items():
        names = {v.path.name for v in videos.videos}
        assert names == clips & official[side], side
        classes = videos.classes
        assert all(v.path.parent.name == classes[v.label] for v in videos.videos)
        # split 1 tests groups 1-7 and trains on 8-25 (Soomro et al.)
        assert all((int(v.group) <= 7) == (side == "test") for v in videos.videos)
    assert {v.path.name for s in sides.values() for v in s.videos} == clips
    assert len(sides["train"].classes) == 101


def test_a_subset_a_lists_folder_and_entries_outside_the_root(tmp_path) -> None:
    root = write_synthetic_ucf101(tmp_path / "ucf", groups=8, clips=1, frames=4, height=12,
                                  width=16)  # fmt: skip
    full = ucf101(root, split=1, train=False)
    moved = tmp_path / "lists"
    (root / "ucfTrainTestlist").rename(moved)
    with pytest.raises(DataLayoutError, match="ucfTrainTestlist/ not found"):
        ucf101(root, split=1, train=False)
    assert ucf101(root, split=1, train=False, lists=moved).videos == full.videos
    with pytest.raises(DataLayoutError, match=r"task\.videos\.lists=.*: no such folder"):
        ucf101(root, lists=tmp_path / "nowhere")
    gone = full.videos[0].path
    gone.unlink()
    with pytest.raises(DataLayoutError, match=gone.name):  # a full copy names what it lacks
        ucf101(root, split=1, train=False, lists=moved)
    part = ucf101(root, split=1, train=False, lists=moved, subset=True)
    assert part.videos == full.videos[1:]
    (moved / "testlist01.txt").write_text("../../etc/hostname\n")
    with pytest.raises(
        DataLayoutError, match=r"testlist01\.txt:1: '\.\./\.\./etc/hostname' leaves"
    ):
        ucf101(root, split=1, train=False, lists=moved, subset=True)
