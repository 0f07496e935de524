"""Table 3: event camera vs frame camera — data rate and sparsity of each representation of the
same clip (``task=event_camera``), a real camera's recording measured beside them
(``task.events=<file>``, the row labelled with its sensor and file), and the paper's hardware
rows."""

from __future__ import annotations

from typing import Any

import pandas as pd

from edr.report.published import lookup
from edr.report.render import Table, mean_std
from edr.report.runs import cells, finished, placeable, unfinished

RATES = ("events_per_s", "bits_per_s", "bits_per_event", "events_per_pixel_frame", "sparsity")
FILE_RATES = ("file_bits_per_s", "file_bits_per_event")  # a real recording's, in its own bytes
RECORDING = ("data.events_file", "data.events_sensor", "data.events_format",
             "data.events_sensor_stated", "data.fps")  # fmt: skip


def _mean(cell: pd.Series, metric: str, fmt: str) -> str:
    """The metric's mean over the cell's runs, ± their std where the runs differ (the event
    counts of a clip are deterministic: repeats give the same number, no spread to show)."""
    mean = cell.get(f"metrics.{metric}:mean", float("nan"))
    std = cell.get(f"metrics.{metric}:std", float("nan"))
    return mean_std(mean, float("nan") if std == 0 else std, fmt=fmt)


def _runs(cell: pd.Series, name: str) -> str:
    """How many runs stand behind a row, and whether they all gave the same numbers."""
    stds = [v for k, v in cell.items() if k.startswith(f"metrics.{name}/") and k.endswith(":std")]
    same = cell["runs"] > 1 and all(v == 0 for v in stds if not pd.isna(v))
    return f"{cell['runs']}, identical" if same else str(cell["runs"])


def table3_event_camera(runs: pd.DataFrame, published: dict[str, Any]) -> Table:
    done = finished(runs, "event_camera")
    names = sorted(
        {
            c.split(".", 1)[1].rsplit("/", 1)[0]
            for c in done.columns
            if c.startswith("metrics.") and c.endswith("/bits_per_s")
        }
    )
    metrics = [c for n in names for r in (*RATES, *FILE_RATES) if (c := f"metrics.{n}/{r}") in done]
    done, unplaced = placeable(done, ["data.video", "data.size"])
    recording = [c for c in RECORDING if c in done]
    grouped = cells(done, metrics, ["data.video", "data.size", *recording])
    measured = grouped.get("data.events_file", pd.Series(index=grouped.index, dtype=object))
    # clips that runs without a recording cover: runs with one add only their camera's row there
    covered = {(c["data.video"], c["data.size"]) for _, c in grouped[measured.isna()].iterrows()}
    rows = []
    for _, cell in grouped.iterrows():
        frames_bits = cell.get("metrics.frames/bits_per_s:mean")
        has_recording = not pd.isna(cell.get("data.events_file"))
        for n in names:
            if pd.isna(cell[f"metrics.{n}/bits_per_s:mean"]):
                continue
            bits = cell[f"metrics.{n}/bits_per_s:mean"]
            camera = n == "camera" and has_recording
            if has_recording and not camera and (cell["data.video"], cell["data.size"]) in covered:
                continue
            against = frames_bits
            if camera:  # against a frame camera of the same sensor, 8 bits a pixel, at fps
                width, height = (int(v) for v in str(cell["data.events_sensor"]).split("x"))
                against = width * height * 8 * float(cell["data.fps"])
            rows.append(
                {
                    "Clip": (
                        f"recording {cell['data.events_file']} ({cell['data.events_format']})"
                        if camera
                        else f"{cell['data.video']}, {cell['data.size']}"
                    ),
                    "Representation": (
                        f"event camera, {cell['data.events_sensor']}"
                        + ("" if cell.get("data.events_sensor_stated") else " (events' span)")
                        if camera
                        else n
                    ),
                    "Events/s": _mean(cell, f"{n}/events_per_s", ",.0f"),
                    "bits/s": _mean(cell, f"{n}/bits_per_s", ",.0f"),
                    "bits/event": _mean(cell, f"{n}/bits_per_event", ".0f"),
                    "bits/s (file)": _mean(cell, f"{n}/file_bits_per_s", ",.0f"),
                    "bits/event (file)": _mean(cell, f"{n}/file_bits_per_event", ".1f"),
                    "Events/pixel/frame": _mean(cell, f"{n}/events_per_pixel_frame", ".4f"),
                    "Sparsity": _mean(cell, f"{n}/sparsity", ".3f"),
                    "bits vs frames": "—" if not against else f"{bits / against:.3f}",
                    "Runs": _runs(cell, n),
                }
            )
    hardware = lookup(published, "table3_event_camera", "rows") or []
    cameras = lookup(published, "table3_event_camera", "cameras") or {}
    paper = pd.DataFrame(hardware).rename(
        columns={
            "specification": "Specification",
            "frame_camera": f"Frame camera ({cameras.get('frame_camera', '?')})",
            "event_camera": f"Event camera ({cameras.get('event_camera', '?')})",
        }
    )
    return Table(
        "table3_event_camera",
        "Table 3: event camera vs frame camera — data rate and sparsity on the same clip",
        # a clip's rows repeat in each run that also measured a recording: shown once
        pd.DataFrame(rows).drop_duplicates(subset=[c for c in rows[0] if c != "Runs"])
        if rows
        else pd.DataFrame(rows),
        done.assign(scale=done["scale"].replace("full", "whole clip")),  # none is a protocol
        notes=[
            "Runs: repeats of a clip with other seeds; 'identical': they gave the same numbers "
            "(the event counts are deterministic), so they are one measurement, not a spread.",
            "Events: for event counts (DVS simulator, hard EDR) their sum, for graded outputs "
            "(soft EDR) the non-zero entries. bits/event: address (x, y, channel) + a 32-bit "
            "timestamp (+ a 16-bit value for graded events). Frames: every pixel, 8 bits. "
            "Sparsity: the fraction of zero outputs. bits vs frames: bits/s over the frames'. "
            "Events/pixel/frame: events per pixel per frame interval. A real camera's row "
            "(task.events=<file>): its recording, with bits/s in the paper's model (address + "
            "timestamp) and in the file's own bytes per event ('file'); its frame interval is "
            "the task's fps, and its bits vs frames is against a frame camera of its own "
            "sensor (8 bits a pixel at that fps). A sensor marked (events' span) is not stated "
            "by its file.",
        ],
        unfinished=unfinished(runs, "event_camera", unplaced),
        paper=paper,
        paper_notes=[
            f"Source: {lookup(published, 'table3_event_camera', 'source')}. The paper compares "
            "camera specifications; ours measures data rates of representations on one clip: "
            "compare the event camera's 4 Mbps and the frame camera's 360 Mbps with our bits/s."
        ],
    )
