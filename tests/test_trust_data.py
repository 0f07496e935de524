"""Hostile event files and video folders (issue 71): each is refused in one line naming the file
and what is wrong (no traceback, nothing written), or read whole; never wrapped, never dropped
without a word, never read into memory beyond a bound."""

from __future__ import annotations

import os
import struct
import tracemalloc
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from edr.checks.config import ConfigError
from edr.data import datasets
from edr.data.events import (
    RecordingError,
    list_recordings,
    read_recording,
    recording_sensor_size,
    write_recording,
)
from edr.data.events import recording as recording_module
from edr.data.events.checks import EVENT_DTYPE
from edr.data.events.jaer import write_aedat2
from edr.data.video import write_video
from event_files import npz_recording

EVT3_HEADER = b"% evt 3.0\n% format EVT3;height=480;width=640\n% end\n"


def _events(n: int = 3, start: int = 1) -> np.ndarray:
    events = np.zeros(n, EVENT_DTYPE)
    events["t"] = np.arange(start, start + n)
    events["x"], events["y"], events["p"] = 1, 2, 1
    return events


def _evt3(path: Path, words: list[int], header: bytes = EVT3_HEADER) -> Path:
    """An EVT 3.0 file: ``header``, then time 0, row 5 and ``words`` (16-bit)."""
    body = [0x8000, 0x6000, 0x0005, *words]
    path.write_bytes(header + np.array(body, "<u2").tobytes())
    return path


def _aedat31(path: Path, t: list[int], header: bytes = b"#!END-HEADER\r\n") -> Path:
    """An AEDAT 3.1 file of one polarity packet of events at ``t`` (int32), valid, x 1, y 2."""
    data = [1 | (1 << 1) | (2 << 2) | (1 << 17)] * len(t)
    events = np.zeros(len(t), [("data", "<u4"), ("t", "<i4")])
    events["data"], events["t"] = data, t
    packet = struct.pack("<hhiiiiii", 1, 0, 8, 4, 0, len(t), len(t), len(t))
    path.write_bytes(b"#!AER-DAT3.1\r\n" + header + packet + events.tobytes())
    return path


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


