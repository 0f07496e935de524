"""The split in time (``task.videos.protocol=time``): no test frame ever reaches a training clip,
on generated video in KTH's and UCF-101's layouts and on the real KTH clips of
``../shared/real-video`` (skipped where that folder is absent)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from edr.checks.config import ConfigError
from edr.data.clips import ClipDataset, VideoSource
from edr.data.datasets import TimeSplit, VideoSet, kth, ucf101
from edr.data.synthetic import KTH_ACTIONS, write_synthetic_kth, write_synthetic_ucf101
from edr.run import run
from edr.store.records import read_record
from edr.tasks.recognition import load_model
from real_video import REAL_VIDEO

DRAWS = 40  # training clips drawn per video


def _frame_numbers(lengths: dict[Path, int]):
    """A source whose every frame holds its own index: (T, 1, 4, 4) float32."""
    return lambda path: np.broadcast_to(
        np.arange(lengths[path], dtype=np.float32)[:, None, None, None], (lengths[path], 1, 4, 4)
    )


def _assert_split_in_time(train: VideoSet, test: VideoSet, lengths: dict[Path, int], clip: int):
    """Every training clip drawn lies in its video's first part, every test stack in its last,
    and at least ``clip`` frames lie between them; each video gives both."""
    assert train.videos == test.videos and train.time_split and test.time_split
    source = _frame_numbers(lengths)
    torch.manual_seed(0)
    for shuffle in (False, True):
        settings = {"frames": clip, "crop": 4, "control": "shuffled_in_clip" if shuffle else None}
        trained = {v.path: set() for v in train.videos}
        tested = {v.path: set() for v in test.videos}
        train_set = ClipDataset(train, source, train=True, scales=(1.0, 0.66), **settings)
        for index in range(len(train_set)):
            for _ in range(DRAWS):
                frames, _ = train_set[index]  # (clip, 1, 4, 4)
                trained[train.videos[index].path] |= set(
                    frames[:, 0].round().int().unique().tolist()
                )
        test_set = ClipDataset(test, source, train=False, **settings)
        for index, (video, _) in enumerate(test_set.items):
            crops, _ = test_set[index]  # (10, clip, 1, 4, 4)
            tested[test.videos[video].path] |= set(crops[:, :, 0].round().int().unique().tolist())
        for path, length in lengths.items():
            assert trained[path] and tested[path], path
            assert max(trained[path]) + clip < min(tested[path]), (path, length)
            assert max(tested[path]) < length


def test_the_two_parts_of_a_video_stay_a_clip_apart() -> None:
    for clip in (8, 24):
        for length in range(5 * clip, 600, 7):
            train = TimeSplit(True, 0.75).window(length, clip, "v.avi")
            test = TimeSplit(False, 0.75).window(length, clip, "v.avi")
            assert train.start == 0 and test.stop == length
            assert test.start - train.stop == clip and len(train) >= clip <= len(test)
    with pytest.raises(ConfigError, match=r"v\.avi: its 30 frames leave 6 to the test part"):
        TimeSplit(False, 0.75).window(30, 8, "v.avi")


def test_no_test_frame_in_a_training_clip_on_generated_kth_and_ucf101(tmp_path) -> None:
    size = {"frames": 40, "height": 30, "width": 40}
    root = write_synthetic_kth(tmp_path / "kth", persons=1, scenarios=1, **size)
    train, test = (kth(root, train=t, protocol="time") for t in (True, False))
    assert train.classes == KTH_ACTIONS and len(train) == 6
    _assert_split_in_time(train, test, {v.path: 40 for v in train.videos}, clip=8)
    root = write_synthetic_ucf101(tmp_path / "ucf", groups=1, clips=1, **size)
    train, test = (
        ucf101(root, train=t, protocol="time", train_fraction=0.6) for t in (True, False)
    )
    assert len(train.classes) == 6 and len(train) == 6 and not train.index_files
    _assert_split_in_time(train, test, {v.path: 39 for v in train.videos}, clip=8)  # flows: T-1


def test_no_test_frame_in_a_training_clip_on_the_real_kth_clips(tmp_path) -> None:
    if not (REAL_VIDEO / "kth").is_dir():
        pytest.skip(f"no real KTH clips at {REAL_VIDEO / 'kth'} (../shared/real-video is absent)")
    train, test = (kth(REAL_VIDEO / "kth", train=t, protocol="time") for t in (True, False))
    assert set(train.classes) == set(KTH_ACTIONS) and {v.label for v in train.videos} == set(
        range(6)
    )
    decoded = VideoSource(tmp_path, size=(16, 12), gray=True)  # the lengths the pipeline sees
    lengths = {v.path: len(decoded(v.path)) for v in train.videos}
    assert min(lengths.values()) >= 240
    for clip in (8, 24):  # debug=tiny's clips and the demo's
        _assert_split_in_time(train, test, lengths, clip)
        _assert_split_in_time(train, test, {p: n - 1 for p, n in lengths.items()}, clip)  # flows


@pytest.mark.slow  # 13 s on a busy 2-core machine
def test_a_run_split_in_time_says_so_in_its_record(compose_config, tmp_path) -> None:
    """... and a model trained on standardised input (task.normalize_input) loads back whole."""
    root = write_synthetic_kth(tmp_path / "kth", persons=1, scenarios=1, frames=40, height=30,
                               width=40)  # fmt: skip
    out = tmp_path / "run"
    run(compose_config("experiment=kth_real", "debug=tiny", f"task.data_root={root}",
                       "task.shuffle_frames=true", "task.normalize_input=true", "task.epochs=1",
                       f"task.cache_dir={tmp_path / 'cache'}", "task.logger=", f"out_dir={out}"))  # fmt: skip
    data = read_record(out / "run.json")["data"]
    assert data["source"] == "real clips, split in time"
    assert data["label"] == "real clips (6 videos), split in time"
    assert (
        "not the paper's protocol" in data["split"]
        and data["frame_order"] == "shuffled within each clip"
    )
    assert data["train_videos"] == data["test_videos"] == 6 and data["test_clips"] == 6
    model = load_model(out).eval()
    assert model.input_norm is not None and int(model.input_norm.num_batches_tracked) > 0
    clip = torch.randint(0, 255, (2, 8, 1, 24, 24), dtype=torch.uint8)
    assert model(clip).shape == (2, 6)


def test_table4_shows_real_clip_rows_beside_generated_ones_never_averaged() -> None:
    import pandas as pd

    from edr.report.published import load_published
    from edr.report.recognition import table4_kth

    def runs(
        label: str | None, source: str, order: str | None, cell: str, norm: bool | None = None
    ) -> list[dict]:
        return [{"task": "kth", "status": "finished", "fingerprint": f"{cell}{seed}", "cell": cell,
                 "data.fingerprint": source, "data.source": source, "data.label": label,
                 "data.frame_order": order, "config.task.normalize_input": norm,
                 "scale": "demo", "seed": seed, "record": f"{cell}{seed}",
                 "machine": "m", "git": "g", "choices.backbone": "lenet_ftrcn",
                 "choices.representation": "edr", "metrics.eval/accuracy": accuracy,
                 "metrics.eval/chance": 1 / 6}
                for seed, accuracy in enumerate((0.5, 0.7))]  # fmt: skip

    time_split = "real clips (8 videos), split in time"
    frame = pd.DataFrame(
        runs(None, "generated", None, "a")  # a record from before data.label
        + runs("real clips (8 videos), split in time", "real clips, split in time", "in order", "b")
        + runs("real clips (8 videos), split in time", "real clips, split in time", "shuffled", "c")
        + runs("real", "real", "in order", "d")  # the real data set, the paper's protocol
        + runs(time_split, "real clips, split in time", "in order", "e", norm=True)
    )
    table = table4_kth(frame, load_published())
    shown = table.frame.set_index(["Data", "Representation"])
    assert len(shown) == 5 and (shown["Runs (seeds)"] == "2 (0, 1)").all()
    assert (shown["Accuracy (%)"] == "60.0 ± 14.1").all()  # each cell its own two runs
    # the paper's LeNet + FT-RCN EDR number beside every row of that setting, whatever its data
    # (the notes say it is the paper's, on KTH); frames shuffled is no setting of the paper's
    paper = str(load_published()["table4_kth"]["accuracy"]["lenet_ftrcn"]["edr"])
    assert shown.loc[(time_split, "edr (raw input)"), "Published (%)"] == paper
    within_clip = "edr (raw input, frames shuffled within each clip, motion statistics survive)"
    assert shown.loc[(time_split, within_clip), "Published (%)"] == "—"
    assert shown.loc[(time_split, "edr"), "Published (%)"] == paper  # standardised: the default
    assert shown.loc[("generated", "edr (raw input)"), "Published (%)"] == paper
    assert shown.loc[("real", "edr (raw input)"), "Published (%)"] == paper
    assert any("not the paper's protocol" in note for note in table.notes)
    assert any("a reference, not the same measurement" in note for note in table.notes)


def test_the_learnable_blocks_fdr_control_is_the_run_on_edrs_own_data() -> None:
    """A newer run of the same FDR config on other data (speed classes generated again by later
    code) belongs to Table 2, not to the learnable-EDR block, whose control ran on EDR's data;
    so does FDR on that data with its input standardised, where EDR's was raw."""
    import pandas as pd

    from edr.report.recognition import learnable_runs

    def run(ablation: str | None, representation: str, data: str, ended: str,
            standardised: bool = False) -> dict:  # fmt: skip
        fingerprint = f"{ablation}-{representation}-{standardised}"  # one config: one fingerprint
        return {"task": "ucf101", "status": "finished", "fingerprint": fingerprint, "seed": 0,
                "choices.ablation": ablation, "choices.representation": representation,
                "data.fingerprint": data, "scale": "demo", "choices.backbone": "lenet_ftrcn",
                "config.task.normalize_input": standardised if standardised else None,
                "ended_at": ended, "record": f"{fingerprint}-{ended}"}  # fmt: skip

    frame = pd.DataFrame([
        run("learnable_log", "edr", "old data", "2026-12-02"),
        run(None, "fdr", "old data", "2026-12-02"),
        run(None, "fdr", "new data", "2026-12-03"),  # the same config, later, on other data
        run(None, "fdr", "old data", "2026-12-03", standardised=True),
    ])  # fmt: skip
    chosen = learnable_runs(frame)
    control = chosen[chosen["choices.ablation"] == "fdr"]
    assert list(control["data.fingerprint"]) == ["old data"]
    assert list(control["record"]) == ["None-fdr-False-2026-12-02"]
