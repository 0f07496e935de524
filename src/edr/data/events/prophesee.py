"""Prophesee's files (EVT 2.0 / EVT 3.0 RAW, DAT), and the writers of EVT 3.0 and AEDAT 4.

All start with a text header of '%' lines.
- EVT 3.0 is this module's numba decoder, exactly as Prophesee publishes it: 16-bit words whose
  4 high bits give the type; EVT_TIME_HIGH and EVT_TIME_LOW set the 12-bit halves of a 24-bit
  µs time (a TIME_HIGH that steps back is a wrap: +2**24), EVT_ADDR_Y sets y, EVT_ADDR_X is one
  event, VECT_BASE_X then VECT_12 / VECT_8 are up to 12 / 8 events at consecutive x. (faery
  0.7.1 keeps the largest time seen, so a TIME_LOW that steps back shifts events by up to
  11 µs on the shared sample: it is not used for EVT 3.0.) Decoded into chunks of at most
  CHUNK_EVENTS events (at least one word), however many events a word holds.
- EVT 2.0 is decoded by faery (the optional extra ``events``), in packets; faery also writes
  EVT 3.0 (times after the first event's, which a ``% t0`` header line states) and AEDAT 4.
- DAT: after the header, for version >= 2, two bytes (event type, event size), then
  little-endian (uint32 timestamp µs, uint32 data) pairs with x in bits 0-13, y in bits 14-27
  and polarity in bits 28-31 (1 = ON).
A ``% t0 <µs>`` header line (faery writes it) is added to every EVT 3.0 and DAT timestamp.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from itertools import chain
from pathlib import Path
from types import ModuleType

import numpy as np
from numba import njit

from edr.data.events.checks import (
    CHUNK_EVENTS,
    EVENT_DTYPE,
    HEADER_LINE_BYTES,
    MAX_HEADER_BYTES,
    RecordingError,
    events_of,
    joined,
    stated_t0,
    time_origin,
)
from edr.store.atomic import atomic_path

# The sensor of a Prophesee camera whose header names only its plugin (hal_plugin_<key>_...)
PLUGIN_SENSORS = {"gen3": (480, 640), "gen31": (480, 640), "gen4": (720, 1280),
                  "gen41": (720, 1280), "imx636": (720, 1280), "genx320": (320, 320)}  # fmt: skip
EVT_SIDE = 2048  # EVT 2.0 and 3.0 address x and y in 11 bits
# The longest span (µs, 25 days) the EVT 3.0 writer takes: its clock has 24 bits, and faery
# writes 4 TIME_HIGH words for each 2**24 µs after the first event, so at most 1 MiB of them.
EVT3_SPAN_US = 1 << 41


def faery_module(path: Path, format_name: str) -> ModuleType:
    """faery, or one line saying which extra brings it."""
    try:
        import faery
    except ImportError:
        raise RecordingError(
            path, format_name, "reading it needs faery: pip install 'edr[events]'"
        ) from None
    return faery


def _header_lines(path: Path) -> tuple[list[bytes], int]:
    """A Prophesee file's '%' header lines (to its ``% end`` line, if it has one) and where its
    data begins; read a line at a time, each bounded (a 100 MB file starting with '%' and no
    line end was read whole: 1.3 GB before its refusal)."""
    lines: list[bytes] = []
    with path.open("rb") as f:
        while f.peek(1)[:1] == b"%":
            line = f.readline(HEADER_LINE_BYTES)
            if not line.endswith(b"\n") and len(line) == HEADER_LINE_BYTES:
                raise RecordingError(
                    path, "Prophesee", f"a '%' header line runs past {HEADER_LINE_BYTES >> 10} "
                    "KiB without a line end: not a header; is it an event file?",
                )  # fmt: skip
            lines.append(line)
            if f.tell() > MAX_HEADER_BYTES:
                raise RecordingError(
                    path, "Prophesee", f"its '%' header runs past {MAX_HEADER_BYTES >> 20} MiB "
                    "(a camera writes a few hundred bytes): not a header; is it an event file?",
                )  # fmt: skip
            if line[1:].strip().lower() == b"end":
                break
        return lines, f.tell()


def prophesee_header(path: Path) -> dict[str, str]:
    """A Prophesee file's '% key value' header lines as a dict (lower-case keys)."""
    found: dict[str, str] = {}
    for line in _header_lines(path)[0]:
        key, _, value = line[1:].decode("latin-1").strip().partition(" ")
        found[key.lower()] = value.strip()
    return found


