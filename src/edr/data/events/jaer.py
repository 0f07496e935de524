"""jAER's and cAER's files: AEDAT 2.0 (DVS128 and DAVIS chips) and AEDAT 3.1 (polarity packets).

AEDAT 2.0: '#' header lines (``# AEChip: <java class>`` names the chip), then big-endian
(uint32 address, uint32 timestamp µs) pairs. jAER (``AEFileInputStream.readHeader``) ends the
header at its ``#End Of ASCII Header`` line, else at the first line not starting with '#'; its
writer ends each line in CR LF. A file without the end line whose first address byte is 0x23
('#') would have its events eaten as a header line, so a header line here is also text: it
ends in LF (CR LF, or LF alone as in tonic's sample) within 64 KiB and holds no NUL byte.
Every DVS event holds one (a DAVIS address's bits 0-9 are zero, a DVS128 address is 15 bits),
so the data begins at the first DVS event. Left ambiguous (jAER reads it as header too): a file
without the end line whose data starts with '#' and non-DVS words (IMU, APS) free of NUL up to
a byte 0x0A. This suite writes the timestamps after the first event's and states that time in
a ``# t0 <µs>`` header line, added back when read: a 32-bit timestamp holds 71 minutes, not a
camera's epoch clock (1.6e15 µs).
- DVS128 (also when no chip is named, as the paper's sensor): polarity in bit 0 (1 = OFF),
  x in bits 1-7 (mirrored), y in bits 8-14.
- DAVIS240 / DAVIS346: a DVS event has bits 31 (APS sample) and 10 (IMU / special) clear;
  polarity bit 11 (1 = ON), x bits 12-21, y bits 22-30 counted from the bottom row.
AEDAT 3.1: '#' header lines up to ``#!END-HEADER``, then packets: a 28-byte little-endian header
(type, source, size, ts offset, ts overflow, capacity, number, valid) and its events. Polarity
packets (type 1): uint32 data (bit 0 valid, bit 1 polarity 1 = ON, y bits 2-16, x bits 17-31)
and int32 timestamp, extended by ``overflow << 31`` (a negative one is refused, never read as
unsigned). Other packets (frames, IMU) are skipped.
Both are read memory-mapped, a chunk at a time.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from edr.data.events.checks import (
    CHUNK_EVENTS,
    HEADER_LINE_BYTES,
    MAX_HEADER_BYTES,
    RecordingError,
    event_array,
    events_of,
    signed_times,
    stated_t0,
    time_origin,
)
from edr.store.atomic import atomic_path

# jAER chip -> (height, width); the name as it appears in headers, matched case-insensitively
CHIPS = {"dvs128": (128, 128), "davis240": (180, 240), "davis346": (260, 346),
         "dvxplorer": (480, 640)}  # fmt: skip
AEDAT2_CHIP_CLASSES = {"dvs128": "ch.unizh.ini.jaer.chip.retina.DVS128",
                       "davis240": "eu.seebetter.ini.chips.davis.DAVIS240C",
                       "davis346": "eu.seebetter.ini.chips.davis.Davis346red"}  # fmt: skip
PACKET_HEADER = np.dtype([("type", "<i2"), ("source", "<i2"), ("size", "<i4"), ("ts_offset", "<i4"),
                          ("overflow", "<i4"), ("capacity", "<i4"), ("number", "<i4"),
                          ("valid", "<i4")])  # fmt: skip
POLARITY_EVENT = 1
POLARITY = np.dtype([("data", "<u4"), ("t", "<i4")])  # AEDAT 3.1's polarity event


def _is_header_line(line: bytes) -> bool:
    """Whether ``line`` (up to and with its LF) is a header line: '#', no NUL byte, a line end
    (see the module's docstring)."""
    return line.startswith(b"#") and line.endswith(b"\n") and b"\0" not in line


def _header(path: Path, end: bytes | None = None) -> tuple[list[str], int]:
    """The '#' header lines (text) and the byte offset where the data begins: after ``end``'s
    line, or at the first line that is no header line."""
    lines: list[str] = []
    with path.open("rb") as f:
        while True:
            start = f.tell()
            line = f.readline(HEADER_LINE_BYTES)
            if not _is_header_line(line):
                return lines, start
            lines.append(line.decode("latin-1").rstrip("\r\n"))
            if f.tell() > MAX_HEADER_BYTES:  # 100 MB of '#' lines would be held as text
                raise RecordingError(
                    path, "AEDAT", f"its '#' header runs past {MAX_HEADER_BYTES >> 20} MiB (jAER "
                    "writes a few KiB): not a header; is it an event file?",
                )  # fmt: skip
            if end is not None and line.lower().startswith(end.lower()):
                return lines, f.tell()


def _chip(lines: list[str], key: str) -> str | None:
    """The known chip a header line starting with ``key`` names, or None."""
    for line in lines:
        if line.startswith(key):
            named = re.sub(r"[^a-z0-9]", "", line.lower())
            return next((chip for chip in CHIPS if chip in named), "unknown")
    return None


def _value(lines: list[str], key: str) -> str | None:
    """The rest of the first header line starting with ``key``, or None."""
    return next((line[len(key) :].strip() for line in lines if line.startswith(key)), None)


def _body(path: Path, offset: int) -> np.ndarray:
    """The file's bytes from ``offset`` on, memory-mapped (empty when there are none)."""
    size = path.stat().st_size - offset
    return (
        np.memmap(path, dtype=np.uint8, mode="r", offset=offset)
        if size > 0
        else np.zeros(0, np.uint8)
    )


AEDAT2_HEADER_END = b"#End Of ASCII Header"  # jAER's last header line, where it writes one
AEDAT2_T0 = "# t0 "  # this suite's header line: the µs the 32-bit timestamps count from
AEDAT2_SPAN_US = (1 << 32) - 1  # the latest a 32-bit timestamp reaches after t0


def aedat2_chip(path: Path) -> str:
    """The AEDAT 2.0 file's chip: a key of CHIPS (DVS128 when none is named)."""
    chip = _chip(_header(path, AEDAT2_HEADER_END)[0], "# AEChip:") or "dvs128"
    if chip not in AEDAT2_CHIP_CLASSES:
        raise RecordingError(
            path,
            "AEDAT 2.0",
            f"its chip is not one this reader knows ({', '.join(AEDAT2_CHIP_CLASSES)})",
        )
    return chip


def aedat2_sensor(path: Path) -> tuple[int, int]:
    return CHIPS[aedat2_chip(path)]


def aedat2_chunks(path: Path) -> Iterator[np.ndarray]:
    """An AEDAT 2.0 file's DVS events, a chunk at a time (EVENT_DTYPE, as stored)."""
    chip = aedat2_chip(path)
    height = CHIPS[chip][0]
    lines, offset = _header(path, AEDAT2_HEADER_END)
    if not lines or not lines[0].startswith("#!AER-DAT2"):
        raise RecordingError(path, "AEDAT 2.0", "its first line is not '#!AER-DAT2.0'")
    t0 = stated_t0(path, "AEDAT 2.0", _value(lines, AEDAT2_T0))
    body = _body(path, offset)
    if len(body) % 8:
        raise RecordingError(
            path, "AEDAT 2.0", f"truncated: {len(body)} bytes of events is not a multiple of 8"
        )
    words = body.view(">u4").reshape(-1, 2)  # (N, 2): address, timestamp
    for start in range(0, len(words), CHUNK_EVENTS):
        address = words[start : start + CHUNK_EVENTS, 0].astype(np.int64)
        t = words[start : start + CHUNK_EVENTS, 1].astype(np.int64) + t0
        if chip == "dvs128":
            x, y, p = 127 - ((address >> 1) & 0x7F), (address >> 8) & 0x7F, 1 - (address & 1)
        else:
            dvs = (((address >> 31) & 1) == 0) & (((address >> 10) & 1) == 0)
            address, t = address[dvs], t[dvs]
            x, y = (address >> 12) & 0x3FF, height - 1 - ((address >> 22) & 0x1FF)
            p = (address >> 11) & 1
        yield events_of(t, x, y, p)


def aedat2_chip_for(path: Path, sensor: tuple[int, int]) -> str:
    """The smallest jAER chip (a key of CHIPS) whose array holds a ``sensor`` = (height, width);
    ValueError naming ``path`` where none does."""
    chip = next(
        (c for c in AEDAT2_CHIP_CLASSES if CHIPS[c][0] >= sensor[0] and CHIPS[c][1] >= sensor[1]),
        None,
    )
    if chip is None:
        raise ValueError(f"{path}: AEDAT 2.0 holds sensors up to DAVIS346's 346x260; got {sensor}")
    return chip


def write_aedat2(
    path: str | Path, events: np.ndarray, sensor: tuple[int, int] = (128, 128)
) -> Path:
    """Events (EVENT_DTYPE) of a ``sensor`` = (height, width) as AEDAT 2.0, naming the smallest
    jAER chip that holds the sensor (DVS128, DAVIS240, DAVIS346); their timestamps after the
    first event's, that time in a ``# t0`` line (refused, before anything is written, when
    they span more than a 32-bit timestamp holds)."""
    path = Path(path)
    events = event_array(path, "AEDAT 2.0", events)
    t0 = time_origin(path, "AEDAT 2.0", events["t"], AEDAT2_SPAN_US)
    chip = aedat2_chip_for(path, sensor)
    height = CHIPS[chip][0]
    x, y = events["x"].astype(np.uint32), events["y"].astype(np.uint32)
    p = events["p"].astype(np.uint32)
    if chip == "dvs128":
        address = ((127 - x) << 1) | (y << 8) | (1 - p)
    else:
        address = (x << 12) | ((height - 1 - y) << 22) | (p << 11)
    t = (events["t"] - t0).astype(np.uint32)  # time_origin: each fits
    words = np.stack([address, t], axis=1).astype(">u4")  # (N, 2)
    header = (
        f"#!AER-DAT2.0\r\n# This is a raw AE data file created by edr\r\n"
        f"# AEChip: {AEDAT2_CHIP_CLASSES[chip]}\r\n{AEDAT2_T0}{t0}\r\n"
        f"{AEDAT2_HEADER_END.decode()}\r\n"
    )
    with atomic_path(path) as tmp:
        tmp.write_bytes(header.encode() + words.tobytes())
    return path


def aedat31_sensor(path: Path) -> tuple[int, int] | None:
    chip = _chip(_header(path, b"#!END-HEADER")[0], "#Source")
    return CHIPS.get(chip or "")


def aedat31_chunks(path: Path) -> Iterator[np.ndarray]:
    """An AEDAT 3.1 file's polarity events, a packet at a time (EVENT_DTYPE)."""
    lines, offset = _header(path, b"#!END-HEADER")
    if not lines or not lines[-1].startswith("#!END-HEADER"):
        raise RecordingError(path, "AEDAT 3.1", "its header never ends ('#!END-HEADER' missing)")
    body = _body(path, offset)
    at = 0
    while at < len(body):
        if at + PACKET_HEADER.itemsize > len(body):
            raise RecordingError(
                path, "AEDAT 3.1", f"truncated packet header at byte {offset + at}"
            )
        head = body[at : at + PACKET_HEADER.itemsize].view(PACKET_HEADER)[0]
        size, number = int(head["size"]), int(head["number"])
        at += PACKET_HEADER.itemsize
        end = at + size * number
        if size < 1 or number < 0 or end > len(body):
            raise RecordingError(
                path, "AEDAT 3.1", f"truncated or corrupt packet at byte {offset + at - 28}"
            )
        if head["type"] == POLARITY_EVENT:
            if size != 8:
                raise RecordingError(path, "AEDAT 3.1", f"polarity events of {size} bytes, not 8")
            events = body[at:end].view(POLARITY)  # (N,): data, timestamp
            data = events["data"].astype(np.int64)
            valid = (data & 1) == 1
            data = data[valid]
            t = (int(head["overflow"]) << 31) | signed_times(events["t"][valid])
            yield events_of(t, data >> 17, (data >> 2) & 0x7FFF, (data >> 1) & 1)
        at = end
