"""The optical-flow accuracy table (``paper/flow_accuracy.md``) from a record of
``python -m edr.studies.flows``."""

from __future__ import annotations

from typing import Any

from edr.report.render import uncommitted

KINDS = ("translation", "rotation", "zoom", "smooth")  # the known flows each method is scored on


def flow_accuracy_table(record: dict[str, Any], source: str = "") -> str:
    """Markdown: each method's average endpoint error on each kind of known flow."""
    m = record["machine"]
    lines = [
        "# Optical flow against ground truth: average endpoint error (pixels, lower is better)",
        "",
        "`python -m edr.studies.flows`: pairs made by warping matplotlib's `grace_hopper.jpg`",
        "(gray, 320x240) with known flows: translation (2.3, -1.4) px, rotation 2 degrees about the",
        "centre, zoom 3 %, a smooth random field (Gaussian-smoothed noise, sigma 25 px, at most",
        f"3 px). EPE over the image less a {record['border']}-pixel border; each method with its",
        "defaults as `representation=...` runs it (speed: `edr-bench`, Table 2's speed rows).",
        f"Machine: {m['cpu']} ({m['cpu_count']} cores), GPU: {m.get('gpu') or 'none'}; "
        f"measured {record['measured_at']}, git `{record['git']}`"
        + (f", record `{source}`" if source else "")
        + ".",
        *([f"Uncommitted code: {dirty}."] if (dirty := uncommitted([record["git"]])) else []),
        "",
        "| Method | " + " | ".join(KINDS) + " |",
        "|---|" + "---:|" * len(KINDS),
    ]
    for name, by_kind in record["epe"].items():
        lines.append(f"| {name} | " + " | ".join(f"{by_kind[k]:.3f}" for k in KINDS) + " |")
    return "\n".join([*lines, ""])
