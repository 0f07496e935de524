"""Issue 36, values and video data: every bad value refused in one line before work, every bad
video named in one line, and training that stops being numbers recorded as diverged."""

from __future__ import annotations

import json
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

import edr.tasks.recognition as recognition
from edr.checks.config import ConfigError
from edr.data.datasets import kth, ucf101
from edr.data.synthetic import write_synthetic_kth
from edr.data.video import read_video, write_video
from edr.evaluate import main as evaluate_main
from edr.representations import EDR
from edr.representations.base import FULL_SCALE
from edr.run import run
from edr.store.checkpoints import ChangedData

TINY_KTH = ("task=kth", "debug=tiny")
LONG_NAME = "n" * 300  # past NAME_MAX (255) everywhere


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("cache")  # generated data shared by the tests of this module


@pytest.fixture(scope="module")
def kth_root(tmp_path_factory) -> Path:
    """A tiny KTH layout (4 persons, 1 scenario, 6 frames of 24x32): 24 videos."""
    root = tmp_path_factory.mktemp("kth") / "KTH"
    return write_synthetic_kth(root, persons=4, scenarios=1, frames=6, height=24, width=32)


@pytest.fixture
def kth_copy(kth_root, tmp_path) -> Path:
    return Path(shutil.copytree(kth_root, tmp_path / "KTH"))


# ---- values refused before any work (case 6, case 4, case 2's ranges) ---------------------
REFUSED = {
    "unknown task key": ((*TINY_KTH, "+task.new_key=1"), "task.new_key: not a setting"),
    "unknown key in a mapping of nodes": (
        ("task=event_camera", "debug=tiny", "+task.representations.edr_soft.half_life=2"),
        "task.representations.edr_soft.half_life: not a setting of edr.representations.EDR "
        "(did you mean task.representations.edr_soft.half_lives?)",
    ),
    "a device that is no device": ((*TINY_KTH, "task.device=banana"), "task.device='banana'"),
    "no crop scale": ((*TINY_KTH, "task.scales=[]"), "task.scales=[]: expected a list of at"),
    "a crop scale past the frame": ((*TINY_KTH, "task.scales=[5.0]"), "task.scales=[5.0]"),
    "more threads than cores": ((*TINY_KTH, "threads=100000"), "threads=100000: expected at most"),
    "GrayDiff on one-frame clips": (
        (*TINY_KTH, "representation=graydiff", "task.frames=1"),
        "task.frames=1: expected at least 2",
    ),
    "a KTH split with no test video": (
        (*TINY_KTH, "task.videos.train_fraction=1"),
        "task.videos.train_fraction=1",
    ),
    "DVS transfer fine-tuning on every recording": (
        ("task=dvs_transfer", "debug=tiny", "task.train_fraction=1"),
        "task.train_fraction=1",
    ),
    "DVS transfer leaving a class no fine-tuning recording": (
        ("task=dvs_transfer", "debug=tiny", "task.train_fraction=0.1"),
        "task.train_fraction=0.1 of task.streams_per_class=3",
    ),
    "an unknown simulator setting": (
        ("task=dvs_transfer", "debug=tiny", "+task.simulator.bogus=1"),
        "task.simulator:",
    ),
    "a negative simulator threshold": (
        ("task=dvs_transfer", "debug=tiny", "task.simulator.threshold_on=-1"),
        "task.simulator: DVSSimulator: threshold_on=-1",
    ),
    "a simulator threshold that floods memory": (
        ("task=dvs_transfer", "debug=tiny", "task.simulator.threshold_on=1e-9"),
        "threshold_on=1e-09: expected at least 0.0555 with eps=1",
    ),
    "simulator shot noise that floods memory": (
        ("task=event_camera", "debug=tiny", "task.representations.dvs.shot_noise_hz=1e12"),
        "shot_noise_hz=1e+12: expected at most 2500",
    ),
    "event_camera frames too small": (
        ("task=event_camera", "debug=tiny", "task.height=4"),
        "task.height=4: expected a number >=",
    ),
    "event_camera clip too short for its DVS row": (
        ("task=event_camera", "debug=tiny", "task.frames=1"),
        "task.frames=1: expected at least 2",
    ),
    "a data root past NAME_MAX": (
        (*TINY_KTH, f"task.data_root=/tmp/{LONG_NAME}"),
        "task.data_root=",
    ),
    "a cache folder past PATH_MAX": (
        (*TINY_KTH, f"task.cache_dir=/tmp/{'/'.join(['d' * 200] * 25)}"),
        "a path shorter than",
    ),
    "a video path past NAME_MAX": (
        ("task=event_camera", "debug=tiny", f"task.video=/tmp/{LONG_NAME}.avi"),
        "task.video=",
    ),
    "eps that float32 rounds to 0": ((*TINY_KTH, "representation.eps=1e-50"), "eps=1e-50"),
    "beta whose ratio overflows float32": (
        (*TINY_KTH, "representation.beta=1e10"),
        "expected at most 16",
    ),
    # sizes past any machine's memory (case 4's class: every setting that sizes an array)
    "a frame size past memory": (
        (*TINY_KTH, "task.resize=[1000000,1000000]"),
        "task.resize=[1000000, 1000000], task.frames=8: a clip's 8 decoded frames",
    ),
    "a batch past memory": (
        (*TINY_KTH, "task.batch_size=1000000000"),
        "task.batch_size=1000000000, task.frames=8, task.crop=24: a batch",
    ),
    "a generated video past memory": (
        (*TINY_KTH, "+task.synthetic.height=1000000000"),
        "task.synthetic.frames=16, task.synthetic.height=1000000000, task.synthetic.width=160: "
        "a generated video of 16 frames",
    ),
    "a demo clip past memory": (
        ("task=representation_demo", "debug=tiny", "task.height=10000000", "task.width=10000000"),
        "task.frames=8, task.height=10000000, task.width=10000000: a clip of 8 frames",
    ),
    "an event_camera clip past memory": (
        ("task=event_camera", "debug=tiny", "task.frames=100000000000"),
        "task.frames=100000000000, task.height=48, task.width=64: a clip",
    ),
    "DVS transfer's frame size past memory": (
        ("task=dvs_transfer", "debug=tiny", "task.pretrain.resize=[1000000,1000000]"),
        "task.pretrain.resize=[1000000, 1000000], task.pretrain.frames=8",
    ),
    "Atari envs past memory": (
        ("task=atari", "debug=tiny", "task.env.num_envs=100000000"),
        "task.env.num_envs=100000000, task.loss.rollout_steps=5, task.env.frame_stack=4: the 9",
    ),
    "Atari evaluation games past memory": (
        ("task=atari", "debug=tiny", "task.evaluation.plays=100000000"),
        "task.evaluation.plays=100000000, task.env.frame_stack=4: one step's input",
    ),
    "an output folder with no room for its files": (
        (*TINY_KTH, f"out_dir=/tmp/{'/'.join(['d' * 200] * 19)}"),
        "(room for 2 levels of names under it)",
    ),
}
CACHE_KEY = {"task=kth": "task.cache_dir", "task=dvs_transfer": "task.pretrain.cache_dir"}


