"""Bad event files, as an adversarial user brings them (issue 36): each is refused in one line
naming the file and what is wrong, before any training, and nothing is binned beyond what is used."""

from __future__ import annotations

import re
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from edr.data.events import RecordingError, read_recording, write_recording
from edr.data.events.jaer import write_aedat2
from edr.representations.dvs import EVENT_DTYPE
from edr.tasks.dvs_transfer import _event_clip, dvs_transfer
from event_files import npz_recording

CLASSES = ("boxing", "walking")


def _events(t, x=None, y=None, p=None) -> np.ndarray:
    events = np.zeros(len(t), EVENT_DTYPE)
    events["t"] = t
    events["x"] = x if x is not None else 1
    events["y"] = y if y is not None else 2
    events["p"] = p if p is not None else 1
    return events


def _truncated(path: Path) -> Path:
    path.write_bytes(path.read_bytes()[:-3])
    return path


def _header_only_davis346(path: Path) -> Path:
    path.write_bytes(
        b"#!AER-DAT2.0\r\n# AEChip: eu.seebetter.ini.chips.davis.Davis346red\r\n# End Of ASCII\r\n"
    )
    return path


BAD_FILES = {
    "header-only DAVIS346 .aedat": (_header_only_davis346, "no events"),
    "empty .npz": (
        lambda p: npz_recording(p.with_suffix(".npz"), t=[], x=[], y=[], p=[]),
        "no events",
    ),
    "negative timestamp": (lambda p: npz_recording(p.with_suffix(".npz"), t=[-5, 10]), "negative"),
    "negative x": (lambda p: npz_recording(p.with_suffix(".npz"), x=[-1, 2]), r"x = -1 outside"),
    "x = y = 30000": (
        lambda p: npz_recording(p.with_suffix(".npz"), x=[30000, 1], y=[30000, 1]),
        r"x = 30000 outside",
    ),
    "x beyond int16": (
        lambda p: npz_recording(p.with_suffix(".npz"), x=[70000, 1]),
        "outside any sensor",
    ),
    "truncated .npz (BadZipFile)": (
        lambda p: _truncated(npz_recording(p.with_suffix(".npz"))),
        "not a readable .npz",
    ),
    "truncated .aedat": (lambda p: _truncated(write_aedat2(p, _events([1, 2, 3]))), "truncated"),
    "unsorted timestamps": (lambda p: write_aedat2(p, _events([5, 1, 9])), "backwards"),
    "zero-byte file": (lambda p: (p.write_bytes(b""), p)[1], r"empty \(0 bytes\)"),
    "text renamed .aedat": (lambda p: (p.write_text("hello\n"), p)[1], "no known header"),
    "events outside a DVS128": (
        lambda p: npz_recording(p.with_suffix(".npz"), x=[200, 1], sensor=[128, 128]),
        r"x = 200 outside its sensor \(width 128",
    ),
    "y outside a DVS128": (
        lambda p: npz_recording(p.with_suffix(".npz"), y=[3, 128], sensor=[128, 128]),
        r"y = 128 outside its sensor \(height 128: y in 0\.\.127\)",
    ),
}


@pytest.mark.parametrize("case", BAD_FILES)
def test_a_bad_event_file_is_one_line_naming_it(tmp_path, case) -> None:
    make, problem = BAD_FILES[case]
    path = make(tmp_path / "rec.aedat")
    with pytest.raises(RecordingError, match=problem) as caught:
        read_recording(path)
    message = str(caught.value)
    assert message.startswith(f"{path}: ") and "\n" not in message


def test_an_aedat4_file_renamed_aedat_is_read_by_its_header(tmp_path) -> None:
    pytest.importorskip("faery")
    events = _events([1, 5, 9], x=[0, 3, 7], y=[1, 2, 3], p=[1, 0, 1])
    aedat4 = write_recording(tmp_path / "rec.aedat4", events, (8, 8))
    renamed = aedat4.rename(tmp_path / "rec.aedat")
    np.testing.assert_array_equal(read_recording(renamed), events)


def test_a_one_hour_recording_bins_only_the_frames_used() -> None:
    # two events an hour apart: binned whole, 90,000 frames of 128x128 (11 GiB)
    events = _events([0, 3_600_000_000], x=[3, 4], y=[5, 6])
    clip = _event_clip([events], 128, 128, 40_000.0, frames=4, crop=128)
    assert tuple(clip.shape) == (4, 2, 128, 128) and float(clip.sum()) == 1.0


