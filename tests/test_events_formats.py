"""Every event format: the real recordings in ``../shared/events/`` read by the suite and by an
independent decoder (evt3, aedat, or the format's published layout in a few lines of numpy),
compared exactly; write -> read round trips; AEDAT 3.1, DSEC and MVSEC on small files written
here in their layouts."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import numpy as np
import pytest

from edr.checks.config import ConfigError
from edr.data.events import (
    detect_format,
    iter_recording,
    list_recordings,
    read_recording,
    recording_sensor_size,
    write_recording,
)
from edr.representations.dvs import EVENT_DTYPE

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "events"


@pytest.fixture
def shared():
    if not SHARED.is_dir():
        pytest.skip(
            f"real event recordings not found at {SHARED} (the repository's ../shared/events)"
        )
    return SHARED


def _columns(events: np.ndarray) -> tuple[np.ndarray, ...]:
    return tuple(events[k].astype(np.int64) for k in ("t", "x", "y", "p"))


def _assert_same(events: np.ndarray, t, x, y, p) -> None:
    for name, ours, theirs in zip("txyp", _columns(events), (t, x, y, p), strict=True):
        np.testing.assert_array_equal(ours, np.asarray(theirs, np.int64), err_msg=name)


def _body(path, header_prefix: bytes) -> bytes:
    """The file's bytes after its header lines starting with ``header_prefix``."""
    raw = path.read_bytes()
    at = 0
    while raw.startswith(header_prefix, at):
        at = raw.index(b"\n", at) + 1
    return raw[at:]


@pytest.mark.parametrize("chunk", [1 << 20, 10_007])  # one chunk; many, the decoder state carried
def test_evt3_matches_the_evt3_decoder(shared, monkeypatch, chunk) -> None:
    from edr.data.events import prophesee

    evt3 = pytest.importorskip("evt3")
    monkeypatch.setattr(prophesee, "CHUNK_EVENTS", chunk)  # words a chunk
    path = shared / "evt3_sample.raw"
    theirs = evt3.decode_file(str(path))
    events = read_recording(path)
    assert len(events) == 219_596  # the count its source states
    _assert_same(events, theirs.timestamp, theirs.x, theirs.y, theirs.polarity)
    assert recording_sensor_size(path) == (theirs.sensor_height, theirs.sensor_width) == (720, 1280)


def _aedat_decoder_events(path) -> tuple[np.ndarray, dict]:
    """The first events stream of an AEDAT 4 file as the ``aedat`` package decodes it: its
    events (N,) (t, x, y, on) and its stream's description."""
    aedat = pytest.importorskip("aedat")
    decoder = aedat.Decoder(str(path))
    stream = min(i for i, s in decoder.id_to_stream().items() if s["type"] == "events")
    packets = [p["events"] for p in decoder if p["stream_id"] == stream and "events" in p]
    return np.concatenate(packets), decoder.id_to_stream()[stream]


@pytest.mark.parametrize("chunk", [1 << 20, 5_000])  # one chunk; packets joined into many
def test_aedat4_matches_the_aedat_decoder(shared, monkeypatch, chunk) -> None:
    from edr.data.events import aedat4

    monkeypatch.setattr(aedat4, "CHUNK_EVENTS", chunk)
    path = shared / "sample.aedat4"  # LZ4-compressed packets, events beside IMU and triggers
    theirs, info = _aedat_decoder_events(path)
    events = read_recording(path)
    assert len(events) == 111_954
    _assert_same(events, theirs["t"], theirs["x"], theirs["y"], theirs["on"])
    assert recording_sensor_size(path) == (info["height"], info["width"]) == (240, 320)


@pytest.mark.parametrize("compression", [None, ("lz4", 1), ("lz4", 9), ("zstd", 3)])
def test_aedat4_in_each_compression_matches_the_aedat_decoder(tmp_path, compression) -> None:
    faery = pytest.importorskip("faery")
    events = _events(20_000, 260, 346)
    packet = np.zeros(len(events), faery.EVENTS_DTYPE)
    packet["t"], packet["x"], packet["y"], packet["on"] = (
        events["t"], events["x"], events["y"], events["p"] == 1,
    )  # fmt: skip
    path = tmp_path / "rec.aedat4"
    faery.events_stream_from_array(packet, dimensions=(346, 260)).to_file(
        path, compression=compression
    )
    theirs, _ = _aedat_decoder_events(path)
    ours = read_recording(path)
    _assert_same(ours, theirs["t"], theirs["x"], theirs["y"], theirs["on"])
    np.testing.assert_array_equal(ours, events)