@pytest.mark.parametrize("case", REFUSED, ids=list(REFUSED))
def test_a_bad_value_is_refused_in_one_line_before_work(compose_config, tmp_path, cache, case):
    overrides, message = REFUSED[case]
    key = CACHE_KEY.get(overrides[0])
    cache_dir = (f"{key}={cache}",) if key and "cache_dir" not in " ".join(overrides) else ()
    with pytest.raises(ConfigError) as refused:
        run(compose_config(f"out_dir={tmp_path}", *overrides, *cache_dir))
    assert message in str(refused.value) and "\n" not in str(refused.value)
    assert not (tmp_path / "checkpoint.pt").exists() and not (tmp_path / "pretrain").exists()


@pytest.mark.skipif(torch.cuda.is_available(), reason="a machine with a GPU takes cuda")
def test_cuda_without_a_gpu_is_refused(compose_config, tmp_path) -> None:
    with pytest.raises(ConfigError, match=r"task\.device=.cuda.: expected a device this machine"):
        run(compose_config(*TINY_KTH, "task.device=cuda", f"out_dir={tmp_path}"))


@pytest.mark.slow
def test_threads_past_the_cores_end_in_one_line_not_a_crash(cli, tmp_path) -> None:
    """threads=100000 once made torch start 100,000 threads and die (a segfault)."""
    result = cli("edr-run", "threads=100000", "debug=tiny", cwd=tmp_path)
    assert result.returncode == 2, result.stderr[-2000:]
    assert "Traceback" not in result.stderr
    (line,) = [x for x in (result.stdout + result.stderr).splitlines() if "threads=" in x]
    assert "expected at most" in line


# ---- EDR's arithmetic ranges and its input checks (case 2, case 8) --------------------------
def _full_range_clip() -> torch.Tensor:
    clip = torch.zeros(1, 4, 1, 4, 4)  # dark, then full scale, then dark: both extremes
    clip[:, 1:3] = FULL_SCALE
    return clip


