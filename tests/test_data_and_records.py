"""Video decoding errors, the generated scene, and atomic run records."""

from __future__ import annotations

import json

import pytest
import torch

from edr.data import read_video, synthetic_scene, write_video
from edr.records import write_json_atomic, write_run_record


def test_video_round_trip(tmp_path) -> None:
    clip = synthetic_scene(6, 32, 48, seed=1)
    path = write_video(tmp_path / "v_Demo_g01_c01.avi", clip)
    back = read_video(path)
    assert back.shape == clip.shape and back.dtype == torch.uint8
    assert (back.float() - clip.float()).abs().mean() < 4  # MJPG is lossy, not that lossy
    assert read_video(path, max_frames=3, size=(24, 16)).shape == (3, 3, 16, 24)
    assert not list(tmp_path.glob(".*partial*"))


def test_missing_and_corrupt_videos_name_the_file(tmp_path) -> None:
    with pytest.raises(FileNotFoundError, match=r"nothere\.avi"):
        read_video(tmp_path / "nothere.avi")
    bad = tmp_path / "corrupt.avi"
    bad.write_bytes(b"\x00" * 1000)
    with pytest.raises(ValueError, match=r"corrupt\.avi"):
        read_video(bad)


def test_scene_is_seeded_and_moves() -> None:
    a, b = synthetic_scene(5, 32, 32, seed=3), synthetic_scene(5, 32, 32, seed=3)
    assert torch.equal(a, b)
    assert not torch.equal(a[0], a[-1])
    with pytest.raises(ValueError):
        synthetic_scene(0, 32, 32)


def test_record_is_written_whole_or_not_at_all(tmp_path) -> None:
    path = write_run_record(
        tmp_path,
        task="demo",
        choices={"task": "demo"},
        config={"a": 1},
        overrides=["a=1"],
        metrics={"x/y": 2.0},
        wall_time_s=1.5,
    )
    record = json.loads(path.read_text())
    assert record["metrics"] == {"x/y": 2.0} and record["machine"]["cpu_count"] >= 1
    assert record["git"] and record["wall_time_s"] == 1.5

    class Unserializable:
        def __str__(self) -> str:
            raise RuntimeError("boom")

    with pytest.raises(RuntimeError):
        write_json_atomic(path, {"bad": Unserializable()})
    assert json.loads(path.read_text())["task"] == "demo"  # the old record survives
    assert [p.name for p in tmp_path.iterdir()] == ["run.json"]  # no half-written leftovers