def data_offset(path: Path) -> int:
    """Where a Prophesee file's data begins: after its '%' header lines."""
    return _header_lines(path)[1]


def prophesee_sensor(path: Path) -> tuple[int, int] | None:
    """(height, width) as the header states it (geometry, format, or the camera's plugin)."""
    header = prophesee_header(path)
    if m := re.fullmatch(r"(\d+)x(\d+)", header.get("geometry", "")):
        return int(m[2]), int(m[1])
    fields = dict(re.findall(r"(width|height)=(\d+)", header.get("format", "")))
    if len(fields) == 2:
        return int(fields["height"]), int(fields["width"])
    if "height" in header and "width" in header:
        return int(header["height"]), int(header["width"])
    plugin = re.match(r"hal_plugin_([a-z0-9]+)", header.get("plugin_name", ""))
    return PLUGIN_SENSORS.get(plugin[1]) if plugin else None


def header_t0(path: Path, format_name: str) -> int:
    """The µs a Prophesee file's timestamps count from: its header's ``% t0``, else 0."""
    return stated_t0(path, format_name, prophesee_header(path).get("t0"))


def evt_version(path: Path) -> str | None:
    """'EVT 2.0' or 'EVT 3.0' as the header states it, else None."""
    header = prophesee_header(path)
    stated = header.get("evt", "") or header.get("format", "").split(";")[0]
    digits = re.sub(r"[^0-9]", "", stated)
    return {"2": "EVT 2.0", "20": "EVT 2.0", "21": "EVT 2.0", "3": "EVT 3.0", "30": "EVT 3.0"}.get(
        digits
    )


def evt2_chunks(path: Path) -> Iterator[np.ndarray]:
    """EVT 2.0 events, a few packets at a time, decoded by faery."""
    faery = faery_module(path, "EVT 2.0")
    size = path.stat().st_size - data_offset(path)
    if size % 4:  # EVT 2.0 words are 32-bit; faery drops a partial one silently
        raise RecordingError(
            path, "EVT 2.0", f"truncated: {size} bytes of words is not a multiple of 4"
        )
    height, width = prophesee_sensor(path) or (720, 1280)  # faery's own fallback
    try:
        stream = faery.events_stream_from_file(
            path, file_type="evt", dimensions_fallback=(width, height), version_fallback="evt2"
        )
        packets, held = [], 0
        for packet in chain(stream, [None]):  # (N,) faery's (t u64, x u16, y u16, on bool)
            if packet is not None:
                packets.append(packet)
                held += len(packet)
            if packets and (held >= CHUNK_EVENTS or packet is None):  # packets into one chunk
                chunk, packets, held = joined(packets), [], 0
                yield events_of(chunk["t"], chunk["x"], chunk["y"], chunk["on"])
    except Exception as error:  # faery's decoders raise plain Exceptions on a corrupt file
        message = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise RecordingError(path, "EVT 2.0", f"cannot be decoded ({message})") from None


