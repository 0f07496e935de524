"""What every event reader and writer accepts, and the one line it gives for the rest: times
beyond a format's clock, values beyond their fields, sensor sizes, things that are not files,
memory in proportion to the events, arrays of the wrong shape, where AEDAT 2.0's header ends,
and the sensor and frame rate a recording is measured at (docs/events.md, "What a reader and
writer accept")."""

from __future__ import annotations

import os
import re
import struct
import threading
import tracemalloc
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from edr.data.events import (
    RecordingError,
    iter_recording,
    prophesee,
    read_recording,
    recording_sensor_size,
    write_recording,
)
from edr.data.events.checks import EVENT_DTYPE
from event_files import npz_recording

T = 1_605_537_493_718_345  # a real AEDAT 4 camera's clock (DV: µs since 1970)
WRAP = 1 << 24  # EVT 3.0's clock: 24 bits


def _events(t, x=1, y=2, p=1) -> np.ndarray:
    events = np.zeros(len(t), EVENT_DTYPE)
    events["t"], events["x"], events["y"], events["p"] = t, x, y, p
    return events


def _one_line(caught: pytest.ExceptionInfo, path: Path) -> str:
    message = str(caught.value)
    assert message.startswith(f"{path}: ") and "\n" not in message
    return message


def _faery_if(suffix: str) -> None:
    if suffix in (".raw", ".aedat4"):
        pytest.importorskip("faery")


# 1, 2: a camera's clock, written relative to the first event, its origin read back


@pytest.mark.parametrize("start", [T, 1 << 55])
@pytest.mark.parametrize("suffix", [".aedat", ".raw"])
def test_a_camera_clock_round_trips_in_bytes_proportional_to_the_events(
    tmp_path, suffix, start
) -> None:
    _faery_if(suffix)
    events = _events([start, start + 10, start + 3 * WRAP + 7], x=[1, 2, 3])  # EVT 3.0 wraps
    path = write_recording(tmp_path / f"rec{suffix}", events, (128, 128))
    assert path.stat().st_size < 1024  # 765 MB for EVT 3.0 at T when written absolute
    np.testing.assert_array_equal(read_recording(path), events)
    assert [f.name for f in tmp_path.iterdir()] == [path.name]  # no temporary file left


SPANS = {".aedat": ("AEDAT 2.0", 1 << 32), ".raw": ("EVT 3.0", 1 << 55)}


@pytest.mark.parametrize("suffix", SPANS)
def test_a_span_its_clock_cannot_hold_is_refused_before_writing(tmp_path, suffix) -> None:
    _faery_if(suffix)
    name, span = SPANS[suffix]
    path = tmp_path / f"rec{suffix}"
    with pytest.raises(RecordingError, match=rf": {name}: timestamps span {span} µs") as caught:
        write_recording(path, _events([T, T + span]), (128, 128))
    _one_line(caught, path)
    assert not list(tmp_path.iterdir())  # nothing written, not even a temporary file


@pytest.mark.parametrize("suffix", [".raw", ".aedat4"])
def test_a_writer_failing_midway_leaves_no_file(tmp_path, monkeypatch, suffix) -> None:
    faery = pytest.importorskip("faery")

    class HalfWritten:
        def to_file(self, target, **options):
            Path(target).write_bytes(b"% evt 3.0\n" + bytes(1000))
            raise RuntimeError("disk full")

    monkeypatch.setattr(faery, "events_stream_from_array", lambda *a, **k: HalfWritten())
    with pytest.raises(RuntimeError, match="disk full"):
        write_recording(tmp_path / f"rec{suffix}", _events([1, 2]), (8, 8))
    assert not list(tmp_path.iterdir())


def test_a_dat_files_t0_is_read_back(tmp_path) -> None:
    faery = pytest.importorskip("faery")
    packet = np.zeros(3, faery.EVENTS_DTYPE)
    packet["t"], packet["x"], packet["on"] = [T, T + 10, T + 50_000_000], [3, 4, 5], True
    path = tmp_path / "rec.dat"
    faery.events_stream_from_array(packet, dimensions=(64, 32)).to_file(path, zero_t0=True)
    assert b"% T0 " in path.read_bytes()[:100]  # its times are after this one
    np.testing.assert_array_equal(read_recording(path)["t"], packet["t"])


