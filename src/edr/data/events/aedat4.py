"""iniVation DV's AEDAT 4, decoded here with numpy (its packets decompressed by lz4 or zstandard).

The layout, as DV writes it and the independent ``aedat`` decoder reads it:
- ``#!AER-DAT4.0\\r\\n``, a little-endian uint32 n, then n bytes of an IOHeader flatbuffer
  ('IOHE': compression 0 none, 1 LZ4, 2 LZ4 high, 3 zstd, 4 zstd high; the data table's byte
  offset, -1 when there is none; an XML description naming each stream's id, its
  ``typeIdentifier`` and, for events, the sensor's ``sizeX`` / ``sizeY``).
- Packets up to the data table (or the file's end): int32 stream id, uint32 size, then ``size``
  bytes, an LZ4 or zstd frame as the header says, of a size-prefixed flatbuffer.
- An events packet ('EVTS'): a table whose first field is a vector of 16-byte structs (int64 t
  µs, int16 x, int16 y, bool on, 3 bytes of padding), viewed as a numpy structured array: no
  per-event Python work. The first events stream the description lists is read; frames, IMU
  samples and triggers are skipped.
"""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
from numba import njit

from edr.data.events.checks import (
    CHUNK_EVENTS,
    EVENT_DTYPE,
    MAX_HEADER_BYTES,
    RecordingError,
    unfit,
)

MAGIC = b"#!AER-DAT4.0\r\n"
# One event as DV stores it: struct Event { int64 t; int16 x; int16 y; bool on; }, 8-aligned
DV_EVENT = np.dtype({"names": ["t", "x", "y", "on"], "formats": ["<i8", "<i2", "<i2", "u1"],
                     "offsets": [0, 8, 10, 12], "itemsize": 16})  # fmt: skip
COMPRESSIONS = {0: None, 1: "lz4", 2: "lz4", 3: "zstd", 4: "zstd"}
PACKAGES = {"lz4": "lz4", "zstd": "zstandard"}


def _u32(data: bytes | memoryview, at: int) -> int:
    return int.from_bytes(data[at : at + 4], "little")


def _field(data: bytes | memoryview, table: int, index: int) -> int | None:
    """The byte offset of field ``index`` of the flatbuffer table at ``table``, None if absent."""
    vtable = table - int.from_bytes(data[table : table + 4], "little", signed=True)
    size = int.from_bytes(data[vtable : vtable + 2], "little")
    if 4 + 2 * index >= size:
        return None
    offset = int.from_bytes(data[vtable + 4 + 2 * index : vtable + 6 + 2 * index], "little")
    return table + offset if offset else None


def _vector(data: bytes | memoryview, at: int) -> tuple[int, int]:
    """(where its elements start, how many) of the vector the offset at ``at`` points to."""
    start = at + _u32(data, at)
    return start + 4, _u32(data, start)


class Header:
    """An AEDAT 4 file's IOHeader: its compression, where its packets end, its events stream."""

    def __init__(self, path: Path) -> None:
        self.path = path
        with path.open("rb") as f:
            head = f.read(len(MAGIC) + 4)
            if not head.startswith(MAGIC):
                raise self.fail(f"its first line is not {MAGIC.decode().strip()!r}")
            if len(head) < len(MAGIC) + 4:
                raise self.fail("truncated inside its header")
            size = _u32(head, len(MAGIC))
            if size > MAX_HEADER_BYTES:  # read whole, it could be 4 GiB
                raise self.fail(
                    f"its header states {size:,} bytes, more than {MAX_HEADER_BYTES >> 20} MiB "
                    "(DV writes a few KiB): a corrupt file"
                )
            data = f.read(size)
        self.data_start = len(MAGIC) + 4 + size
        if len(data) < size:
            raise self.fail(f"truncated inside its header (of {self.data_start} bytes)")
        try:
            root = _u32(data, 0)
            if data[4:8] != b"IOHE":
                raise ValueError(f"its header is {bytes(data[4:8])!r}, not an IOHeader ('IOHE')")
            at = _field(data, root, 0)
            code = int.from_bytes(data[at : at + 4], "little") if at is not None else 0
            at = _field(data, root, 1)
            self.data_end = int.from_bytes(data[at : at + 8], "little", signed=True) if at else -1
            at = _field(data, root, 2)
            if at is None:
                raise ValueError("its header has no stream description")
            start = at + _u32(data, at)
            description = data[start + 4 : start + 4 + _u32(data, start)].decode()
            streams = ElementTree.fromstring(description).find("node[@name='outInfo']")
        except (ValueError, UnicodeDecodeError, ElementTree.ParseError) as error:
            raise self.fail(f"its header cannot be decoded ({error})") from None
        if code not in COMPRESSIONS:
            raise self.fail(f"unknown compression {code} (known: 0 to 4)")
        self.compression = COMPRESSIONS[code]
        found = {
            int(node.get("name", -1)): node
            for node in (streams if streams is not None else [])
            if node.findtext("attr[@key='typeIdentifier']") == "EVTS"
        }
        if not found:
            raise self.fail("no events stream ('EVTS') in its description")
        self.stream = min(found)
        info = found[self.stream].find("node[@name='info']")
        size_x = info.findtext("attr[@key='sizeX']") if info is not None else None
        size_y = info.findtext("attr[@key='sizeY']") if info is not None else None
        self.sensor = (int(size_y), int(size_x)) if size_x and size_y else None

    def fail(self, problem: str) -> RecordingError:
        return RecordingError(self.path, "AEDAT 4", problem)

    def decompressor(self) -> Callable[[memoryview], bytes | memoryview]:
        """A packet's stored bytes -> its flatbuffer's bytes."""
        if self.compression is None:
            return lambda stored: stored
        try:
            if self.compression == "lz4":
                import lz4.frame

                return lz4.frame.decompress
            import zstandard
        except ImportError:
            raise self.fail(
                f"its packets are {self.compression}-compressed; reading it needs "
                f"{PACKAGES[self.compression]}: pip install 'edr[events]'"
            ) from None

        def unzstd(stored: memoryview) -> bytes:
            stream = zstandard.ZstdDecompressor().decompressobj()
            try:
                data = stream.decompress(stored)
            except zstandard.ZstdError as error:
                raise ValueError(str(error)) from None
            if not stream.eof:
                raise ValueError("the zstd frame ends early")
            return data

        return unzstd