def write_with_faery(
    path: Path, events: np.ndarray, sensor: tuple[int, int], format_name: str
) -> Path:
    """Events (EVENT_DTYPE, sorted) as EVT 3.0 (.raw) or AEDAT 4 (.aedat4), written by faery
    into a temporary file renamed over ``path`` (none is left when it fails)."""
    faery = faery_module(path, format_name)
    evt3 = format_name == "EVT 3.0"
    if evt3:  # refused before a byte is written
        time_origin(path, format_name, events["t"], EVT3_SPAN_US)
    packet = np.empty(len(events), faery.EVENTS_DTYPE)
    packet["t"], packet["x"], packet["y"], packet["on"] = (
        events["t"], events["x"], events["y"], events["p"] > 0,
    )  # fmt: skip
    height, width = sensor
    # zero_t0: times after the first event's, stated as '% t0' (header_t0 reads it back);
    # absolute ones cost 4 words per 2**24 µs since 0 (765 MB at DV's clock, 1.6e15 µs)
    options = {"version": "evt3", "zero_t0": True} if evt3 else {}
    with atomic_path(path) as tmp:  # tmp keeps path's suffix
        faery.events_stream_from_array(packet, dimensions=(width, height)).to_file(
            tmp, file_type="evt" if evt3 else "aedat", **options
        )
    return path


@njit(cache=True)
def _evt3_held(word):  # pragma: no cover (numba)
    """How many events one EVT 3.0 word holds."""
    w = np.int64(word)  # int64 arithmetic: a uint16's shifts and masks widen slowly
    kind = w >> 12
    if kind == 2:
        return 1
    n = 0
    if kind == 4 or kind == 5:
        mask = w & (0xFFF if kind == 4 else 0xFF)
        while mask:  # one turn per set bit
            mask &= mask - 1
            n += 1
    return n


@njit(cache=True)
def _evt3_count(words):  # pragma: no cover (numba)
    """How many events ``words`` (N,) uint16 hold (a loop without an exit: it vectorises)."""
    n = 0
    for i in range(len(words)):
        n += _evt3_held(words[i])
    return n


@njit(cache=True)
def _evt3_window(words, start, limit):  # pragma: no cover (numba)
    """From word ``start`` of ``words`` (N,) uint16, the words whose events number at most
    ``limit`` (at least one word): (the word after them, how many events they hold). Counted
    4096 words at a time, word by word only in the block that passes ``limit`` (10x faster
    than an exit tested at every word, which keeps the loop from vectorising)."""
    n, i = 0, start
    while i < len(words):
        held = _evt3_count(words[i : i + 4096])
        if n + held > limit:
            break
        n, i = n + held, i + 4096
    while i < len(words):
        held = _evt3_held(words[i])
        if n + held > limit and i > start:
            break
        n, i = n + held, i + 1
    return min(i, len(words)), n


@njit(cache=True)
def _evt3_decode(words, state, out):  # pragma: no cover (numba)
    """Decode ``words`` (N,) uint16 into ``out`` (EVENT_DTYPE, _evt3_window's events and one
    spare slot), record by record (4x faster than four column arrays copied in after);
    ``state`` (6,) int64 carries (time high, time low, wraps, y, base x, polarity) from one chunk
    to the next. The common words (EVT_ADDR_Y, EVT_ADDR_X) and a vector's bits are decoded
    without a branch, twice as fast: each writes the next slot ``out[n]`` and counts it only if
    it is an event (n never passes the events' count, so the spare slot is the furthest
    written). Returns the largest x of an event written: a run of vectors carries x past the
    11 bits (and int16 would wrap 65,636 to 100), which the caller refuses."""
    high, low, wraps, row, base, pol = state[0], state[1], state[2], state[3], state[4], state[5]
    time = wraps + (high << 12) + low
    n = 0
    widest = 0
    for i in range(len(words)):
        w = np.int64(words[i])
        kind = w >> 12
        if kind <= 2:  # EVT_ADDR_Y (0) sets y; EVT_ADDR_X (2) is one event (1 is unused)
            is_x = kind >> 1
            row = row if is_x else w & 0x7FF
            event = out[n]
            event.t, event.x, event.y, event.p = time, w & 0x7FF, row, (w >> 11) & 1
            n += is_x
        elif kind == 4 or kind == 5:  # VECT_12, VECT_8: an event at base + b for each set bit b
            width = 12 if kind == 4 else 8
            for b in range(width):
                event = out[n]
                event.t, event.x, event.y, event.p = time, base + b, row, pol
                n += (w >> b) & 1
            if base + width > EVT_SIDE:  # rare: only then the highest set bit is found
                bits = w & (0xFFF if kind == 4 else 0xFF)
                top = -1
                while bits:
                    bits >>= 1
                    top += 1
                if top >= 0:  # a vector without events only moves x on
                    widest = max(widest, base + top)
            base += width
        elif kind == 3:  # VECT_BASE_X
            base, pol = w & 0x7FF, (w >> 11) & 1
        elif kind == 6:  # EVT_TIME_LOW
            low = w & 0xFFF
            time = wraps + (high << 12) + low
        elif kind == 8:  # EVT_TIME_HIGH
            new = w & 0xFFF
            if new < high:
                wraps += 1 << 24
            high = new
            time = wraps + (high << 12) + low
    state[0], state[1], state[2], state[3], state[4], state[5] = high, low, wraps, row, base, pol
    return widest