def test_a_long_recording_is_decoded_only_as_far_as_used(tmp_path) -> None:
    t = np.arange(0, 3_600_000_000, 1_000_000)  # one event a second for an hour
    path = write_aedat2(tmp_path / "hour.aedat", _events(t))
    first = read_recording(path, duration_us=160_000)
    assert len(first) == 1 and len(read_recording(path)) == len(t)


def _pretrain_that_must_not_run(tmp_path: Path):
    """A pre-training whose KTH settings name a two-class set; calling it fails the test."""

    def videos(root, train=True):
        return types.SimpleNamespace(classes=CLASSES, videos=[])

    def pretrain(*, out_dir, seed, resume, videos=videos, synthetic=None,
                 data_root=str(tmp_path), cache_dir=str(tmp_path), resize=(32, 32),
                 max_frames=None, frames=4, crop=16):  # fmt: skip
        raise AssertionError("the pre-training ran before the event data was checked")

    return pretrain


DVS_ROOTS = {
    "truncated .npz": lambda d: _truncated(npz_recording(d / "rec.npz")),
    "truncated .aedat": lambda d: _truncated(write_aedat2(d / "rec.aedat", _events([1, 2, 3]))),
    "negative x": lambda d: npz_recording(d / "rec.npz", x=[-3, 1]),
    "header-only .aedat": lambda d: _header_only_davis346(d / "rec.aedat"),
    "empty .npz": lambda d: npz_recording(d / "rec.npz", t=[], x=[], y=[], p=[]),
}


@pytest.mark.parametrize("case", DVS_ROOTS)
def test_dvs_transfer_checks_event_data_before_pretraining(tmp_path, case) -> None:
    root = tmp_path / "dvs"
    for k, action in enumerate(CLASSES):  # a recording of its own: a copy in two is refused
        (root / action).mkdir(parents=True)
        write_aedat2(root / action / "good.aedat", _events([1, 2, 3 + k]))
    bad = DVS_ROOTS[case](root / "walking")
    with pytest.raises(RecordingError, match=str(bad).replace(".", r"\.")):
        dvs_transfer(
            out_dir=tmp_path / "run", seed=0, pretrain=_pretrain_that_must_not_run(tmp_path),
            optimizer=None, dvs_root=str(root),
        )  # fmt: skip


def test_a_folder_of_only_aedat4_recordings_is_read(tmp_path) -> None:
    pytest.importorskip("faery")
    root = tmp_path / "dvs"
    for k, action in enumerate(CLASSES):
        (root / action).mkdir(parents=True)
        for i in range(2):
            write_recording(root / action / f"u{i}.aedat4", _events([1, 2, 3 + k]), (128, 128))
    with pytest.raises(AssertionError, match="pre-training ran"):  # reading got that far
        dvs_transfer(
            out_dir=tmp_path / "run", seed=0, pretrain=_pretrain_that_must_not_run(tmp_path),
            optimizer=None, dvs_root=str(root),
        )  # fmt: skip


def test_without_faery_an_evt2_file_names_the_extra(tmp_path, monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "faery", None)  # import faery: ImportError
    path = tmp_path / "rec.raw"
    path.write_bytes(b"% evt 2.0\n" + bytes(64))
    with pytest.raises(
        RecordingError,
        match=r"rec\.raw: EVT 2\.0: reading it needs faery: pip install 'edr\[events\]'",
    ):
        read_recording(path)


@pytest.mark.parametrize(("compression", "hidden"), [("lz4", "lz4.frame"), ("zstd", "zstandard")])
def test_without_its_decompressor_an_aedat4_file_names_the_extra(
    tmp_path, monkeypatch, compression, hidden
) -> None:
    faery = pytest.importorskip("faery")
    packet = np.zeros(3, faery.EVENTS_DTYPE)
    packet["t"] = [1, 5, 9]
    path = tmp_path / "rec.aedat4"
    faery.events_stream_from_array(packet, dimensions=(8, 8)).to_file(
        path, compression=(compression, 1)
    )
    monkeypatch.setitem(sys.modules, hidden, None)
    with pytest.raises(
        RecordingError,
        match=rf"rec\.aedat4: AEDAT 4: its packets are {compression}-compressed; reading it needs "
        rf"{hidden.split('.')[0]}: pip install 'edr\[events\]'",
    ):
        read_recording(path)


SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "events"


def _shared(name: str) -> bytes:
    if not (SHARED / name).is_file():
        pytest.skip(
            f"real event recordings not found at {SHARED} (the repository's ../shared/events)"
        )
    return (SHARED / name).read_bytes()


@pytest.mark.parametrize(("name", "keep"), [("sample.aedat4", 2000), ("sample.aedat4", 300_001),
                                            ("evt2_sample.raw", 300_001),
                                            ("evt3_sample.raw", 300_001)])  # fmt: skip
def test_a_truncated_real_recording_is_one_line(tmp_path, name, keep) -> None:
    data = _shared(name)
    pytest.importorskip("lz4" if name.endswith(".aedat4") else "faery")
    path = tmp_path / name
    path.write_bytes(data[:keep])
    with pytest.raises(RecordingError, match=r"(truncated|cannot be decoded)") as caught:
        read_recording(path)
    assert str(caught.value).startswith(f"{path}: ") and "\n" not in str(caught.value)


LZ4_FRAME_MAGIC = b"\x04\x22\x4d\x18"
BAD_AEDAT4 = {  # the shared recording, altered: (how, what its one line says)
    "its packets' LZ4 frames garbled": (
        lambda data: data.replace(LZ4_FRAME_MAGIC, bytes(4)),
        r"the packet at byte \d+ cannot be decoded \(.*frameType_unknown",
    ),
    "no events stream": (
        lambda data: data.replace(b">EVTS</attr>", b">FRME</attr>"),
        r"no events stream \('EVTS'\)",
    ),
    "not AEDAT 4 after its magic": (
        lambda data: data[:14] + bytes(64),
        "its header cannot be decoded",
    ),
}


@pytest.mark.parametrize("case", BAD_AEDAT4)
def test_a_corrupt_aedat4_file_is_one_line(tmp_path, case) -> None:
    alter, problem = BAD_AEDAT4[case]
    data = _shared("sample.aedat4")
    pytest.importorskip("lz4")
    path = tmp_path / "rec.aedat4"
    path.write_bytes(alter(data))
    with pytest.raises(
        RecordingError, match=rf"^{re.escape(str(path))}: AEDAT 4: {problem}"
    ) as caught:
        read_recording(path)
    assert "\n" not in str(caught.value)


@pytest.mark.slow
@pytest.mark.parametrize("task", ["event_camera", "dvs_transfer"])
def test_edr_run_refuses_a_bad_recording_in_one_line_before_work(cli, tmp_path, task) -> None:
    recordings = tmp_path / "dvs"
    for k, action in enumerate(("boxing", "handclapping", "handwaving", "jogging", "running",
                                "walking")):  # fmt: skip
        (recordings / action).mkdir(parents=True)
        write_aedat2(recordings / action / "good.aedat", _events([1, 2, 3 + k]))
    bad = _truncated(write_aedat2(recordings / "walking" / "bad.aedat", _events([1, 2, 3])))
    setting = f"task.events={bad}" if task == "event_camera" else f"task.dvs_root={recordings}"
    run_dir = tmp_path / "run"
    result = cli("edr-run", f"task={task}", setting, "debug=tiny", f"hydra.run.dir={run_dir}",
                 cwd=tmp_path, env={"EDR_CACHE": str(tmp_path / "cache")})  # fmt: skip
    output = result.stdout + result.stderr
    assert result.returncode == 2 and "Traceback" not in output, output[-3000:]
    assert f"{bad}: AEDAT 2.0: truncated" in output
    assert not (run_dir / "pretrain").exists()  # refused before the pre-training


def test_a_truncated_hdf5_file_is_one_line(tmp_path) -> None:
    h5py = pytest.importorskip("h5py")
    path = tmp_path / "events.h5"
    with h5py.File(path, "w") as f:
        for k in "xytp":
            f[f"events/{k}"] = np.arange(10_000)
    _truncated(path)
    with pytest.raises(RecordingError, match=r"events\.h5: HDF5") as caught:
        read_recording(path)
    assert "\n" not in str(caught.value)
