"""Issue 57's cases outside the event files: a cache that survives a full disk, the command
line's one-line refusals, and the records of runs that end on a signal. Each case was a
reproducer that failed before its fix."""

from __future__ import annotations

import cv2
import pytest

from edr.data.synthetic import write_synthetic_kth


class _SilentWriter:
    """cv2.VideoWriter as it behaves on a full disk: opens, takes every frame, writes nothing."""

    def __init__(self, *args, **kwargs) -> None:
        pass

    def isOpened(self) -> bool:
        return True

    def write(self, frame) -> None:
        pass

    def release(self) -> None:
        pass


def test_a_full_disk_leaves_no_generated_data_set_behind(tmp_path, monkeypatch) -> None:
    root = tmp_path / "cache" / "kth"
    size = {"persons": 1, "scenarios": 1, "frames": 4, "height": 12, "width": 16}
    with monkeypatch.context() as patch:
        patch.setattr(cv2, "VideoWriter", _SilentWriter)
        with pytest.raises(OSError, match=r"left an empty file \(the disk holding it has .* MiB"):
            write_synthetic_kth(root, **size)
    assert not root.exists() and list((tmp_path / "cache").iterdir()) == []  # nothing half kept
    videos = sorted(write_synthetic_kth(root, **size).glob("*/*.avi"))  # space back: it works
    assert len(videos) == 6 and all(v.stat().st_size > 0 for v in videos)


def test_a_key_given_twice_is_refused_in_one_line(cli, tmp_path) -> None:
    result = cli("edr-run", "task=kth", "task=atari", "debug=tiny", cwd=tmp_path)
    assert result.returncode == 2 and result.stderr.count("\n") == 1
    assert "task is given twice (task=kth and task=atari)" in result.stderr


def test_a_file_where_a_folder_belongs_is_refused_in_one_line(cli, tmp_path) -> None:
    video = tmp_path / "person01_boxing_d1_uncomp.avi"
    video.write_bytes(b"not a folder")
    result = cli("edr-run", "task=kth", f"task.data_root={video}", "debug=tiny", cwd=tmp_path)
    assert result.returncode == 2 and f"expected a folder ({video} is a file)" in result.stderr
    result = cli("edr-run", "task=kth", "debug=tiny", cwd=tmp_path, env={"EDR_CACHE": str(video)})
    assert result.returncode == 2 and result.stderr.count("\n") == 1
    assert f"task.cache_dir='{video}': expected a folder" in result.stderr


def test_edr_eval_on_a_recognition_run_says_what_it_scores(tmp_path) -> None:
    import json

    from edr.store.records import UnreadableRecord
    from edr.tasks.atari import evaluate_checkpoint

    (tmp_path / "run.json").write_text(json.dumps({"task": "kth", "status": "finished"}))
    with pytest.raises(UnreadableRecord, match="is a kth run: edr-eval scores Atari runs"):
        evaluate_checkpoint(tmp_path)
