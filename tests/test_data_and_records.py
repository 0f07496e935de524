"""Video decoding errors, the generated scene, atomic run records, and the paths they hold."""

from __future__ import annotations

import json
import shutil
import subprocess

import pytest
import torch

from edr import tables
from edr.data import read_video, synthetic_scene, write_video
from edr.run import run
from edr.store.atomic import write_json_atomic
from edr.store.records import check_flat, git_revision, read_record, write_record
from edr.tasks.recognition import load_model


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
    path = write_record(tmp_path, {"status": "finished", "metrics": {"x/y": 2.0}})
    assert read_record(path)["metrics"] == {"x/y": 2.0}
    assert path.stat().st_mode & 0o044 == 0o044  # the group and others can read it (not 0600)

    class Unserializable:
        def __str__(self) -> str:
            raise RuntimeError("boom")

    with pytest.raises(RuntimeError):
        write_json_atomic(path, {"bad": Unserializable()})
    assert read_record(path)["status"] == "finished"  # the old record survives
    assert [p.name for p in tmp_path.iterdir()] == ["run.json"]  # no half-written leftovers


def test_metrics_must_be_flat() -> None:
    assert check_flat({"eval/accuracy": 0.5, "data/root": "x", "n": 3, "none": None})
    with pytest.raises(TypeError, match="eval/confusion"):
        check_flat({"eval/confusion": [[1, 0], [0, 1]]})


def test_git_revision_is_dirty_for_code_changes_not_for_results(tmp_path) -> None:
    def git(*args: str) -> str:
        return subprocess.run(
            ["git", "-c", "user.name=t", "-c", "user.email=t@t", *args],
            cwd=tmp_path, check=True, capture_output=True, text=True,
        ).stdout.strip()  # fmt: skip

    git("init", "-q")
    for name in ("src/code.py", "results/run.json", "paper/table.md"):
        (tmp_path / name).parent.mkdir(exist_ok=True)
        (tmp_path / name).write_text("1")
    git("add", ".")
    git("commit", "-qm", "first")
    head = git("rev-parse", "HEAD")
    (tmp_path / "results/run.json").write_text("2")  # a run's output
    (tmp_path / "paper/table.md").write_text("2")  # edr-tables' output
    (tmp_path / "notes.txt").write_text("untracked")
    assert git_revision(tmp_path / "src") == head
    (tmp_path / "src/code.py").write_text("2")
    assert git_revision(tmp_path / "src") == head + "+dirty"


def test_a_record_names_no_folder_of_its_machine_under_the_results_root(
    compose_config, monkeypatch, tmp_path
) -> None:
    """Paths under the results root are written from it, files of the run from its folder; the
    tables read a record of this form and one of the old, absolute form alike."""
    results = tmp_path / "results"
    monkeypatch.setenv("EDR_RESULTS", str(results))
    run_dir = results / "runs" / "kth"
    run(compose_config("task=kth", "debug=tiny", f"out_dir={run_dir}", "task.logger="))
    record = read_record(run_dir / "run.json")
    assert record["config"]["out_dir"] == "<paths.results>/runs/kth"
    assert record["config"]["paths"]["results"] == "<paths.results>"
    assert record["config"]["task"]["cache_dir"] == "<paths.results>/cache"
    assert record["data"]["root"].startswith("<paths.results>/cache/write_synthetic_kth_")
    written = json.dumps([record["config"], record["data"], record["metrics"]])
    assert str(tmp_path) not in written  # (the overrides stay as they were typed)

    old = tmp_path / "old" / "kth"  # as records were written before: absolute paths
    shutil.copytree(run_dir, old)
    text = (run_dir / "run.json").read_text().replace("<paths.results>", str(results))
    (old / "run.json").write_text(text)
    rendered = []
    (tmp_path / "bench").mkdir()  # no bench records (a --bench named must be there)
    for runs in (results / "runs", old.parent):
        out = tmp_path / f"paper_{runs.name}"
        tables.main(["--runs", str(runs), "--out", str(out), "--bench", str(tmp_path / "bench")])
        rendered.append((out / "table4_kth.md").read_text().split("Records:")[0])
    assert rendered[0] == rendered[1]
    assert load_model(old).state_dict().keys() == load_model(run_dir).state_dict().keys()
