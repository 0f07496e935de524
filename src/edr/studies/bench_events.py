"""``edr-bench --events FILE ...``: how fast the suite reads event recordings (events/s), each
file read whole by :func:`edr.data.events.read_recording` (decoded, checked, sorted): the median
and the best of ``repeats`` reads after one untimed read (which also compiles the numba
decoders), and the machine's load average, since a shared machine's median says more about
its neighbours than about the reader. EVT 3.0 and AEDAT 4 must read at least ``FLOOR_EVENTS_PER_S``
(issue 34); their rows say whether the median did."""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

from tabulate import tabulate

from edr.data.events import detect_format, read_recording
from edr.store.atomic import write_json_atomic
from edr.store.records import git_revision, machine_info

FLOOR_EVENTS_PER_S = {"EVT 3.0": 10e6, "AEDAT 4": 10e6}  # the median a read must reach


def run_events_bench(args: argparse.Namespace, repeats: int) -> None:
    rows = []
    for path in args.events:
        events = read_recording(path)  # untimed: page cache, numba's compiled decoders
        spent = []
        for _ in range(repeats):
            start = time.perf_counter()
            read_recording(path)
            spent.append(time.perf_counter() - start)
        seconds = statistics.median(spent)
        rows.append({"file": Path(path).name, "format": detect_format(path).name,
                     "events": len(events), "bytes": Path(path).stat().st_size,
                     "seconds": seconds, "events_per_s": len(events) / seconds,
                     "best_events_per_s": len(events) / min(spent)})  # fmt: skip
    stamp = time.strftime("%Y-%m-%d_%H-%M-%S")
    machine = machine_info()
    record = {"kind": "event_read", "repeats": repeats, "git": git_revision(),
              "measured_at": stamp, "load_average_1min": os.getloadavg()[0],
              "machine": machine, "rows": rows}  # fmt: skip
    out = write_json_atomic(args.out_dir / f"events_{machine['hostname']}_{stamp}.json", record)
    table = [[r["file"], r["format"], f"{r['events']:,}", f"{r['seconds'] * 1e3:.2f}",
              f"{r['events_per_s'] / 1e6:.1f}", f"{r['best_events_per_s'] / 1e6:.1f}",
              _floor(r["format"], r["events_per_s"])]
             for r in rows]  # fmt: skip
    header = ["file", "format", "events", "ms a read", "M events/s (median)", "best M events/s",
              "floor"]  # fmt: skip
    print(tabulate(table, header, "pipe"))
    print(f"load average (1 min): {record['load_average_1min']:.1f}")
    print(f"record: {out}")


def _floor(format_name: str, events_per_s: float) -> str:
    """'>= 10 M/s: met' (or 'missed') for a format with a floor, else ''."""
    floor = FLOOR_EVENTS_PER_S.get(format_name)
    if floor is None:
        return ""
    return f">= {floor / 1e6:.0f} M/s: {'met' if events_per_s >= floor else 'missed'}"
