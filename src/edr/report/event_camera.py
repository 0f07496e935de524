"""Table 3: event camera vs frame camera — data rate and sparsity of each representation of the
same clip (``task=event_camera``), beside the paper's hardware rows."""

from __future__ import annotations

from typing import Any

import pandas as pd

from edr.report.published import lookup
from edr.report.render import Table, mean_std
from edr.report.runs import cells, finished, placeable, unfinished

RATES = ("events_per_s", "bits_per_s", "bits_per_event", "sparsity")


def table3_event_camera(runs: pd.DataFrame, published: dict[str, Any]) -> Table:
    done = finished(runs, "event_camera")
    names = sorted(
        {
            c.split(".", 1)[1].rsplit("/", 1)[0]
            for c in done.columns
            if c.startswith("metrics.") and c.endswith("/bits_per_s")
        }
    )
    metrics = [f"metrics.{n}/{r}" for n in names for r in RATES]
    done, unplaced = placeable(done, ["data.video", "data.size"])
    grouped = cells(done, metrics, ["data.video", "data.size"])
    rows = []
    for _, cell in grouped.iterrows():
        frames_bits = cell.get("metrics.frames/bits_per_s:mean")
        for n in names:
            if pd.isna(cell[f"metrics.{n}/bits_per_s:mean"]):
                continue
            bits = cell[f"metrics.{n}/bits_per_s:mean"]
            rows.append(
                {
                    "Clip": f"{cell['data.video']}, {cell['data.size']}",
                    "Representation": n,
                    "Events/s": mean_std(
                        cell[f"metrics.{n}/events_per_s:mean"],
                        cell[f"metrics.{n}/events_per_s:std"],
                        fmt=",.0f",
                    ),
                    "bits/s": mean_std(bits, cell[f"metrics.{n}/bits_per_s:std"], fmt=",.0f"),
                    "bits/event": mean_std(
                        cell[f"metrics.{n}/bits_per_event:mean"], float("nan"), fmt=".0f"
                    ),
                    "Sparsity": mean_std(
                        cell[f"metrics.{n}/sparsity:mean"],
                        cell[f"metrics.{n}/sparsity:std"],
                        fmt=".3f",
                    ),
                    "bits vs frames": "—" if not frames_bits else f"{bits / frames_bits:.3f}",
                    "Runs": cell["runs"],
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
        pd.DataFrame(rows),
        done,
        notes=[
            "Events: for event counts (DVS simulator, hard EDR) their sum, for graded outputs "
            "(soft EDR) the non-zero entries. bits/event: address (x, y, channel) + a 32-bit "
            "timestamp (+ a 16-bit value for graded events). Frames: every pixel, 8 bits. "
            "Sparsity: the fraction of zero outputs. bits vs frames: bits/s over the frames'.",
        ],
        unfinished=unfinished(runs, "event_camera", unplaced),
        paper=paper,
        paper_notes=[
            f"Source: {lookup(published, 'table3_event_camera', 'source')}. The paper compares "
            "camera specifications; ours measures data rates of representations on one clip: "
            "compare the event camera's 4 Mbps and the frame camera's 360 Mbps with our bits/s."
        ],
    )