BAD_T0 = {  # a header's stated origin: (file, its one line)
    "EVT 3.0 '% t0 -5'": (
        lambda p: _written(p, b"% evt 3.0\n% geometry 8x8\n% t0 -5\n" + bytes(4)),
        "EVT 3.0: its header's t0 '-5' is not 0..2^62 µs",
    ),
    "AEDAT 2.0 '# t0 1e9'": (
        lambda p: _written(p, b"#!AER-DAT2.0\r\n# t0 1e9\r\n" + bytes(8)),
        "AEDAT 2.0: its header's t0 '1e9' is not 0..2^62 µs",
    ),
}


@pytest.mark.parametrize("case", BAD_T0)
def test_a_time_origin_that_is_no_time_is_refused(tmp_path, case) -> None:
    make, problem = BAD_T0[case]
    path = make(tmp_path / ("rec.raw" if "EVT" in case else "rec.aedat"))
    with pytest.raises(RecordingError, match=re.escape(problem)) as caught:
        read_recording(path)
    _one_line(caught, path)


# 3: values beyond their fields, refused by their value (never wrapped or truncated)


def _aedat4_with_polarity_byte(path: Path, byte: int) -> Path:
    """An uncompressed AEDAT 4 file of three events, the second's ``on`` byte set to ``byte``."""
    faery = pytest.importorskip("faery")
    packet = np.zeros(3, faery.EVENTS_DTYPE)
    packet["t"], packet["x"], packet["y"], packet["on"] = [1, 5, 9], [0, 3, 7], 2, True
    faery.events_stream_from_array(packet, dimensions=(8, 8)).to_file(path, compression=None)
    stored = struct.pack("<qhh?", 5, 3, 2, True)  # DV's event: int64 t, int16 x, y, bool on
    data = path.read_bytes()
    assert data.count(stored) == 1
    path.write_bytes(data.replace(stored, stored[:-1] + bytes([byte])))
    return path