def _evt3_words(path: Path) -> np.ndarray:
    """An EVT 3.0 file's 16-bit words (N,) uint16, memory-mapped."""
    offset = data_offset(path)
    size = path.stat().st_size - offset
    if size % 2:
        raise RecordingError(path, "EVT 3.0", f"truncated: {size} bytes of words is not even")
    if not size:
        return np.zeros(0, np.uint16)
    return np.asarray(np.memmap(path, dtype="<u2", mode="r", offset=offset))


def evt3_count(path: Path) -> int:
    """How many events an EVT 3.0 file holds (one pass over its words, no events made)."""
    return int(_evt3_count(_evt3_words(path)))


def evt3_chunks(path: Path) -> Iterator[np.ndarray]:
    """An EVT 3.0 file's events, chunks of at most CHUNK_EVENTS (EVENT_DTYPE), each decoded
    from the words that hold them: a word holds up to 12 events, so chunks of a fixed count of
    words were up to 12x larger (12M events, 150 MB, on a dense file)."""
    words = _evt3_words(path)
    state = np.zeros(6, np.int64)
    state[2] = header_t0(path, "EVT 3.0")  # the wraps' sum starts from the stated origin
    at = 0
    while at < len(words):
        stop, n = _evt3_window(words, at, CHUNK_EVENTS)
        events = np.empty(n + 1, EVENT_DTYPE)  # and _evt3_decode's spare slot
        widest = _evt3_decode(words[at:stop], state, events)
        if widest >= EVT_SIDE:  # stored in int16, it would have wrapped (65,636 -> 100)
            raise RecordingError(
                path, "EVT 3.0",
                f"x = {widest} outside any EVT 3.0 sensor (x in 0..{EVT_SIDE - 1}): a run of "
                f"vector words in words {at}..{stop} carries x past its 11 bits (a corrupt file)",
            )  # fmt: skip
        at = stop
        yield events[:n]


def dat_chunks(path: Path) -> Iterator[np.ndarray]:
    """A DAT file's CD events, a chunk at a time (EVENT_DTYPE)."""
    header = prophesee_header(path)
    offset = data_offset(path)
    if int(re.sub(r"\D", "", header.get("version", "2")) or 2) >= 2:
        offset += 2  # event type, event size
    size = path.stat().st_size - offset
    if size < 0:
        raise RecordingError(path, "DAT", "truncated inside its header")
    if size % 8:
        raise RecordingError(
            path, "DAT", f"truncated: {size} bytes of events is not a multiple of 8"
        )
    if not size:
        return
    t0 = header_t0(path, "DAT")
    words = np.memmap(path, dtype="<u4", mode="r", offset=offset).reshape(-1, 2)  # (N, 2): t, data
    for start in range(0, len(words), CHUNK_EVENTS):
        t = words[start : start + CHUNK_EVENTS, 0].astype(np.int64) + t0
        data = words[start : start + CHUNK_EVENTS, 1].astype(np.int64)
        yield events_of(t, data & 0x3FFF, (data >> 14) & 0x3FFF, np.minimum((data >> 28) & 0xF, 1))