def test_evt2_matches_its_published_layout(shared) -> None:
    pytest.importorskip("faery")
    path = shared / "evt2_sample.raw"
    words = np.frombuffer(_body(path, b"%"), "<u4").astype(np.int64)
    kind = words >> 28  # 0 CD OFF, 1 CD ON, 8 EVT_TIME_HIGH
    high = np.where(kind == 8, words & 0x0FFFFFFF, 0)
    high = np.maximum.accumulate(np.where(kind == 8, high, -1))  # the latest TIME_HIGH
    cd = (kind <= 1) & (high >= 0)
    t = (high[cd] << 6) | ((words[cd] >> 22) & 0x3F)
    x, y = (words[cd] >> 11) & 0x7FF, words[cd] & 0x7FF
    _assert_same(read_recording(path), t, x, y, kind[cd])
    assert recording_sensor_size(path) == (480, 640)  # Gen3, by its header's plugin


def test_dat_matches_its_published_layout(shared) -> None:
    path = shared / "sample_ncars.dat"
    body = _body(path, b"%")[2:]  # event type, event size
    words = np.frombuffer(body, "<u4").reshape(-1, 2).astype(np.int64)
    t, data = words[:, 0], words[:, 1]
    _assert_same(read_recording(path), t, data & 0x3FFF, (data >> 14) & 0x3FFF, (data >> 28) & 1)
    assert detect_format(path).name == "DAT" and recording_sensor_size(path) is None


def test_nmnist_matches_its_published_layout(shared) -> None:
    path = shared / "sample_nmnist.bin"
    b = np.frombuffer(path.read_bytes(), np.uint8).reshape(-1, 5).astype(np.int64)
    t = ((b[:, 2] & 127) << 16) | (b[:, 3] << 8) | b[:, 4]
    _assert_same(read_recording(path), t, b[:, 0], b[:, 1], b[:, 2] >> 7)
    assert len(b) == 4_325 and recording_sensor_size(path) == (34, 34)


def test_a_header_only_davis346_file_is_refused_as_empty(shared) -> None:
    path = shared / "sample_aedat_header.aedat"
    assert recording_sensor_size(path) == (260, 346)  # its AEChip line, not DVS128
    with pytest.raises(ValueError, match=r"sample_aedat_header\.aedat: AEDAT 2\.0: no events"):
        read_recording(path)


def test_a_duration_reads_only_the_first_microseconds(shared) -> None:
    pytest.importorskip("faery")
    path = shared / "evt2_sample.raw"
    whole = read_recording(path)
    first = read_recording(path, duration_us=1000)
    assert 0 < len(first) < len(whole) and first["t"][-1] < whole["t"][0] + 1000
    np.testing.assert_array_equal(first, whole[: len(first)])
    assert sum(len(c) for c in iter_recording(path)) == len(whole)