def aedat4_sensor(path: Path) -> tuple[int, int] | None:
    """(height, width) of the events stream, as its description states it."""
    return Header(path).sensor


def _packet_events(data: bytes | memoryview) -> np.ndarray:
    """An events packet's flatbuffer (size-prefixed) -> its events (N,) DV_EVENT, a view."""
    if _u32(data, 0) + 4 > len(data) or bytes(data[8:12]) != b"EVTS":
        raise ValueError(f"not a whole events packet (identifier {bytes(data[8:12])!r})")
    table = 4 + _u32(data, 4)
    at = _field(data, table, 0)
    if at is None:
        return np.zeros(0, DV_EVENT)
    start, n = _vector(data, at)
    if start + n * DV_EVENT.itemsize > len(data):
        raise ValueError(f"its {n} events run past its end")
    return np.frombuffer(data, DV_EVENT, n, start)


@njit(cache=True)
def _copy_events(packet, out):  # pragma: no cover (numba)
    """``packet`` (N,) DV_EVENT into ``out`` (N,) EVENT_DTYPE, record by record (5x faster than
    numpy's copies field by field); returns the largest ``on`` byte copied."""
    largest = 0
    for i in range(len(packet)):
        event, stored = out[i], packet[i]
        event.t, event.x, event.y, event.p = stored.t, stored.x, stored.y, stored.on
        largest = max(largest, stored.on)
    return largest


def _to_events(packets: list[np.ndarray]) -> np.ndarray:
    """Packets (N_i,) DV_EVENT -> one chunk (sum N_i,) EVENT_DTYPE; an ``on`` byte other than
    0 or 1 is refused by its value (int8 p would hold 255 as -1)."""
    out = np.empty(sum(len(packet) for packet in packets), EVENT_DTYPE)
    at = 0
    for packet in packets:
        largest = _copy_events(packet, out[at : at + len(packet)])
        if largest > 1:
            raise unfit("p", int(largest))
        at += len(packet)
    return out


def _packets(header: Header, path: Path) -> Iterator[np.ndarray]:
    """The events stream's packets, in order, each as events (N,) DV_EVENT; the file
    memory-mapped, each packet decompressed and viewed."""
    decompress = header.decompressor()
    size = path.stat().st_size
    end = header.data_end if header.data_end >= 0 else size
    if end > size:
        raise header.fail(
            f"truncated: {size} bytes, its packets run to byte {end} (its data table)"
        )
    if end <= header.data_start:
        return
    body = memoryview(np.memmap(path, np.uint8, mode="r"))
    at = header.data_start
    while at < end:
        if at + 8 > end:
            raise header.fail(f"truncated: a packet header at byte {at} runs past {end}")
        stream, stored = (
            int.from_bytes(body[at : at + 4], "little", signed=True),
            _u32(body, at + 4),
        )
        if at + 8 + stored > end:
            raise header.fail(
                f"truncated: the packet at byte {at} ({stored} bytes) runs past {end}"
            )
        if stream == header.stream:
            try:
                events = _packet_events(decompress(body[at + 8 : at + 8 + stored]))
            except (ValueError, RuntimeError) as error:  # lz4 raises RuntimeError
                raise header.fail(f"the packet at byte {at} cannot be decoded ({error})") from None
            yield events
        at += 8 + stored


def aedat4_chunks(path: Path) -> Iterator[np.ndarray]:
    """An AEDAT 4 file's events, packets joined into chunks of about CHUNK_EVENTS (EVENT_DTYPE)."""
    parts: list[np.ndarray] = []
    held = 0
    for events in _packets(Header(path), path):
        parts.append(events)
        held += len(events)
        if held >= CHUNK_EVENTS:
            yield _to_events(parts)
            parts, held = [], 0
    if parts:
        yield _to_events(parts)