@pytest.mark.parametrize(
    "settings",
    [{"eps": 1e-50}, {"eps": 1e-37}, {"beta": 1e10}, {"beta": 16.5},
     {"beta": [9.0, 9.0], "half_lives": [1.0, 3.8], "combine": "sum"},
     {"beta": 1e38, "return_form": "log"}],
    ids=["eps 1e-50", "eps 1e-37", "beta 1e10", "beta 16.5", "summed betas", "log beta 1e38"],
)  # fmt: skip
def test_edr_refuses_eps_and_beta_past_float32(settings) -> None:
    with pytest.raises(ValueError, match=r"EDR: (eps|beta)=.*expected at (least|most)"):
        EDR(**settings)


@pytest.mark.parametrize("fast", [True, False], ids=["fused", "torch"])
@pytest.mark.parametrize(
    "settings",
    [{"eps": 1e-36}, {"beta": 15.9}, {"beta": 1e30, "return_form": "log"},
     {"eps": 1e-50, "out_dtype": "float64"}],
    ids=["eps 1e-36", "beta 15.9", "log beta 1e30", "float64 eps 1e-50"],
)  # fmt: skip
def test_what_edr_accepts_stays_finite_on_every_path(settings, fast) -> None:
    """The ranges are what the arithmetic supports: the extremes they let in give numbers."""
    events = EDR(fast=fast, **settings)(_full_range_clip())
    assert torch.isfinite(events).all() and events.abs().max() > 0


def test_a_wrong_state_object_is_a_value_error() -> None:
    with pytest.raises(ValueError, match="state must be the EDRState"):
        EDR().step(torch.zeros(1, 1, 4, 4), state=torch.zeros(1, 1, 1, 4, 4))


@pytest.mark.parametrize("fast", [True, False], ids=["fused", "torch"])
def test_an_input_past_float32_is_reported_as_such(fast) -> None:
    clip = torch.full((1, 3, 1, 4, 4), 1e300, dtype=torch.float64)
    with pytest.raises(ValueError, match=r"intensities up to 1e\+300, past the largest float32"):
        EDR(fast=fast)(clip)
    with pytest.raises(ValueError, match=r"intensities up to 1e\+300"):
        EDR(fast=fast).step(clip[:, 0])


# ---- video files and data layouts (case 7, case 2) -------------------------------------------
def _boxing(root: Path) -> Path:
    return next((root / "boxing").glob("*.avi"))


def _zero_bytes(root: Path) -> Path:
    bad = _boxing(root)
    bad.write_bytes(b"")
    return bad


def _symlink_loop(root: Path) -> Path:
    loop = root / "boxing" / "person09_boxing_d1_uncomp.avi"
    os.symlink(loop.name, loop)
    return loop


def _stray_name(root: Path) -> Path:
    stray = root / "boxing" / "person01_boxing_d1_uncomp (copy).avi"
    shutil.copy(_boxing(root), stray)
    return stray


def _empty_action(root: Path) -> Path:
    for video in (root / "running").glob("*.avi"):
        video.unlink()
    return root / "running"


def _converted(root: Path) -> Path:
    """A video converted to another container: not read, so its class would silently shrink."""
    video = _boxing(root)
    return video.rename(video.with_suffix(".mp4"))


def _notes(root: Path) -> Path:
    (notes := root / "walking" / "notes.txt").write_text("person 3 left early\n")
    return notes


def _subfolder(root: Path) -> Path:
    (extra := root / "jogging" / "more").mkdir()
    return extra


BAD_KTH = {"zero-byte video": _zero_bytes, "symlink loop": _symlink_loop,
           "stray file name": _stray_name, "empty action folder": _empty_action,
           "a video as .mp4": _converted, "a text file": _notes,
           "a folder in an action folder": _subfolder}  # fmt: skip


@pytest.mark.parametrize("spoil", BAD_KTH.values(), ids=list(BAD_KTH))
def test_a_bad_kth_file_is_one_line_naming_it(kth_copy, spoil) -> None:
    bad = spoil(kth_copy)
    with pytest.raises(ConfigError) as refused:
        kth(kth_copy)
    assert str(bad) in str(refused.value) and "\n" not in str(refused.value)


def test_hidden_files_in_a_kth_folder_are_not_videos(kth_copy, kth_root) -> None:
    (kth_copy / "boxing" / ".DS_Store").write_bytes(b"\0\1")  # what a desktop leaves behind
    (kth_copy / "boxing" / "._person01_boxing_d1_uncomp.avi").write_bytes(b"\0")
    names = [(v.path.name, v.label) for v in kth(kth_copy).videos]
    assert names == [(v.path.name, v.label) for v in kth(kth_root).videos]