# ---- reading: (a file maker, the file's name, what its one line says) ---------------------------
BAD_READS: dict[str, tuple[Callable[[Path], Path], str]] = {
    "EVT 3.0 vector run to x 65,636 (was read as x 100)": (
        lambda p: _evt3(p / "far.raw", [0x3000, *[0x4000] * 5469, 0x4000 | 1 << 8]),
        r"x = 65636 outside any EVT 3\.0 sensor \(x in 0\.\.2047\)",
    ),
    "EVT 3.0 vector run just past x 2047": (
        lambda p: _evt3(p / "edge.raw", [0x3000 | 2040, 0x4FFF]),
        r"x = 2051 outside any EVT 3\.0 sensor",
    ),
    "EVT 3.0 event beyond its stated width": (
        lambda p: _evt3(p / "wide.raw", [0x2000 | 700]),
        r"x = 700 outside its sensor \(width 640",
    ),
    "'%' header line of 2 MiB without a line end": (
        lambda p: _write(p / "noline.raw", b"% evt 3.0" + b"x" * (2 << 20)),
        r"a '%' header line runs past 64 KiB without a line end",
    ),
    "'%' header of 2 MiB of short lines": (
        lambda p: _write(p / "long.raw", b"% evt 3.0\n" + (b"%" + b"a" * 999 + b"\n") * 1100),
        r"its '%' header runs past 1 MiB",
    ),
    "'#' AEDAT 2.0 header of 2 MiB of lines": (
        lambda p: _write(p / "long.aedat", b"#!AER-DAT2.0\r\n" + (b"#" * 999 + b"\r\n") * 1100),
        r"its '#' header runs past 1 MiB",
    ),
    "AEDAT 4 header stating 2 GiB": (
        lambda p: _write(p / "big.aedat4", b"#!AER-DAT4.0\r\n" + struct.pack("<I", 1 << 31)),
        r"its header states 2,147,483,648 bytes",
    ),
    "EVT 3.0 header cut before its first line end": (
        lambda p: _write(p / "cut.raw", b"% evt 3.0"),
        r"EVT 3\.0: no events \(a header only\)",
    ),
    "EVT 2.0 header cut inside a line": (
        lambda p: _write(p / "cut2.raw", b"% evt 2.0\n% format EVT2;wid"),
        r"EVT 2\.0: no events \(a header only\)",
    ),
    "DAT header cut inside a line": (
        lambda p: _write(p / "cut.dat", b"% Version 2\n% Date 2017"),
        r"DAT: truncated inside its header",
    ),
    "AEDAT 2.0 header cut inside its chip line": (
        lambda p: _write(p / "cut.aedat", b"#!AER-DAT2.0\r\n# AEChip: eu.seebetter.ini.chi"),
        r"AEDAT 2\.0: truncated: 30 bytes of events is not a multiple of 8",
    ),
    "AEDAT 3.1 header cut before its end line": (
        lambda p: _write(p / "cut.aedat3", b"#!AER-DAT3.1\r\n#Source 1: DAVIS346\r\n"),
        r"AEDAT 3\.1: its header never ends",
    ),
    "AEDAT 4 header cut inside its size": (
        lambda p: _write(p / "cut.aedat4", b"#!AER-DAT4.0\r\n\x10\x00"),
        r"AEDAT 4: truncated inside its header",
    ),
    "AEDAT 4 header cut inside its flatbuffer": (
        lambda p: _write(
            p / "cut2.aedat4", b"#!AER-DAT4.0\r\n" + struct.pack("<I", 64) + b"\0" * 9
        ),
        r"AEDAT 4: truncated inside its header \(of 82 bytes\)",
    ),
    "HDF5 cut after its signature": (
        lambda p: _write(p / "cut.h5", b"\x89HDF\r\n\x1a\n" + b"\0" * 8),
        r"HDF5: cannot be (opened|read)",
    ),
    "N-MNIST cut inside an event": (
        lambda p: _write(p / "cut.bin", bytes(7)),
        r"N-MNIST: truncated: 7 bytes is not a multiple of 5",
    ),
    "AEDAT 3.1 negative timestamp": (
        lambda p: _aedat31(p / "neg.aedat", [-5, 3]),
        r"AEDAT 3\.1: timestamp -5 µs is negative",
    ),
    ".npz polarity 2": (
        lambda p: npz_recording(p / "p2.npz", p=[1, 2]),
        r"p = 2 is not a polarity",
    ),
    ".npz polarity -1": (
        lambda p: npz_recording(p / "pm.npz", p=[-1, 1]),
        r"p = -1 is not a polarity",
    ),
    ".npz zero-size sensor": (
        lambda p: npz_recording(p / "zero.npz", sensor=[0, 34]),
        r"sensor must be \(height, width\) >= 1",
    ),
    "EVT 3.0 header of a 0x0 sensor": (
        lambda p: _evt3(p / "zero.raw", [0x2001], b"% evt 3.0\n% geometry 0x0\n% end\n"),
        r"sensor 0x0 \(width x height\) outside 1\.\.2048",
    ),
    ".npz timestamps going backwards": (
        lambda p: npz_recording(p / "back.npz", t=[10, 5], x=[1, 1], y=[1, 1], p=[1, 1]),
        None,  # the suite's own lists may come unsorted: sorted, not refused
    ),
}


@pytest.mark.parametrize("case", BAD_READS)
def test_a_hostile_event_file_is_one_line_naming_it(tmp_path, case) -> None:
    make, problem = BAD_READS[case]
    path = make(tmp_path)
    if problem is None:
        assert np.all(np.diff(read_recording(path)["t"]) >= 0)
        return
    with pytest.raises(RecordingError, match=problem) as caught:
        read_recording(path)
    text = str(caught.value)
    assert text.startswith(f"{path}: ") and "\n" not in text and len(text) < 400


def test_an_out_of_range_x_is_never_wrapped_into_the_sensor(tmp_path) -> None:
    """issue 71: x = 65,636 came back as x = 100 (int16); the same word run below 2048 reads."""
    near = _evt3(tmp_path / "near.raw", [0x3000, *[0x4000] * 10, 0x4000 | 1 << 3])
    assert read_recording(near)["x"].tolist() == [123]