def _written(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def _mvsec(path: Path, rows: list[list[float]]) -> Path:
    """An MVSEC-layout file: ``rows`` (N, 4) of x, y, t (s), p (-1/1) as float64."""
    h5py = pytest.importorskip("h5py")
    with h5py.File(path, "w") as f:
        f["davis/left/events"] = np.asarray(rows, np.float64)
    return path


def _aedat31_of_one_event(path: Path, t: int) -> Path:
    """An AEDAT 3.1 file of one polarity packet (overflow 0) of one valid event at int32 ``t``."""
    packet = struct.pack("<hhiiiiii", 1, 1, 8, 4, 0, 1, 1, 1)  # type, source, size, ..., valid
    event = struct.pack("<Ii", 1 | (1 << 2) | (1 << 17), t)  # valid, y 1, x 1; int32 time
    header = b"#!AER-DAT3.1\r\n#Source 1: DVS128\r\n#!END-HEADER\r\n"
    return _written(path, header + packet + event)


def _dsec(path: Path, x: list[int]) -> Path:
    h5py = pytest.importorskip("h5py")
    with h5py.File(path, "w") as f:
        f["events/t"], f["events/y"] = np.arange(len(x)), np.zeros(len(x), np.uint16)
        f["events/x"], f["events/p"] = np.asarray(x, np.int32), np.ones(len(x), np.uint8)
    return path


BAD_VALUES = {  # a file whose values numpy would narrow silently: (file, its one line)
    "AEDAT 4 polarity byte 2": (
        lambda d: _aedat4_with_polarity_byte(d / "rec.aedat4", 2),
        "AEDAT 4: p = 2 is not a polarity (0 OFF, 1 ON)",
    ),
    "AEDAT 4 polarity byte 255": (
        lambda d: _aedat4_with_polarity_byte(d / "rec.aedat4", 255),
        "AEDAT 4: p = 255 is not a polarity",
    ),
    ".npz float seconds": (
        lambda d: npz_recording(d / "rec.npz", t=[0.25, 0.5]),
        ".npz: t holds float64 values, not integers: timestamps are integer microseconds",
    ),
    ".npz x that int16 wraps to 3": (
        lambda d: npz_recording(d / "rec.npz", x=[-65533, 2]),
        ".npz: x = -65533 outside any sensor (beyond int16)",
    ),
    ".npz p that int8 wraps to 0": (
        lambda d: npz_recording(d / "rec.npz", p=[256, 1]),
        ".npz: p = 256 is not a polarity",
    ),
    "DSEC x beyond 16 bits": (
        lambda d: _dsec(d / "events.h5", [70000, 1]),
        "HDF5: x = 70000 outside any sensor",
    ),
    "MVSEC NaN time (numpy casts it to -2^63)": (  # battery a02
        lambda d: _mvsec(d / "data.hdf5", [[1, 1, 0.0, 1], [2, 2, float("nan"), -1]]),
        "HDF5: t = nan is not a finite number",
    ),
    "MVSEC 1e14 s (1e20 µs, beyond int64)": (  # battery a03
        lambda d: _mvsec(d / "data.hdf5", [[1, 1, 0.0, 1], [2, 2, 1e14, -1]]),
        "HDF5: t = 1e+20 µs, beyond int64",
    ),
    "AEDAT 3.1 int32 time -5 (4294967291 as unsigned)": (  # battery a08
        lambda d: _aedat31_of_one_event(d / "rec.aedat", -5),
        "AEDAT 3.1: timestamp -5 µs is negative",
    ),
}


@pytest.mark.filterwarnings("error")  # numpy's RuntimeWarning on a cast it cannot hold, too
@pytest.mark.parametrize("case", BAD_VALUES)
def test_a_value_beyond_its_field_is_refused_by_its_value(tmp_path, case) -> None:
    _refused_in_one_line(*BAD_VALUES[case], tmp_path)


def _refused_in_one_line(make: Callable[[Path], Path], problem: str, tmp_path: Path) -> None:
    """The file ``make`` writes is refused by :func:`read_recording`, naming ``problem``."""
    path = make(tmp_path)
    with pytest.raises(RecordingError, match=re.escape(problem)) as caught:
        read_recording(path)
    _one_line(caught, path)


def _float_times() -> np.ndarray:
    events = np.zeros(2, [("t", "f8"), ("x", "i2"), ("y", "i2"), ("p", "i1")])
    events["t"] = [0.25, 0.5]  # seconds: integer µs would truncate them to 0
    return events


BAD_WRITES = {  # events a writer would narrow silently: (events, their one line)
    "float t": (_float_times, "t holds float64 values, not integers: timestamps are integer"),
    "p = 2": (lambda: _events([1, 2], p=[1, 2]), "p = 2 is not a polarity"),
}


@pytest.mark.parametrize("suffix", [".aedat", ".raw", ".aedat4", ".npz"])
@pytest.mark.parametrize("case", BAD_WRITES)
def test_a_writer_refuses_values_beyond_their_fields(tmp_path, case, suffix) -> None:
    _faery_if(suffix)
    make, problem = BAD_WRITES[case]
    path = tmp_path / f"rec{suffix}"
    with pytest.raises(RecordingError, match=re.escape(problem)) as caught:
        write_recording(path, make(), (8, 8))
    _one_line(caught, path)
    assert not list(tmp_path.iterdir())


# 3: sensor sizes, bounded in one place for every reader and the writer


def _aedat4_of_width(path: Path, stated: bytes) -> Path:
    """An AEDAT 4 file whose description states a width of ``stated`` (5 digits)."""
    faery = pytest.importorskip("faery")
    packet = np.zeros(2, faery.EVENTS_DTYPE)
    packet["t"] = [1, 2]
    faery.events_stream_from_array(packet, dimensions=(12345, 8)).to_file(path)
    data = path.read_bytes()
    assert data.count(b">12345<") == 1  # the same length: the flatbuffer stays whole
    path.write_bytes(data.replace(b">12345<", b">" + stated + b"<"))
    return path


HUGE_SENSORS = {  # a header stating a sensor beyond its format's side: (file, its size, side)
    ".npz 100000 x 100000": (
        lambda d: npz_recording(d / "rec.npz", sensor=[100_000, 100_000]),
        "100000x100000",
        16384,
    ),
    "AEDAT 4 99999 wide": (
        lambda d: _aedat4_of_width(d / "rec.aedat4", b"99999"),
        "99999x8",
        16384,
    ),
    "EVT 3.0 30000 x 30000": (
        lambda d: _written(d / "rec.raw", b"% evt 3.0\n% geometry 30000x30000\n" + bytes(4)),
        "30000x30000",
        2048,  # 11-bit x and y
    ),
}


@pytest.mark.parametrize("case", HUGE_SENSORS)
def test_a_sensor_beyond_its_formats_side_is_refused(tmp_path, case) -> None:
    make, size, side = HUGE_SENSORS[case]
    path = make(tmp_path)
    problem = f"sensor {size} (width x height) outside 1..{side} on a side"
    for read in (recording_sensor_size, read_recording):
        with pytest.raises(RecordingError, match=re.escape(problem)) as caught:
            read(path)
        _one_line(caught, path)


def test_a_writer_takes_a_sensor_up_to_its_formats_side(tmp_path) -> None:
    events = _events([1, 2], x=[3000, 4095])  # past EVT 3.0's 11-bit x, within int16
    path = write_recording(tmp_path / "rec.npz", events, (8, 4096))
    np.testing.assert_array_equal(read_recording(path), events)
    assert recording_sensor_size(path) == (8, 4096)
    for suffix, side in ((".raw", 2048), (".npz", 16384)):
        path = tmp_path / f"big{suffix}"
        width = 2 * side
        with pytest.raises(RecordingError, match=rf"sensor {width}x8 .* outside 1\.\.{side} "):
            write_recording(path, events, (8, width))
        assert not path.exists()


def test_a_recording_stating_no_sensor_spans_up_to_16384(tmp_path) -> None:
    path = npz_recording(tmp_path / "rec.npz", x=[5000, 16383])  # DAT's 14-bit x reaches this
    assert read_recording(path)["x"].tolist() == [5000, 16383]
    path = npz_recording(tmp_path / "far.npz", x=[5000, 16384])
    with pytest.raises(RecordingError, match=r"x = 16384 outside the largest sensor read"):
        read_recording(path)


# 4: only regular files are opened


def test_a_named_pipe_is_refused_without_blocking(tmp_path) -> None:
    fifo = tmp_path / "rec.aedat"
    os.mkfifo(fifo)
    outcome: list[str] = []

    def read() -> None:
        try:
            read_recording(fifo)
        except RecordingError as error:
            outcome.append(str(error))

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(timeout=20)
    if reader.is_alive():  # blocked in open(): a writer's open releases it, then fail
        with open(fifo, "wb"):
            pass
        reader.join()
        pytest.fail("read_recording blocked on a named pipe")
    assert outcome == [f"{fifo}: event file: not a regular file (a named pipe (FIFO))"]


def test_a_folder_is_refused_as_not_a_file(tmp_path) -> None:
    folder = tmp_path / "rec.aedat"
    folder.mkdir()
    for read in (read_recording, recording_sensor_size):
        with pytest.raises(RecordingError, match=r"not a regular file \(a folder\)") as caught:
            read(folder)
        _one_line(caught, folder)


# 5: memory in proportion to the events, not the words


def _dense_evt3(path: Path, blocks: int) -> np.ndarray:
    """An EVT 3.0 file as dense as the format goes (12 events a word): per µs a row of 1200
    events (TIME_HIGH, TIME_LOW, ADDR_Y, VECT_BASE_X, 100 VECT_12 with every bit set); its
    events."""
    i = np.arange(blocks)
    words = np.empty((blocks, 104), np.uint16)
    words[:, 0], words[:, 1] = 0x8000 | (i >> 12), 0x6000 | (i & 0xFFF)
    words[:, 2], words[:, 3], words[:, 4:] = i % 720, 0x3800, 0x4FFF  # base x 0, ON
    path.write_bytes(b"% evt 3.0\n% format EVT3;width=1280;height=720\n" + words.tobytes())
    return _events(np.repeat(i, 1200), np.tile(np.arange(1200), blocks), np.repeat(i % 720, 1200))


def test_evt3_chunks_are_bounded_by_events_not_words(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(prophesee, "CHUNK_EVENTS", 1000)
    expected = _dense_evt3(tmp_path / "dense.raw", 50)  # 60,000 events in 5,200 words
    sizes = [len(chunk) for chunk in iter_recording(tmp_path / "dense.raw")]
    assert max(sizes) <= 1000 and sum(sizes) == len(expected)  # were 1000 words: 11,500 events
    np.testing.assert_array_equal(read_recording(tmp_path / "dense.raw"), expected)


def test_reading_a_dense_evt3_file_holds_its_events_once(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(prophesee, "CHUNK_EVENTS", 20_000)  # 60 chunks
    expected = _dense_evt3(tmp_path / "dense.raw", 1000)  # 1.2M events, 15.6 MB
    _dense_evt3(tmp_path / "warm.raw", 30)
    read_recording(tmp_path / "warm.raw")  # numba's compiled code loaded outside the trace
    tracemalloc.start()
    try:
        events = read_recording(tmp_path / "dense.raw")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1.2 * events.nbytes  # a list of the chunks and their join: 2x
    np.testing.assert_array_equal(events, expected)


def _dense_class_folder(root: Path, blocks: int) -> int:
    """``root/boxing/dense.raw``: an EVT 3.0 recording of a 64 x 64 sensor, every pixel of
    x < 60 ON at each of ``blocks`` µs (3,840 events in 450 words a µs); how many events."""
    row = [0x0000, 0x3800, *[0x4FFF] * 5]  # ADDR_Y, VECT_BASE_X (x 0, ON), 5 x VECT_12
    words = np.empty((blocks, 2 + 64 * 7), np.uint16)
    i = np.arange(blocks)
    words[:, 0], words[:, 1] = 0x8000 | (i >> 12), 0x6000 | (i & 0xFFF)  # TIME_HIGH, TIME_LOW
    words[:, 2:] = np.tile(row, 64)
    words[:, 2::7] = np.arange(64)  # each row's y
    (root / "boxing").mkdir(parents=True)
    (root / "boxing" / "dense.raw").write_bytes(
        b"% evt 3.0\n% format EVT3;width=64;height=64\n" + words.astype("<u2").tobytes()
    )
    return blocks * 64 * 60


def test_a_dense_dvs_class_folder_is_binned_in_bounded_memory(tmp_path, monkeypatch) -> None:
    """issue 71: a dense recording of a DVS class folder was decoded whole before binning
    (3.5 GB for 20 MB); now a chunk at a time, however dense: memory is a chunk and the clip."""
    from edr.data.events import recording
    from edr.representations import DVSSimulator
    from edr.tasks.dvs_transfer import _recorded_clips

    monkeypatch.setattr(prophesee, "CHUNK_EVENTS", 20_000)
    monkeypatch.setattr(recording, "MAX_READ_EVENTS", 100_000)  # read whole, it was refused
    count = _dense_class_folder(tmp_path / "dvs", 200)  # 768,000 events (10 MB) in 180 KB
    _dense_evt3(tmp_path / "warm.raw", 2)
    list(iter_recording(tmp_path / "warm.raw"))  # numba's compiled code loaded outside the trace
    tracemalloc.start()
    try:
        (clip,), labels, _ = _recorded_clips(
            str(tmp_path / "dvs"), ["boxing", "walking"], DVSSimulator(), frames=4, crop=64
        )
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < count * EVENT_DTYPE.itemsize / 4, peak  # whole: 2x the events' 10 MB
    assert labels == [0] and tuple(clip.shape) == (4, 2, 64, 64)  # 200 µs: one frame, held
    assert (clip[:, 0, :, :60] == 200).all() and float(clip.sum()) == 4 * count  # all ON


def test_a_dvs_recording_whose_binning_cannot_fit_is_refused_naming_it(
    tmp_path, monkeypatch
) -> None:
    from edr.checks import config
    from edr.checks.config import ConfigError
    from edr.representations import DVSSimulator
    from edr.tasks.dvs_transfer import _recorded_clips

    _dense_class_folder(tmp_path / "dvs", 1)
    monkeypatch.setattr(config, "available_memory_bytes", lambda: 1 << 10)
    path = tmp_path / "dvs" / "boxing" / "dense.raw"
    with pytest.raises(ConfigError) as caught:
        _recorded_clips(str(tmp_path / "dvs"), ["boxing"], DVSSimulator(), frames=4, crop=64)
    message = str(caught.value)
    assert message.startswith(f"task.dvs_root={tmp_path / 'dvs'}: {path}'s frames binned 16 ")
    assert "at its 64x64 sensor would take" in message and "\n" not in message


def test_a_clip_binned_chunk_by_chunk_is_the_clip_of_all_its_events() -> None:
    """A recording's chunks, binned as they come, give what its events binned at once give
    (tonic's windows), across groups of BIN_FRAMES intervals and gaps without events."""
    from edr.representations import events_to_frames
    from edr.tasks.dvs_transfer import _event_clip

    rng = np.random.default_rng(0)
    t = np.sort(rng.integers(0, 1_400_000, 3000))
    t = t[(t < 300_000) | (t > 700_000)]  # 12 frame intervals without an event
    events = _events(t, *rng.integers(0, 32, (2, len(t))), rng.integers(0, 2, len(t)))
    w = 33_333.25  # a frame interval of no whole µs (exact in binary: no window rounds)
    whole = events_to_frames(
        events, 32, 32, time_window=w, start_time=0, end_time=40 * w, dtype=np.float32
    )  # (40, [OFF, ON], 32, 32)
    for parts in (1, 7, 60):
        clip = _event_clip(np.array_split(events, parts), 32, 32, w, frames=40, crop=32)
        np.testing.assert_array_equal(clip.numpy(), whole[:, ::-1])  # [ON, OFF]
    # 33,333.4 µs: a group's end rounded its last interval away (binned as the one before)
    last = _event_clip([events], 32, 32, 33_333.4, frames=40, crop=32)[39]
    assert float(last.sum()) == ((t >= 39 * 33_333.4) & (t < 40 * 33_333.4)).sum() > 0
    first = _event_clip(np.array_split(events, 5), 32, 32, w, frames=3, crop=32, start_us=None)
    assert float(first.sum()) == (t < t[0] + 3 * w).sum()


# 6: a file's arrays are 1-d columns of one length (MVSEC's: (N, 4) rows), refused by name


def _hdf5_of(path: Path, make) -> Path:
    """An HDF5 file that ``make(file)`` fills."""
    h5py = pytest.importorskip("h5py")
    with h5py.File(path, "w") as f:
        make(f)
    return path


BAD_COLUMNS = {  # (file, its one line): each was a TypeError or AttributeError traceback
    ".npz of 0-d scalars": (  # battery a01
        lambda d: npz_recording(d / "rec.npz", **{k: np.array(5) for k in "txyp"}),
        ".npz: t is a scalar, not 1-d",
    ),
    ".npz x of 3 events, t of 2": (
        lambda d: npz_recording(d / "rec.npz", x=[1, 2, 3]),
        ".npz: its columns differ in length (t 2, x 3, y 2, p 2)",
    ),
    ".npz 2-d p": (
        lambda d: npz_recording(d / "rec.npz", p=[[0, 1]]),
        ".npz: p is of shape (1, 2), not 1-d",
    ),
    "MVSEC events a group": (  # battery a04
        lambda d: _hdf5_of(d / "data.hdf5", lambda f: f.create_group("davis/left/events")),
        "HDF5 (MVSEC): davis/left/events is a Group (no array), not (N, 4) rows",
    ),
    "DSEC scalar datasets": (  # battery a05
        lambda d: _hdf5_of(
            d / "events.h5", lambda f: [f.create_dataset(f"events/{k}", data=1) for k in "txyp"]
        ),
        "HDF5 (DSEC): events/t is a scalar, not 1-d",
    ),
}


@pytest.mark.parametrize("case", BAD_COLUMNS)
def test_columns_that_are_not_1d_of_one_length_are_refused_by_name(tmp_path, case) -> None:
    _refused_in_one_line(*BAD_COLUMNS[case], tmp_path)


# 7: AEDAT 2.0's header ends where jAER's does, or at the first line that is not one


def test_a_davis_file_without_an_end_line_reads_its_first_event_starting_with_hash(
    tmp_path,
) -> None:
    """battery a11: the first address byte 0x23 ('#') made both events a header line."""
    words = np.array([[0x23000000 | (3 << 12), 1], [4 << 12, 2]], ">u4")  # (N, 2): address, t
    header = b"#!AER-DAT2.0\r\n# AEChip: eu.seebetter.ini.chips.davis.Davis346red\r\n"
    path = _written(tmp_path / "rec.aedat", header + words.tobytes())
    expected = _events([1, 2], x=[3, 4], y=[259 - 0x8C, 259], p=0)  # address bits 22-30: 0x8C
    np.testing.assert_array_equal(read_recording(path), expected)
    assert recording_sensor_size(path) == (260, 346)  # its header lines are still read


# 8: a recording's measured sensor, and the frame rate it is binned at


def _evt3_without_geometry(path: Path, micros: int) -> Path:
    """EVT 3.0 stating no sensor: 12 events (y 0, x 0..11) each µs, then one at x 1200, y 700."""
    i = np.arange(micros)
    words = np.empty((micros, 5), np.uint16)
    words[:, 0], words[:, 1] = 0x8000 | (i >> 12), 0x6000 | (i & 0xFFF)  # TIME_HIGH, TIME_LOW
    words[:, 2], words[:, 3], words[:, 4] = 0, 0x3800, 0x4FFF  # y 0, base x 0 ON, 12 bits
    last = [0x8000 | (micros >> 12), 0x6000 | (micros & 0xFFF), 700, 0x2000 | (1 << 11) | 1200]
    data = np.concatenate([words.ravel(), np.array(last, np.uint16)])
    return _written(path, b"% evt 3.0\n" + data.astype("<u2").tobytes())


def test_a_recording_stating_no_sensor_spans_the_events_of_every_chunk(
    tmp_path, monkeypatch
) -> None:
    """battery a29: the sensor came from the first chunk alone (12x1, not 1201x701)."""
    from edr.tasks.event_camera import recording_cost

    monkeypatch.setattr(prophesee, "CHUNK_EVENTS", 1000)  # 13 chunks; the widest event last
    path = _evt3_without_geometry(tmp_path / "wide.raw", 1000)
    events = read_recording(path)
    cost = recording_cost(path, fps=25_000.0, timestamp_bits=32)  # 40 µs frames: 26 of them
    assert cost["data/events_sensor"] == "1201x701" and not cost["data/events_sensor_stated"]
    frame = (events["t"] - events["t"][0]) // 40
    bins = len(np.unique(np.stack([frame, events["p"], events["y"], events["x"]]), axis=1).T)
    assert cost["camera/sparsity"] == pytest.approx(1 - bins / (26 * 2 * 701 * 1201))


def test_a_frame_rate_finer_than_a_microsecond_is_refused_before_the_run(compose_config) -> None:
    """battery a30: task.fps=1e300 cast a frame's index beyond int64 (a RuntimeWarning)."""
    from edr.checks.config import ConfigError, check_config
    from edr.run import ENTRY_KEYS

    cfg = compose_config("task=event_camera", "debug=tiny", "task.fps=1e300")
    with pytest.raises(ConfigError, match=r"task\.fps=1e\+300: expected a number <= 1000000"):
        check_config(cfg, entry=ENTRY_KEYS)