@pytest.mark.parametrize("protocol", ["time", "official"])
def test_a_stray_file_in_a_ucf_class_folder_is_named(tmp_path, protocol) -> None:
    """Split in time, every file of a class folder is one of its videos; the official split
    reads the files its lists name, and nothing else."""
    root = _ucf(tmp_path / "UCF-101", "1 Foo\n", "Foo/v_Foo_g01_c01.avi 1\n",
                ["Foo/v_Foo_g01_c01.avi"])  # fmt: skip
    (root / "Foo" / "v_Foo_g02_c01.mp4").write_bytes(b"\0" * 64)
    if protocol == "official":
        assert len(ucf101(root, train=True)) == 1
        return
    with pytest.raises(ConfigError, match=r"v_Foo_g02_c01\.mp4: not a video of the layout"):
        ucf101(root, train=True, protocol="time")


@pytest.mark.parametrize("content", [b"", b"this is not a video\n" * 50], ids=["empty", "text"])
def test_an_unreadable_video_is_one_line_naming_it(tmp_path, content) -> None:
    path = tmp_path / "clip.avi"
    path.write_bytes(content)
    with pytest.raises(ConfigError, match=r"clip\.avi"):
        read_video(path)
    loop = tmp_path / "loop.avi"
    os.symlink(loop.name, loop)
    with pytest.raises(ConfigError, match=r"loop\.avi"):
        read_video(loop)


def test_a_kth_split_with_no_training_video_is_refused(kth_root) -> None:
    with pytest.raises(
        ConfigError, match=r"train_fraction=0\.01 of the 24 videos .* leaves no train"
    ):
        kth(kth_root, train=True, train_fraction=0.01)


def _ucf(root: Path, class_index: str, train_list: str, videos: list[str]) -> Path:
    lists = root / "ucfTrainTestlist"
    lists.mkdir(parents=True)
    (lists / "classInd.txt").write_text(class_index)
    (lists / "trainlist01.txt").write_text(train_list)
    frame = np.zeros((2, 8, 8), np.uint8)
    for name in videos:
        write_video(root / name, frame)
    return root


UCF_CASES = {
    "two classes on one index": (
        "1 Foo\n1 Bar\n", "Foo/v_Foo_g01_c01.avi 1\nBar/v_Bar_g01_c01.avi 1\n",
        ["Foo/v_Foo_g01_c01.avi", "Bar/v_Bar_g01_c01.avi"], r"classInd\.txt:2: index 1",
    ),
    "one class twice": (
        "1 Foo\n2 Foo\n", "Foo/v_Foo_g01_c01.avi 1\n", ["Foo/v_Foo_g01_c01.avi"],
        r"classInd\.txt:2: class Foo is listed twice",
    ),
    "an index missing": (
        "1 Foo\n3 Bar\n", "Foo/v_Foo_g01_c01.avi 1\n", ["Foo/v_Foo_g01_c01.avi"],
        r"classInd\.txt: expected the indices 1 to 2",
    ),
    "a listed video missing": (
        "1 Foo\n", "Foo/v_Foo_g01_c01.avi 1\nFoo/v_Foo_g02_c01.avi 1\n",
        ["Foo/v_Foo_g01_c01.avi"], r"trainlist01\.txt:2 lists Foo/v_Foo_g02_c01\.avi",
    ),
}  # fmt: skip


@pytest.mark.parametrize("case", UCF_CASES, ids=list(UCF_CASES))
def test_a_bad_ucf_list_is_one_line_naming_the_file(tmp_path, case) -> None:
    class_index, train_list, videos, message = UCF_CASES[case]
    root = _ucf(tmp_path / "UCF-101", class_index, train_list, videos)
    with pytest.raises(ConfigError, match=message) as refused:
        ucf101(root, train=True)
    assert "\n" not in str(refused.value)


# ---- training that stops being numbers, data that changed (case 2, case 6) ------------------
def test_a_class_without_training_videos_is_refused(compose_config, tmp_path) -> None:
    root = _ucf(
        tmp_path / "UCF-101", "1 Foo\n2 Bar\n", "Foo/v_Foo_g01_c01.avi 1\n",
        ["Foo/v_Foo_g01_c01.avi", "Bar/v_Bar_g01_c01.avi"],
    )  # fmt: skip
    (root / "ucfTrainTestlist" / "testlist01.txt").write_text("Bar/v_Bar_g01_c01.avi\n")
    with pytest.raises(ConfigError, match="lists no video of the classes Bar that classInd"):
        run(compose_config("task=ucf101", "debug=tiny", f"task.data_root={root}",
                           f"task.cache_dir={tmp_path}/cache", f"out_dir={tmp_path}/run"))  # fmt: skip