def test_a_header_without_a_line_end_is_refused_within_a_bounded_read(tmp_path) -> None:
    """issue 71: 100 MB without a line end took 1.3 GB before its refusal."""
    path = _write(tmp_path / "noline.raw", b"%" + b"x" * (8 << 20))
    with pytest.raises(RecordingError):  # warm: imports and numba outside the trace
        read_recording(path)
    tracemalloc.start()
    try:
        with pytest.raises(RecordingError, match="without a line end"):
            recording_sensor_size(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20


@pytest.mark.parametrize("suffix", [".npz", ".raw", ".aedat"])
@pytest.mark.parametrize("duration", [None, 1e6])
def test_more_events_than_a_read_holds_are_one_line_naming_the_limit(
    tmp_path, monkeypatch, suffix, duration
) -> None:
    """issue 71: a dense 20 MB EVT 3.0 file was decoded whole (2.0 GB; 3.5 GB from a class
    folder, read for its first frames); here the limit is 4 events."""
    if suffix == ".raw":
        pytest.importorskip("faery")
    path = write_recording(tmp_path / f"dense{suffix}", _events(10), (8, 8))
    monkeypatch.setattr(recording_module, "MAX_READ_EVENTS", 4)
    with pytest.raises(RecordingError, match=r"more than 4 events .*: cut it into shorter") as e:
        read_recording(path, duration)
    assert "\n" not in str(e.value)
    monkeypatch.setattr(recording_module, "MAX_READ_EVENTS", 10)
    assert len(read_recording(path, duration)) == 10


# ---- writing: what is not events, or not a sensor -------------------------------------------------
def _missing_p() -> np.ndarray:
    return np.zeros(3, [("t", "i8"), ("x", "i2"), ("y", "i2")])


BAD_WRITES: dict[str, tuple[Callable[[], object], tuple[int, int] | object, str]] = {
    "a float array": (lambda: np.zeros(5), (8, 8), r"got float64 of shape \(5,\)"),
    "a 2-d integer array": (lambda: np.zeros((3, 4), np.int64), (8, 8), r"got int64 of shape"),
    "a list of tuples": (lambda: [(1, 1, 1, 1)], (8, 8), r"got a list"),
    "a dict of columns": (lambda: {k: np.zeros(2, int) for k in "txyp"}, (8, 8), r"got a dict"),
    "a structured array without p": (_missing_p, (8, 8), r"fields t, x, y, p"),
    "a 2-d structured array": (lambda: _events(4).reshape(2, 2), (8, 8), r"of shape \(2, 2\)"),
    "a zero-size sensor": (lambda: _events(3), (0, 8), r"sensor 8x0 \(width x height\) outside"),
    "a sensor of one side": (lambda: _events(3), (8,), r"sensor \(8,\) is not \(height, width\)"),
    "a sensor of floats": (lambda: _events(3), (8.5, 8), r"is not \(height, width\), two int"),
    "no sensor": (lambda: _events(3), None, r"sensor None is not \(height, width\)"),
}


@pytest.mark.parametrize("suffix", [".aedat", ".raw", ".aedat4", ".npz"])
@pytest.mark.parametrize("case", BAD_WRITES)
def test_a_writer_refuses_what_is_not_events_in_one_line(tmp_path, case, suffix) -> None:
    make, sensor, problem = BAD_WRITES[case]
    path = tmp_path / f"rec{suffix}"
    with pytest.raises(RecordingError, match=problem) as caught:
        write_recording(path, make(), sensor)  # type: ignore[arg-type]
    assert str(caught.value).startswith(f"{path}: ") and "\n" not in str(caught.value)
    assert not list(tmp_path.iterdir())


def test_the_aedat2_writer_refuses_a_plain_array_in_one_line(tmp_path) -> None:
    """issue 71: an IndexError traceback."""
    with pytest.raises(RecordingError, match=r"AEDAT 2\.0: events must be a 1-d structured"):
        write_aedat2(tmp_path / "rec.aedat", np.arange(6))
    assert not list(tmp_path.iterdir())


# ---- folders of classes: each file in one class, each class with files ---------------------------
def _recordings(root: Path) -> Path:
    for k, action in enumerate(("boxing", "walking")):
        (root / action).mkdir(parents=True)
        npz_recording(root / action / "own.npz", t=[0, 10 + k])
    return root


SHARED_RECORDINGS = {
    "a hard link": lambda a, b: os.link(a, b),
    "a symbolic link": lambda a, b: b.symlink_to(a),
    "a copy": lambda a, b: b.write_bytes(a.read_bytes()),
}


@pytest.mark.parametrize("how", SHARED_RECORDINGS)
def test_a_recording_filed_under_two_classes_is_refused_naming_both(tmp_path, how) -> None:
    root = _recordings(tmp_path / "dvs")
    SHARED_RECORDINGS[how](root / "boxing" / "own.npz", root / "walking" / "again.npz")
    with pytest.raises(ConfigError, match=r"own\.npz \(boxing\) and .*again\.npz \(walking\)"):
        list_recordings(root, ("boxing", "walking"))


def _video(path: Path, shade: int = 0) -> Path:
    return write_video(path, np.full((4, 8, 8), shade, np.uint8))


def _kth(root: Path) -> Path:
    for k, action in enumerate(datasets.KTH_ACTIONS):
        _video(root / action / f"person01_{action}_d1_uncomp.avi", 20 * k)
    return root


def _ucf(root: Path, classes: str = "1 A\n2 B\n", listed: tuple[str, ...] = ("A", "B")) -> Path:
    for k, name in enumerate(("A", "B")):
        _video(root / name / f"v_{name}_g01_c01.avi", 40 * k)
    lists = root / "ucfTrainTestlist"
    lists.mkdir()
    (lists / "classInd.txt").write_text(classes)
    entries = [f"{n}/v_{n}_g01_c01.avi" for n in listed]
    for split in (1, 2, 3):
        (lists / f"trainlist0{split}.txt").write_text("".join(f"{e} 1\n" for e in entries))
        (lists / f"testlist0{split}.txt").write_text("".join(f"{e}\n" for e in entries))
    return root


def _kth_two_actions(root: Path) -> Callable[[], object]:
    _kth(root)
    os.link(root / "boxing/person01_boxing_d1_uncomp.avi",
            root / "walking/person02_walking_d1_uncomp.avi")  # fmt: skip
    return lambda: datasets.kth(root, protocol="time")


def _kth_copy(root: Path) -> Callable[[], object]:
    _kth(root)
    copy = root / "running/person07_running_d2_uncomp.avi"
    copy.write_bytes((root / "jogging/person01_jogging_d1_uncomp.avi").read_bytes())
    return lambda: datasets.kth(root)


def _ucf_linked(root: Path) -> Callable[[], object]:
    _ucf(root)
    (root / "B" / "v_B_g02_c01.avi").symlink_to(root / "A" / "v_A_g01_c01.avi")
    return lambda: datasets.ucf101(root, protocol="time")


def _ucf_empty_listed(root: Path) -> Callable[[], object]:
    _ucf(root, "1 A\n2 B\n3 C\n")
    return lambda: datasets.ucf101(root)


def _ucf_empty_folder(root: Path) -> Callable[[], object]:
    _ucf(root)
    (root / "C").mkdir()
    return lambda: datasets.ucf101(root, protocol="time")


def _ucf_case_twice(root: Path) -> Callable[[], object]:
    _ucf(root, "1 A\n2 B\n3 a\n")
    return lambda: datasets.ucf101(root)


BAD_FOLDERS = {
    "KTH video hard-linked under two actions": (
        _kth_two_actions,
        r"boxing_d1_uncomp\.avi \(boxing\) and .*person02_walking_d1_uncomp",
    ),
    "KTH video copied under another action": (
        _kth_copy,
        r"jogging_d1_uncomp\.avi \(jogging\) and .*running_d2_uncomp\.avi \(running\)",
    ),
    "UCF-101 clip linked into another class": (
        _ucf_linked,
        r"v_A_g01_c01\.avi \(A\) and .*v_B_g02_c01\.avi \(B\) are the same video",
    ),
    "UCF-101 class of classInd.txt without a listed video": (
        _ucf_empty_listed,
        r"trainlist01\.txt lists no video of the classes C",
    ),
    "UCF-101 empty class folder (split in time)": (
        _ucf_empty_folder,
        r"C: an empty class folder: every class needs videos",
    ),
    "UCF-101 class listed twice, in another case": (
        _ucf_case_twice,
        r"classInd\.txt:3: class a is listed twice \(as A before\)",
    ),
}


@pytest.mark.parametrize("case", BAD_FOLDERS)
def test_a_hostile_video_folder_is_refused_in_one_line(tmp_path, case) -> None:
    make, problem = BAD_FOLDERS[case]
    load = make(tmp_path / "data")
    with pytest.raises(ConfigError, match=problem) as caught:
        load()
    assert "\n" not in str(caught.value)


def test_upper_case_avi_videos_are_read_not_dropped(tmp_path) -> None:
    """issue 71: a class whose files end in .AVI was dropped without a word."""
    root = _ucf(tmp_path / "ucf")
    (root / "B" / "v_B_g01_c01.avi").rename(root / "B" / "v_B_g01_c01.AVI")
    _video(root / "B" / "v_B_g02_c01.AVI", 99)
    split = datasets.ucf101(root, protocol="time")
    assert split.classes == ("A", "B") and len(split) == 3
    kth = _kth(tmp_path / "kth")
    _video(kth / "boxing" / "person02_boxing_d1_uncomp.AVI", 7)
    assert len(datasets.kth(kth, protocol="time")) == 7


def test_a_ucf101_subset_may_leave_classes_without_clips(tmp_path) -> None:
    root = _ucf(tmp_path / "ucf", "1 A\n2 B\n3 C\n")
    assert datasets.ucf101(root, subset=True).classes == ("A", "B", "C")
