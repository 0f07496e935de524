"""``edr-tables``: the paper's tables regenerated from the records our runs wrote.

    edr-tables                      # every table whose records exist
    edr-tables --results results --paper paper

Each table says where its numbers come from (data, scale, machine, records) and puts the
published numbers beside ours, never in their place.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from edr.records import read_record

# The paper's speed figures we can cite (fps), by our row names; the paper's own machine and code.
PUBLISHED_FPS = {"EDR K=1 soft gray": 9.8e3, "Brox flow": 6.3}
PUBLISHED_RATIOS = {
    "EDR / GrayDiff": "≈ 0.25 (GrayDiff ≈ 4x faster)",
    "EDR / optical flow": "≈ 1,500x (Brox)",
}


def _fps(rows: list[dict[str, Any]], name: str, implementation: str | None = None) -> float | None:
    """Best fps among the rows called ``name`` (and, if given, with that implementation)."""
    found = [
        r["fps"]
        for r in rows
        if r["name"] == name and (implementation is None or r["implementation"] == implementation)
    ]
    return max(found) if found else None


def _ratio(a: float | None, b: float | None, fmt: str) -> str:
    return format(a / b, fmt) if a and b else "n/a"


def speed_table(record: dict[str, Any], source: str = "") -> str:
    """Markdown for the speed column of Table 2 from one ``edr-bench`` record."""
    m = record["machine"]
    rows = record["rows"]
    lines = [
        "# Table 2, speed: representations per second, ours beside the paper's",
        "",
        f"- **Ours**: `edr-bench` on {m['cpu']} ({m['cpu_count']} cores), "
        f"{m['torch_threads']} torch / {m.get('numba_threads', '?')} numba threads, "
        f"allocator: {m.get('allocator', '?')}, GPU: {m.get('gpu') or 'none'}; {record['measured_at']}, git `{record['git']}`"
        + (f", record `{source}`" if source else "")
        + ".",
        f"- **Data**: {record['clip']}; {record['frames_per_call']} frames per call "
        f"(slow flows: fewer, see Frames); median of {record['repeats']} timed calls after "
        f"{record.get('warmup', 1)} warm-up call(s). "
        "Synthetic unless a video file is named: not a UCF-101 clip.",
        "- **Published**: the paper's figures, on its own machine and code; "
        "'—' where we have no published figure to cite.",
        "- fps counts input frames consumed per second (every env of a batch counted).",
        "",
        "| Representation | Implementation | Frame size | Frames | Ours (fps) | Published (fps) |",
        "|---|---|---|---:|---:|---:|",
    ]
    for r in rows:
        published = PUBLISHED_FPS.get(r["name"]) if "torch" not in r["implementation"] else None
        lines.append(
            f"| {r['name']} | {r['implementation']} | {r['frame_size']} | {r['frames']} | "
            f"{r['fps']:,.1f} | {f'{published:,.1f}' if published else '—'} |"
        )
    edr = _fps(rows, "EDR K=1 soft gray", "fused numba kernel")
    edr_k3 = _fps(rows, "EDR K=3 soft gray")
    edr_stream = _fps(rows, "EDR K=1 soft gray, streaming")
    gray_diff = _fps(rows, "GrayDiff")
    tvl1, farneback = _fps(rows, "TV-L1 flow"), _fps(rows, "Farneback flow")
    lines += [
        "",
        "Ratios, ours from this one run (GrayDiff = its fastest implementation here):",
        "",
        "| Ratio | Ours | Paper |",
        "|---|---:|---:|",
        f"| EDR K=1 / GrayDiff | {_ratio(edr, gray_diff, '.2f')} | {PUBLISHED_RATIOS['EDR / GrayDiff']} |",
        f"| EDR K=1 streaming (per frame) / GrayDiff (per clip) | {_ratio(edr_stream, gray_diff, '.2f')} | — |",
        f"| EDR K=3 / GrayDiff | {_ratio(edr_k3, gray_diff, '.2f')} | — |",
        f"| EDR K=1 / TV-L1 | {_ratio(edr, tvl1, ',.0f')}x | {PUBLISHED_RATIOS['EDR / optical flow']} |",
        f"| EDR K=1 / Farneback | {_ratio(edr, farneback, ',.0f')}x | — |",
        "",
    ]
    return "\n".join(lines)


def write_speed_table(record: dict[str, Any], path: Path, source: str = "") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(speed_table(record, source))
    tmp.replace(path)
    return path


def newest(pattern: str, root: Path) -> Path | None:
    found = sorted(root.glob(pattern), key=lambda p: p.stat().st_mtime)
    return found[-1] if found else None


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="edr-tables", description=__doc__.split("\n\n")[0])
    parser.add_argument("--results", type=Path, default=Path("results"), help="where runs wrote")
    parser.add_argument("--paper", type=Path, default=Path("paper"), help="where tables go")
    args = parser.parse_args(argv)
    written = []
    speed = newest("bench/speed_*.json", args.results)
    if speed is None:
        print(f"no speed record under {args.results}/bench: run edr-bench first")
    else:
        written.append(
            write_speed_table(read_record(speed), args.paper / "table2_speed.md", str(speed))
        )
    for path in written:
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