@pytest.mark.slow
def test_resuming_on_changed_data_is_refused(compose_config, tmp_path, kth_copy, monkeypatch):
    """Stopped (as SIGTERM stops it) after epoch 1, two classes' videos swapped: the run does not
    go on from a checkpoint trained on other data; restored, it does."""
    overrides = (*TINY_KTH, "representation=fdr", f"task.data_root={kth_copy}",
                 f"task.cache_dir={tmp_path}/cache", f"out_dir={tmp_path}/run")  # fmt: skip
    calls = []

    class StoppedInEpoch2(torch.nn.CrossEntropyLoss):
        def forward(self, logits, labels):
            calls.append(1)
            if len(calls) == 3:  # 2 steps an epoch
                raise KeyboardInterrupt("SIGTERM")
            return super().forward(logits, labels)

    monkeypatch.setattr(recognition.nn, "CrossEntropyLoss", StoppedInEpoch2)
    with pytest.raises(KeyboardInterrupt):
        run(compose_config(*overrides))
    monkeypatch.undo()
    a, b = _boxing(kth_copy), next((kth_copy / "walking").glob("*.avi"))
    a_bytes, b_bytes = a.read_bytes(), b.read_bytes()
    a.write_bytes(b_bytes)
    b.write_bytes(a_bytes)
    with pytest.raises(ChangedData, match="trained on other data") as refused:
        run(compose_config(*overrides))
    assert "\n" not in str(refused.value)
    a.write_bytes(a_bytes)
    b.write_bytes(b_bytes)
    run(compose_config(*overrides))
    record = json.loads((tmp_path / "run" / "run.json").read_text())
    saved = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True)
    assert record["resumed"] and record["data"]["fingerprint"] == saved["data_fingerprint"]


@pytest.mark.parametrize("parameterization", ["log", "bounded"])
def test_a_learnable_edr_whose_values_blow_up_is_recorded_as_diverged(
    compose_config, tmp_path, cache, parameterization
) -> None:
    """Adam at lr 1e6: the first step throws EDR's values out of their ranges (beta past the
    largest that float32 holds, or a value out of its range, depending on the input's scale
    reaching the backbone) while the loss is still a number. Recorded as diverged at that step,
    with the value that left."""
    metrics = run(compose_config(
        *TINY_KTH, "representation.learnable=true", "optimizer=adam", "optimizer.lr=1e6",
        f"representation.parameterization={parameterization}", f"task.cache_dir={cache}",
        f"out_dir={tmp_path}",
    ))  # fmt: skip
    record = json.loads((tmp_path / "run.json").read_text())
    assert record["status"] == "finished" and metrics["train/diverged_step"] == 1
    reason = metrics["train/diverged_reason"]
    assert "left its range" in reason or re.match(r"beta=\S+: expected at most 16", reason), reason
    assert np.isnan(metrics["eval/accuracy"])


def test_dvs_fine_tuning_on_infinite_events_is_recorded_as_diverged(
    compose_config, tmp_path, cache
) -> None:
    metrics = run(compose_config(
        "task=dvs_transfer", "debug=tiny", "task.event_scale=1e300",
        f"task.pretrain.cache_dir={cache}", f"out_dir={tmp_path}",
    ))  # fmt: skip
    assert metrics["train/diverged_step"] == 1 and "loss" in metrics["train/diverged_reason"]
    assert np.isnan(metrics["eval/accuracy"]) and np.isnan(metrics["eval/zero_shot_accuracy"])


@pytest.mark.slow
def test_an_atari_lr_of_1e30_is_recorded_as_diverged(compose_config, tmp_path, capsys) -> None:
    metrics = run(compose_config(
        "task=atari", "debug=tiny", "representation.color=gray", "task.optim.lr=1e30",
        f"out_dir={tmp_path}",
    ))  # fmt: skip
    record = json.loads((tmp_path / "run.json").read_text())
    assert record["status"] == "finished" and metrics["train/diverged_step"] > 0
    assert metrics["eval/plays"] == 0 and np.isnan(metrics["eval/mean"])
    # edr-eval on it: one line naming the run (its networks' outputs are not numbers), and the
    # folder as it was
    files = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    with pytest.raises(SystemExit) as stopped:
        evaluate_main([str(tmp_path), "--plays", "1"])
    assert stopped.value.code == 1
    assert "NaN or inf" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()} == files