def _events(n: int, height: int, width: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    events = np.zeros(n, EVENT_DTYPE)
    events["t"] = np.sort(rng.integers(0, 5_000_000, n))
    events["x"], events["y"] = rng.integers(0, width, n), rng.integers(0, height, n)
    events["p"] = rng.integers(0, 2, n)
    return events


@pytest.mark.parametrize(
    ("suffix", "sensor", "stated"),
    [
        (".raw", (120, 160), (120, 160)),
        (".aedat4", (260, 346), (260, 346)),
        (".aedat", (128, 128), (128, 128)),  # DVS128
        (".aedat", (120, 160), (180, 240)),  # the smallest jAER chip that holds it: DAVIS240
        (".npz", (34, 34), (34, 34)),
    ],
)
def test_write_then_read_round_trips(tmp_path, suffix, sensor, stated) -> None:
    if suffix in (".raw", ".aedat4"):
        pytest.importorskip("faery")
    events = _events(500, *sensor)
    path = write_recording(tmp_path / f"rec{suffix}", events, sensor)
    np.testing.assert_array_equal(read_recording(path), events)
    assert recording_sensor_size(path) == stated


def test_write_refuses_an_unwritable_suffix_and_events_off_the_sensor(tmp_path) -> None:
    with pytest.raises(ValueError, match=r"cannot write \.txt"):
        write_recording(tmp_path / "rec.txt", _events(3, 8, 8), (8, 8))
    with pytest.raises(ValueError, match=r"x = .* outside its sensor"):
        write_recording(tmp_path / "rec.npz", _events(30, 8, 64), (8, 8))


def _aedat31(path, events: np.ndarray, source: str = "DVS128") -> None:
    """A cAER AEDAT 3.1 file: one polarity packet, then a frame packet the reader skips."""
    data = (events["x"].astype(np.uint32) << 17) | (events["y"].astype(np.uint32) << 2)
    data |= (events["p"].astype(np.uint32) << 1) | 1
    words = np.stack([data, events["t"].astype(np.uint32)], 1).astype("<u4")
    n = len(events)
    polarity = np.array([1, 1], "<i2").tobytes() + np.array([8, 4, 0, n, n, n], "<i4").tobytes()
    frame = np.array([2, 1], "<i2").tobytes() + np.array([4, 0, 0, 1, 1, 1], "<i4").tobytes()
    path.write_bytes(
        f"#!AER-DAT3.1\r\n#Format: RAW\r\n#Source 1: {source}\r\n#!END-HEADER\r\n".encode()
        + polarity + words.tobytes() + frame + b"\0\0\0\0"
    )  # fmt: skip


def test_aedat31_polarity_packets(tmp_path) -> None:
    events = _events(200, 128, 128)
    _aedat31(tmp_path / "rec.aedat", events)
    np.testing.assert_array_equal(read_recording(tmp_path / "rec.aedat"), events)
    assert recording_sensor_size(tmp_path / "rec.aedat") == (128, 128)
    assert detect_format(tmp_path / "rec.aedat").name == "AEDAT 3.1"


@pytest.mark.parametrize("layout", ["DSEC", "MVSEC"])
def test_hdf5_in_the_dsec_and_mvsec_layouts(tmp_path, layout) -> None:
    h5py = pytest.importorskip("h5py")
    sensor = (480, 640) if layout == "DSEC" else (260, 346)
    events = _events(300, *sensor)
    with h5py.File(tmp_path / "events.h5", "w") as f:
        if layout == "DSEC":
            for k in "xytp":
                f[f"events/{k}"] = events[k]
            f["ms_to_idx"] = np.searchsorted(events["t"], np.arange(0, 5000) * 1000)
        else:
            rows = np.stack([events["x"], events["y"], events["t"] * 1e-6 + 1.5e9,
                             2.0 * events["p"] - 1], 1)  # fmt: skip
            f["davis/left/events"] = rows
            events["t"] = np.round(rows[:, 2] * 1e6)
    np.testing.assert_array_equal(read_recording(tmp_path / "events.h5"), events)
    assert recording_sensor_size(tmp_path / "events.h5") == sensor


def test_a_folder_of_recordings_in_any_format(tmp_path) -> None:
    for action, suffix in (("boxing", ".aedat"), ("walking", ".npz")):
        (tmp_path / action).mkdir()
        write_recording(tmp_path / action / f"user1{suffix}", _events(5, 128, 128), (128, 128))
    (tmp_path / "walking" / ".DS_Store").write_text("hidden: skipped")
    assert list_recordings(tmp_path, ("boxing", "walking")) == [
        (tmp_path / "boxing" / "user1.aedat", 0),
        (tmp_path / "walking" / "user1.npz", 1),
    ]
    for stray in ("notes.txt", "user2.mp4"):  # never skipped unsaid: one line naming it
        (tmp_path / "walking" / stray).write_text("not a recording")
        with pytest.raises(ConfigError, match=f"walking/{stray}: not an event recording"):
            list_recordings(tmp_path, ("boxing", "walking"))
        (tmp_path / "walking" / stray).unlink()


def test_a_recordings_rates_in_both_bit_models(tmp_path) -> None:
    from edr.tasks.event_camera import recording_cost

    events = np.zeros(4, EVENT_DTYPE)
    events["t"], events["x"], events["y"], events["p"] = [0, 10, 40_000, 79_999], 1, 0, [1, 1, 0, 1]
    path = write_recording(tmp_path / "rec.npz", events, (2, 2))
    cost = recording_cost(path, fps=25.0, timestamp_bits=32)
    assert cost["camera/events_per_s"] == pytest.approx(4 / 0.08)
    assert cost["camera/bits_per_event"] == 3 + 32  # address of 2 x 2 x 2 bins + timestamp
    assert cost["camera/file_bits_per_event"] == pytest.approx(8 * path.stat().st_size / 4)
    assert cost["camera/events_per_pixel_frame"] == pytest.approx(4 / (2 * 4))
    assert cost["camera/sparsity"] == pytest.approx(1 - 3 / 16)  # bins: (0, ON), (1, OFF), (1, ON)
    assert cost["data/events_sensor"] == "2x2" and cost["data/events_format"] == ".npz"


def test_a_recordings_sparsity_is_the_same_chunked(shared, monkeypatch) -> None:
    from edr.data.events import prophesee
    from edr.tasks.event_camera import recording_cost

    path = shared / "evt3_sample.raw"
    whole = recording_cost(path, fps=1000.0, timestamp_bits=32)
    monkeypatch.setattr(prophesee, "CHUNK_EVENTS", 10_000)  # many chunks, bins across them
    assert recording_cost(path, fps=1000.0, timestamp_bits=32) == whole
    events = read_recording(path)
    frame = (events["t"] - events["t"][0]) // 1000
    bins = len(np.unique(np.stack([frame, events["p"], events["y"], events["x"]]), axis=1).T)
    assert whole["camera/sparsity"] == pytest.approx(1 - bins / (9 * 2 * 720 * 1280))


def test_event_camera_saves_the_dvs_and_hard_edr_events(compose_config, tmp_path) -> None:
    import json

    from edr.run import run

    run(compose_config("task=event_camera", "debug=tiny", "task.save_events=.aedat",
                       f"out_dir={tmp_path}"))  # fmt: skip
    metrics = json.loads((tmp_path / "run.json").read_text())["metrics"]
    # debug=tiny: 8 frames at 25 fps; the DVS's output has 7 intervals, EDR's 8 frames
    for name, seconds in (("dvs", 7 / 25.0), ("edr_hard", 8 / 25.0)):
        events = read_recording(tmp_path / f"{name}_events.aedat")
        assert recording_sensor_size(tmp_path / f"{name}_events.aedat") == (128, 128)  # 64x48 fits
        assert len(events) == pytest.approx(metrics[f"{name}/events_per_s"] * seconds)
    assert not (tmp_path / "edr_soft_events.aedat").exists()  # graded: not events


def test_a_davis_event_whose_first_byte_is_hash_is_not_taken_for_header(tmp_path) -> None:
    events = _events(20, 260, 346)
    events["y"][0] = 119  # DAVIS346 address: its top byte is (259 - 119) >> 2 = 0x23, '#'
    path = write_recording(tmp_path / "rec.aedat", events, (260, 346))
    np.testing.assert_array_equal(read_recording(path), events)


@pytest.mark.slow
def test_dvs_transfer_on_a_folder_of_mixed_formats(compose_config, tmp_path) -> None:
    """Recordings of every writable format, one with DV's absolute (epoch) timestamps: each is
    binned from its own first event."""
    import json

    from edr.data.synthetic import KTH_ACTIONS
    from edr.run import run

    if importlib.util.find_spec("faery") is None:
        pytest.skip("faery (the events extra) is not installed")
    recordings = tmp_path / "dvs"
    for label, action in enumerate(KTH_ACTIONS):
        (recordings / action).mkdir(parents=True)
        for i, suffix in enumerate((".raw", ".aedat4", ".aedat", ".npz")[label % 2 :: 2]):
            events = _events(3000, 128, 128, seed=label * 10 + i)
            events["t"] = events["t"] % 400_000 + (1_605_537_493_718_345 if i else 0)
            events = np.sort(events, order="t")
            write_recording(recordings / action / f"user{i}{suffix}", events, (128, 128))
    run(compose_config("task=dvs_transfer", "debug=tiny", f"out_dir={tmp_path / 'run'}",
                       f"task.pretrain.cache_dir={tmp_path / 'cache'}",
                       f"task.dvs_root={recordings}"))  # fmt: skip
    record = json.loads((tmp_path / "run" / "run.json").read_text())
    assert record["status"] == "finished"
    assert record["data"]["train_recordings"] + record["data"]["test_recordings"] == 12


def test_a_clip_is_binned_from_its_recordings_first_event() -> None:
    from edr.tasks.dvs_transfer import _event_clip

    events = _events(100, 128, 128)
    events["t"] = np.sort(events["t"] % 200_000) + 1_605_537_493_718_345  # DV's epoch time
    start = int(events["t"][0])
    clip = _event_clip([events], 128, 128, 40_000.0, frames=4, crop=128, start_us=start)
    assert float(clip.sum()) == (events["t"] < start + 160_000).sum() > 0


def _evt2(path: Path, events: np.ndarray, sensor: tuple[int, int]) -> None:
    """EVT 2.0 as Prophesee publishes it: 32-bit words, type in the top 4 bits (0 CD OFF, 1 CD
    ON, 8 EVT_TIME_HIGH: t >> 6), a CD word holding t's 6 low bits, x (11 bits) and y (11)."""
    t, x, y, p = _columns(events)
    high = t >> 6
    new = np.r_[True, high[1:] != high[:-1]]  # a TIME_HIGH word before each new high
    words = np.zeros(len(t) + new.sum(), "<u4")
    at = np.arange(len(t)) + np.cumsum(new)
    words[at] = (p << 28) | ((t & 63) << 22) | (x << 11) | y
    words[at[new] - 1] = (8 << 28) | high[new]
    header = f"% evt 2.0\n% geometry {sensor[1]}x{sensor[0]}\n% end\n".encode()
    path.write_bytes(header + words.tobytes())


def _dat(path: Path, events: np.ndarray, sensor: tuple[int, int]) -> None:
    """DAT version 2: '%' lines, event type and size, then (uint32 t, uint32 x | y << 14 |
    p << 28) pairs."""
    t, x, y, p = _columns(events)
    words = np.stack([t, x | (y << 14) | (p << 28)], 1).astype("<u4")  # (N, 2)
    header = f"% Version 2\n% Height {sensor[0]}\n% Width {sensor[1]}\n".encode()
    path.write_bytes(header + bytes([12, 8]) + words.tobytes())


def _nmnist(path: Path, events: np.ndarray, sensor: tuple[int, int]) -> None:
    """N-MNIST: 5 bytes an event, x, y, then p in bit 7 and a 23-bit t, big-endian."""
    t, x, y, p = _columns(events)
    rows = np.stack([x, y, (p << 7) | (t >> 16), (t >> 8) & 255, t & 255], 1)  # (N, 5)
    path.write_bytes(rows.astype(np.uint8).tobytes())


def _hdf5(layout: str):
    def write(path: Path, events: np.ndarray, sensor: tuple[int, int]) -> None:
        h5py = pytest.importorskip("h5py")
        with h5py.File(path, "w") as f:
            if layout == "DSEC":
                for k in "xytp":
                    f[f"events/{k}"] = events[k]
            else:  # MVSEC: rows (x, y, t seconds, p -1/1)
                f["davis/left/events"] = np.stack(
                    [events["x"], events["y"], events["t"] * 1e-6, 2.0 * events["p"] - 1], 1
                )

    return write


# A row of docs/events.md's table, by its first words -> (the format detect_format finds there,
# a writer of a small file in it, the file's sensor)
DOCUMENTED_FORMATS = {
    "AEDAT 2.0": ("AEDAT 2.0", write_recording, (128, 128)),
    "AEDAT 3.1": ("AEDAT 3.1", lambda path, events, sensor: _aedat31(path, events), (128, 128)),
    "AEDAT 4": ("AEDAT 4", write_recording, (260, 346)),
    "EVT 2.0": ("EVT 2.0", _evt2, (120, 160)),
    "EVT 3.0": ("EVT 3.0", write_recording, (720, 1280)),
    "DAT": ("DAT", _dat, (120, 160)),
    "N-MNIST": ("N-MNIST", _nmnist, (34, 34)),
    "HDF5, DSEC": ("HDF5", _hdf5("DSEC"), (480, 640)),
    "HDF5, MVSEC": ("HDF5", _hdf5("MVSEC"), (260, 346)),
    "the suite's own": (".npz", write_recording, (34, 34)),
}


def test_every_format_docs_events_md_lists_reads_in_its_one_line(tmp_path, monkeypatch) -> None:
    pytest.importorskip("faery")  # writes AEDAT 4 and EVT 3.0, reads EVT 2.0
    document = Path(__file__).resolve().parents[1] / "docs" / "events.md"
    rows = re.findall(
        r'^\| ([^|]+?) \|.*\| `(read_recording\("([^"]+)"\))` \|$', document.read_text(), re.M
    )  # (format, its one-line read, the file it reads)
    keys = [next((k for k in DOCUMENTED_FORMATS if cell.startswith(k)), cell) for cell, *_ in rows]
    assert sorted(keys) == sorted(DOCUMENTED_FORMATS)  # each documented format once, and only them
    for key, (_, line, name) in zip(keys, rows, strict=True):
        found, write, sensor = DOCUMENTED_FORMATS[key]
        folder = tmp_path / re.sub(r"\W+", "_", key)
        folder.mkdir()
        monkeypatch.chdir(folder)
        events = _events(300, *sensor)
        write(Path(name), events, sensor)
        read = eval(line, {"read_recording": read_recording})  # the documented line, as written
        np.testing.assert_array_equal(read, events, err_msg=f"{key}: {line}")
        assert detect_format(name).name == found
