"""The split by person (``experiment=kth_person``, ``task.videos.protocol=person_folds``): train
and test persons disjoint in every fold, every video tested once over the folds, clips only
within KTH's sub-sequences, and a cross-validated run whose record pools its folds; on
generated video in KTH's layout and on the real KTH clips of ``../shared/real-video``
(skipped where that folder is absent)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from edr.checks.config import ConfigError
from edr.data.clips import ClipDataset
from edr.data.datasets import (
    DataLayoutError,
    Video,
    VideoSet,
    kth,
    person_folds,
    read_kth_sequences,
)
from edr.data.synthetic import write_synthetic_kth
from edr.run import run
from edr.store.identity import run_identity
from edr.store.records import read_record
from real_video import REAL_VIDEO

ACTIONS = ["boxing", "running", "walking"]
REPO = Path(__file__).resolve().parents[1]


def _folds(root: Path, folds: int | str, **kwargs) -> list[tuple[list[Video], list[Video]]]:
    count = kth(root, protocol="person_folds", actions=ACTIONS, folds=folds, **kwargs).person_fold[
        1
    ]
    return [
        tuple(list(kth(root, train=t, protocol="person_folds", actions=ACTIONS, folds=folds,
                       fold=f, **kwargs).videos) for t in (True, False))
        for f in range(count)
    ]  # fmt: skip


def _assert_cross_validated(splits: list[tuple[list[Video], list[Video]]]) -> None:
    every = {v.path for train, test in splits[:1] for v in train + test}
    tested = [v.path for _, test in splits for v in test]
    assert sorted(tested) == sorted(every)  # each video tested once over the folds
    for train, test in splits:
        assert not {v.group for v in train} & {v.group for v in test}  # persons disjoint
        assert {v.label for v in train} == set(range(len(ACTIONS)))  # every class trains


def test_persons_are_dealt_whole_and_each_class_spread_over_the_folds() -> None:
    videos = [Video(Path(f"{p}_{c}"), c, p) for p, c in
              [("01", 0), ("01", 2), ("04", 0), ("04", 1), ("09", 1), ("15", 1), ("16", 0),
               ("21", 0), ("25", 0), ("23", 1), ("07", 2), ("14", 2), ("20", 2)]]  # fmt: skip
    dealt = person_folds(videos, 2)
    assert dealt == person_folds(list(reversed(videos)), 2)  # the order given does not matter
    counts = np.zeros((2, 3), int)
    for v in videos:
        counts[dealt[v.group], v.label] += 1
    assert (counts.max(0) - counts.min(0) <= 1).all(), counts  # boxing 5: 3 / 2; the others 2 / 2


def test_generated_kth_split_by_person_is_cross_validated(tmp_path) -> None:
    root = write_synthetic_kth(tmp_path / "kth", persons=4, scenarios=1, frames=20, height=12,
                               width=16)  # fmt: skip
    for folds in (2, 4):
        _assert_cross_validated(_folds(root, folds))
    every_person = _folds(root, "persons")  # leave one person out: a fold per person
    _assert_cross_validated(every_person)
    assert [len({v.group for v in test}) for _, test in every_person] == [1, 1, 1, 1]
    with pytest.raises(ConfigError, match=r"task\.videos\.fold=4: the folds are 0 to 3"):
        kth(root, protocol="person_folds", folds="persons", fold=4)
    with pytest.raises(ConfigError, match=r"task\.videos\.fold=2: the folds are 0 to 1"):
        kth(root, protocol="person_folds", folds=2, fold=2)
    with pytest.raises(ConfigError, match=r"\['jumping'\] are not KTH actions"):
        kth(root, protocol="person_folds", actions=["boxing", "jumping"])


def test_the_sub_sequences_file_reads_and_refuses_a_bad_line(tmp_path) -> None:
    good = tmp_path / "00sequences.txt"
    good.write_text("header line\n\nperson01_boxing_d1\t\tframes\t1-95, 96-185, 186-245\n")
    assert read_kth_sequences(good) == {"person01_boxing_d1": ((0, 95), (95, 185), (185, 245))}
    bad = tmp_path / "bad.txt"
    bad.write_text("person01_boxing_d1\t\tframes\t1-95, 96-x\n")
    with pytest.raises(DataLayoutError, match=r"bad\.txt:1: expected ranges"):
        read_kth_sequences(bad)
    with pytest.raises(DataLayoutError, match="no such file"):
        read_kth_sequences(tmp_path / "absent.txt")


def test_clips_come_from_within_the_sub_sequences() -> None:
    """Training clips never take a frame between two sub-sequences; the test gives a stack at
    the start of each sub-sequence that holds a clip (the too-short one gives none)."""
    segments = ((0, 30), (40, 80), (90, 95))  # frames 30-39 and 80-89: no action
    video = Video(Path("v.avi"), 0, "01", segments)
    videos = VideoSet((video,), ("boxing",))
    source = lambda path: np.broadcast_to(  # noqa: E731  every frame holds its own index
        np.arange(100, dtype=np.float32)[:, None, None, None], (100, 1, 4, 4)
    )
    train = ClipDataset(videos, source, frames=8, crop=4, train=True, scales=(1.0,))
    torch.manual_seed(0)
    seen = set()
    for _ in range(200):
        frames = train[0][0][:, 0].round().int()  # (8, 4, 4)
        first, last = int(frames.min()), int(frames.max())
        assert last - first == 7 and any(a <= first and last < b for a, b in segments[:2])
        seen.add(first < 30)
    assert seen == {True, False}  # both usable sub-sequences are drawn from
    test = ClipDataset(videos, source, frames=8, crop=4, train=False)
    assert test.items == [(0, 0), (0, 40)]


def test_the_real_kth_clips_split_by_person(tmp_path) -> None:
    if not (REAL_VIDEO / "kth").is_dir():
        pytest.skip(f"no real KTH clips at {REAL_VIDEO / 'kth'} (../shared/real-video is absent)")
    sequences = REAL_VIDEO / "splits" / "kth" / "00sequences.txt"
    splits = _folds(REAL_VIDEO / "kth", 2, sequences=sequences)
    _assert_cross_validated(splits)
    train, test = splits[0]
    assert len(train) + len(test) == 14 and all(len(v.segments) == 4 for v in train + test)
    every_person = _folds(REAL_VIDEO / "kth", "persons", sequences=sequences)
    _assert_cross_validated(every_person)  # 12 folds: each person held out once
    held_out = [sorted({v.group for v in test}) for _, test in every_person]
    assert held_out == [[p] for p in ["01", "03", "04", "07", "09", "14", "15", "16", "20",
                                      "21", "23", "25"]]  # fmt: skip


def test_new_options_at_their_defaults_keep_the_committed_by_person_fingerprints(
    compose_config,
) -> None:
    """task.frame_control (null) and task.videos.folds (2) leave a committed kth_person run's
    identity as it was; folds=persons is another run."""
    records = sorted((REPO / "results/learning/kth_person").glob("*/run.json"))
    if not records:
        pytest.skip("no committed kth_person records")
    record = json.loads(records[0].read_text())
    overrides = [o for o in record["overrides"] if not o.startswith("threads")]
    assert run_identity(compose_config(*overrides))[1] == record["fingerprint"]
    other = run_identity(compose_config(*overrides, "task.videos.folds=persons"))[1]
    assert other != record["fingerprint"]


@pytest.mark.slow  # two folds of debug=tiny training: seconds
def test_a_cross_validated_run_pools_its_folds(compose_config, tmp_path) -> None:
    root = write_synthetic_kth(tmp_path / "kth", persons=4, scenarios=1, frames=40, height=30,
                               width=40)  # fmt: skip
    out = tmp_path / "run"
    overrides = ("experiment=kth_person", "debug=tiny", f"task.data_root={root}",
                 "task.videos.sequences=null", f"task.cache_dir={tmp_path / 'cache'}",
                 "task.logger=", f"out_dir={out}")  # fmt: skip
    metrics = run(compose_config(*overrides))
    record = read_record(out / "run.json")
    assert record["data"]["source"] == "real clips, split by person"
    assert record["data"]["label"] == "real clips (12 videos, 3 classes), split by person"
    assert "cross-validated over 2 folds" in record["data"]["split"]
    assert record["data"]["test_videos"] == 12 and metrics["eval/chance"] == pytest.approx(1 / 3)
    matrix = np.array(json.loads((out / "confusion.json").read_text())["matrix"])
    folds = [np.array(json.loads((out / f"fold{k}/confusion.json").read_text())["matrix"])
             for k in (0, 1)]  # fmt: skip
    assert (matrix == folds[0] + folds[1]).all() and matrix.sum() == 12
    assert metrics["eval/accuracy"] == pytest.approx(matrix.trace() / 12)
    pooled = json.loads((out / "predictions.json").read_text())["videos"]  # each video once
    assert sorted(e["video"] for e in pooled) == sorted(
        p.name.removesuffix("_uncomp.avi") for c in ACTIONS for p in (root / c).glob("*.avi")
    )
    assert {e["fold"] for e in pooled} == {0, 1} and all(len(e["items"]) == 1 for e in pooled)
    assert metrics["eval/video_accuracy"] == np.mean([e["predicted"] == e["true"] for e in pooled])
    assert metrics["eval/item_accuracy"] == metrics["eval/accuracy"]
    # a run stopped after its first fold trains only the second when it resumes
    (out / "fold1" / "fold.json").unlink()
    (out / "run.json").write_text(
        json.dumps({**json.loads((out / "run.json").read_text()), "status": "interrupted"})
    )
    before = (out / "fold0" / "fold.json").stat().st_mtime_ns
    resumed = run(compose_config(*overrides))
    assert resumed["eval/fold0/accuracy"] == metrics["eval/fold0/accuracy"]
    assert (out / "fold0" / "fold.json").stat().st_mtime_ns == before
    assert (out / "fold1" / "fold.json").is_file()


@pytest.mark.slow  # 12 folds of debug=tiny training on the 14 real videos: about 10 s of CPU
def test_every_real_person_held_out_once_keeps_each_video_once(compose_config, tmp_path) -> None:
    if not (REAL_VIDEO / "kth").is_dir():
        pytest.skip(f"no real KTH clips at {REAL_VIDEO / 'kth'} (../shared/real-video is absent)")
    out = tmp_path / "run"
    metrics = run(compose_config(
        "experiment=kth_person", "debug=tiny", "task.videos.folds=persons",
        f"task.data_root={REAL_VIDEO / 'kth'}",
        f"task.videos.sequences={REAL_VIDEO / 'splits/kth/00sequences.txt'}",
        f"task.cache_dir={tmp_path / 'cache'}", "task.logger=", f"out_dir={out}",
    ))  # fmt: skip
    pooled = json.loads((out / "predictions.json").read_text())["videos"]
    assert len(pooled) == 14 and len({e["video"] for e in pooled}) == 14
    assert {e["fold"] for e in pooled} == set(range(12))
    assert read_record(out / "run.json")["data"]["folds"] == 12
    assert all(len(e["items"]) == 4 and len(e["soft_vote"]) == 3 for e in pooled)
    assert {e["scenario"] for e in pooled if e["true"] == "boxing"} == {"d1", "d3", "d4"}
    assert metrics["eval/video_accuracy"] == np.mean([e["predicted"] == e["true"] for e in pooled])


def test_a_fold_that_diverged_is_pooled_as_the_run_diverged_whichever_fold_it_was() -> None:
    """A fold's ``train/diverged_*`` reaches the pooled record (the tables list it as diverged)
    whether the first fold diverged or a later one; numbers every fold holds are averaged."""
    from edr.tasks.recognition import fold_means

    calm = {"train/loss": 1.0, "eval/accuracy": 0.5, "data/scale": "demo"}
    wild = {
        "train/loss": 3.0,
        "eval/accuracy": float("nan"),
        "data/scale": "demo",
        "train/diverged_step": 7,
        "train/diverged_epoch": 1,
        "train/diverged_reason": "nan loss",
    }
    for folds, at in (([wild, calm], 0), ([calm, calm, wild], 2)):
        pooled = fold_means(folds)
        assert pooled["train/diverged_step"] == 7 and pooled["train/diverged_fold"] == at
        assert pooled["train/diverged_reason"] == "nan loss" and pooled["data/scale"] == "demo"
        assert pooled["train/loss"] == pytest.approx(
            sum(f["train/loss"] for f in folds) / len(folds)
        )
    assert "train/diverged_step" not in fold_means([calm, calm])
