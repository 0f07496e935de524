"""``edr-tables``: every table and figure of the paper, regenerated from the records runs and
benchmarks wrote — the only writer of ``paper/``.

    edr-tables                                        # everything under results/, into paper/
    edr-tables --runs results/sweeps/kth_demo --out results/sweeps/kth_demo   # one sweep

Each table is written as Markdown and LaTeX and says where its numbers come from (data, scale,
machine, git, records); published numbers (``paper/published.yaml``) stand beside ours, never in
their place. Tables without records are skipped, and said to be.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from edr.atomic import write_text_atomic
from edr.report.atari import table1_atari
from edr.report.event_camera import table3_event_camera
from edr.report.features import features_table
from edr.report.figures import (
    atari_performance_profile,
    copy_pixel_response,
    fig5_atari_curves,
    fig6_ucf101_per_class,
    fig7b_dvs_confusion,
    fig10_kth_curves,
    fig11_activation_sparsity,
    learnable_edr_curves,
    write_figure,
)
from edr.report.flow_accuracy import flow_accuracy_table
from edr.report.published import PUBLISHED, load_published
from edr.report.recognition import ablation_edr, appendix_a_dvs, table2_ucf101, table4_kth
from edr.report.render import write_table
from edr.report.runs import load_runs
from edr.report.speed import atari_cost_table, speed_table


def _bench_records(bench_dir: Path, kind: str) -> list[tuple[Path, dict[str, Any]]]:
    """``<kind>_*.json`` records in ``bench_dir``, oldest first (by when they were measured:
    file times change with every checkout)."""
    found = [(p, json.loads(p.read_text())) for p in bench_dir.glob(f"{kind}_*.json")]
    return sorted(found, key=lambda item: (item[1].get("measured_at", ""), item[0].name))


def render_all(
    roots: list[Path], bench_dir: Path, out_dir: Path, published_path: Path
) -> dict[str, list[Path]]:
    """Every table and figure that has records; returns what was written, by name (empty where
    nothing was: no records)."""
    runs = load_runs(roots)
    published = load_published(published_path)
    speed = _bench_records(bench_dir, "speed")
    atari_costs = _bench_records(bench_dir, "atari")
    flow_accuracy = _bench_records(bench_dir, "flow_accuracy")
    written: dict[str, list[Path]] = {}
    tables = [
        features_table(),
        table1_atari(runs, published),
        table2_ucf101(runs, published, speed[-1][1] if speed else None),
        table3_event_camera(runs, published),
        table4_kth(runs, published),
        appendix_a_dvs(runs, published),
        ablation_edr(runs),
    ]
    for table in tables:
        written[table.name] = write_table(table, out_dir, published) if table.has_content else []
    if speed:
        path, record = speed[-1]
        written["table2_speed"] = [
            write_text_atomic(
                out_dir / "table2_speed.md",
                speed_table(record, published.get("speed", {}), str(path)),
            )
        ]
    if atari_costs:
        written["atari_edr_cost"] = [
            write_text_atomic(out_dir / "atari_edr_cost.md", atari_cost_table(atari_costs))
        ]
    if flow_accuracy:
        path, record = flow_accuracy[-1]
        written["flow_accuracy"] = [
            write_text_atomic(out_dir / "flow_accuracy.md", flow_accuracy_table(record, str(path)))
        ]
    figures = {
        "figure5_atari_curves": (
            "Figure 5: Atari training curves, FDR vs FDR+EDR",
            fig5_atari_curves(runs),
        ),
        "figure6_ucf101_per_class": (
            "Figure 6: UCF-101 per-class accuracy",
            fig6_ucf101_per_class(runs),
        ),
        "figure7b_dvs_confusion": (
            "Figure 7b: DVS transfer confusion matrix",
            fig7b_dvs_confusion(runs),
        ),
        "figure10_kth_curves": ("Figure 10: KTH learning curves", fig10_kth_curves(runs)),
        "figure11_activation_sparsity": (
            "Figure 11: activation sparsity per layer",
            fig11_activation_sparsity(runs),
        ),
        "learnable_edr": (
            "Learnable EDR: its values and gradient norm per epoch",
            learnable_edr_curves(runs),
        ),
        "atari_performance_profile": (
            "Performance profile of human-normalised Atari scores",
            atari_performance_profile(runs, published),
        ),
    }
    for name, (title, (figure_runs, draw)) in figures.items():
        written[name] = write_figure(name, title, figure_runs, draw, out_dir)
    written["figure3b_pixel_response"] = copy_pixel_response(runs, out_dir)
    return written


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="edr-tables",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument(
        "--runs",
        type=Path,
        action="append",
        help="a folder of run records (repeatable; default: results/)",
    )
    parser.add_argument(
        "--bench", type=Path, default=Path("results/bench"), help="edr-bench records"
    )
    parser.add_argument("--out", type=Path, default=Path("paper"), help="where tables go")
    parser.add_argument("--published", type=Path, default=PUBLISHED, help="published numbers")
    args = parser.parse_args(argv)
    roots = args.runs or [Path("results")]
    written = render_all(roots, args.bench, args.out, args.published)
    for name, paths in written.items():
        print(f"{name:30s} " + (", ".join(map(str, paths)) if paths else "no records: skipped"))


if __name__ == "__main__":
    main()
