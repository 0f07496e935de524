"""``edr-tables``: every table and figure of the paper, regenerated from the records runs and
benchmarks wrote — the only writer of ``paper/``.

    edr-tables                                        # paper/ from the records behind it
    edr-tables --runs results/sweeps/kth_demo --out results/sweeps/kth_demo   # one sweep

Plain, it renders the committed scope (:data:`COMMITTED_SCOPE`: the folders ``make paper``
names) into ``paper/``; with ``--runs``, the folders given, into ``--out`` (required: ``paper/``
holds the committed scope only, never a mix). Each table is written as Markdown and LaTeX and
says where its numbers come from (data, scale, machine, git, records); published numbers
(``paper/published.yaml``) stand beside ours, never in their place. Tables without records are
skipped, and said to be; every record that cannot be read or placed in a row is listed under the
tables, with the reason. Refused in one line, exit 2, before anything is written: a scope with
no records, ``--runs`` without ``--out``, a ``--bench`` folder or ``--published`` file named but
not there, a published-numbers file of the wrong shape; the defaults, where absent, are one line
each (the tables are rendered without them).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pandas as pd

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
from edr.report.published import PUBLISHED, BadPublished, load_published
from edr.report.recognition import ablation_edr, appendix_a_dvs, table2_ucf101, table4_kth
from edr.report.render import write_table
from edr.report.runs import BadRecord, displaced, load_runs, read_json, run_file
from edr.report.speed import atari_cost_table, latest_batch, speed_table
from edr.store.atomic import write_text_atomic

# paper/ as committed: the largest-scale records there are (each folder's command in
# results/learning/README.md) and the tiny sweeps of Table 2 and Figure 3b (make paper runs them).
LEARNING = ("table1_pong", "table1_pong_5m", "table1_centipede", "table1_breakout",
            "table1_mspacman", "table1_qbert", "table1_seaquest", "learnable_edr", "kth_demo",
            "kth_real", "kth_person", "ucf101_real", "speed_classes_demo", "dvs_transfer_demo",
            "learnable_edr_real", "event_camera_real", "event_camera_recordings")  # fmt: skip
COMMITTED_SCOPE = (*(Path("results/learning", name) for name in LEARNING),
                   Path("results/sweeps/tiny/table2"), Path("results/sweeps/tiny/demo"))  # fmt: skip
PAPER = Path("paper")
BENCH_DEFAULT = Path("results/bench")
Bench = tuple[Path, dict[str, Any]]


class Refused(ValueError):
    """edr-tables asked for what it does not do; one line, before anything is written."""


def _named_path(text: str) -> Path:
    """A path option's value; an empty one (an unset shell variable) is refused, not read as
    the current folder."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty path (an unset variable?): name a folder")
    return Path(text)


def _bench_records(
    bench_dir: Path, kind: str, render: Callable[[Bench], str], skipped: list[str]
) -> list[tuple[Bench, str]]:
    """``<kind>_*.json`` records in ``bench_dir`` with what ``render`` makes of each, oldest
    first (by when they were measured: file times change with every checkout); one that cannot
    be read, or lacks a field ``render`` reads, goes to ``skipped`` with the reason."""
    found = []
    for path in sorted(bench_dir.glob(f"{kind}_*.json")):
        try:
            record = read_json(run_file(bench_dir, path.name) or path)
            if not isinstance(record, dict) or not isinstance(record.get("measured_at", ""), str):
                raise BadRecord(f"{path.name} is not a bench record")
            found.append(((path, record), render((path, record))))
        except BadRecord as error:
            skipped.append(f"{path}: {error}")
        except (KeyError, TypeError, ValueError, AttributeError, IndexError) as error:
            skipped.append(f"{path}: not a bench record this table reads ({error!r})")
    return sorted(found, key=lambda item: (item[0][1].get("measured_at", ""), item[0][0].name))


def render_all(
    roots: list[Path], bench_dir: Path, out_dir: Path, published_path: Path
) -> dict[str, list[Path]]:
    """Every table and figure that has records; returns what was written, by name (empty where
    nothing was: no records)."""
    return render_runs(load_runs(roots), bench_dir, out_dir, load_published(published_path), [])


def render_runs(
    runs: pd.DataFrame,
    bench_dir: Path,
    out_dir: Path,
    published: dict[str, Any],
    skipped: list[str],
) -> dict[str, list[Path]]:
    """:func:`render_all` on loaded records; the bench records it cannot read go to
    ``skipped``."""
    speed = _bench_records(
        bench_dir, "speed", lambda item: speed_table([item], published.get("speed", {})), skipped
    )
    atari_costs = [
        item for item, _ in _bench_records(bench_dir, "atari", lambda one: atari_cost_table([one]),
                                           skipped)
    ]  # fmt: skip
    flow_accuracy = _bench_records(
        bench_dir, "flow_accuracy", lambda item: flow_accuracy_table(item[1], str(item[0])), skipped
    )
    written: dict[str, list[Path]] = {}
    tables = [
        features_table(),
        table1_atari(runs, published),
        table2_ucf101(runs, published, speed[-1][0][1] if speed else None),
        table3_event_camera(runs, published),
        table4_kth(runs, published),
        appendix_a_dvs(runs, published),
        ablation_edr(runs, published),
    ]
    for table in tables:
        written[table.name] = write_table(table, out_dir, published) if table.has_content else []
    if speed:
        batch = latest_batch([item for item, _ in speed])
        text = speed_table(batch, published.get("speed", {}))
        written["table2_speed"] = [write_text_atomic(out_dir / "table2_speed.md", text)]
    if atari_costs:
        written["atari_edr_cost"] = [
            write_text_atomic(out_dir / "atari_edr_cost.md", atari_cost_table(atari_costs))
        ]
    if flow_accuracy:
        written["flow_accuracy"] = [
            write_text_atomic(out_dir / "flow_accuracy.md", flow_accuracy[-1][1])
        ]
    figures = {
        "figure5_atari_curves": (
            "Figure 5: Atari training curves, FDR vs FDR+EDR",
            fig5_atari_curves(runs, published),
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
        written[name] = write_figure(name, title, figure_runs, draw, out_dir, published)
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
        type=_named_path,
        action="append",
        help="a folder of run records (repeatable; default: the committed scope, into paper/)",
    )
    parser.add_argument(
        "--bench", type=_named_path, default=BENCH_DEFAULT, help="edr-bench records"
    )
    parser.add_argument(
        "--out", type=_named_path, help="where tables go (default, for the committed scope: paper/)"
    )
    parser.add_argument(
        "--published", type=_named_path, default=PUBLISHED, help="published numbers"
    )
    args = parser.parse_args(argv)
    try:
        absent = _absent_inputs(
            {"--bench": (args.bench, BENCH_DEFAULT, "folder of edr-bench records"),
             "--published": (args.published, PUBLISHED, "file of published numbers")}
        )  # fmt: skip
        runs, out_dir, published = _scope(
            args.runs, args.out, args.published, args.bench, args.bench != BENCH_DEFAULT
        )
    except (Refused, BadPublished) as error:
        print(f"edr-tables: {error}", file=sys.stderr)
        raise SystemExit(2) from None
    for line in absent:
        print(f"edr-tables: {line}")
    skipped: list[str] = []
    try:
        written = render_runs(runs, args.bench, out_dir, published, skipped)
    except OSError as error:  # a read-only or full --out: nothing half written is left (atomic)
        print(f"edr-tables: cannot write the tables into {out_dir}: {error.strerror or error} "
              f"({error.filename or out_dir})", file=sys.stderr)  # fmt: skip
        raise SystemExit(2) from None
    for line in displaced(runs):
        print(line)
    for name, paths in written.items():
        print(f"{name:30s} " + (", ".join(map(str, paths)) if paths else "no records: skipped"))
    for row in runs[runs["status"].isin(["unreadable", "not counted"])].itertuples():
        skipped.append(f"{row.record}: {row.error}")
    if skipped:
        print(f"not read or not counted ({len(skipped)}; the records are listed under the tables "
              "too):")  # fmt: skip
        print("\n".join(f"  {line}" for line in skipped))


def _absent_inputs(inputs: dict[str, tuple[Path, Path, str]]) -> list[str]:
    """One line for each input (option -> (its path, its default, what it is)) that is absent
    by default: the tables render without it. One named but absent is :class:`Refused`."""
    lines = []
    for option, (path, default, what) in inputs.items():
        kind = what.split()[0]  # folder or file
        if path.is_dir() if kind == "folder" else path.exists():
            continue
        if path != default or path.exists():
            raise Refused(f"{option} {path}: no such {kind}; name an existing {what}")
        lines.append(f"{option} {path} (the default) is absent: rendered without its {what}")
    return lines


def _scope(
    roots: list[Path] | None, out: Path | None, published_path: Path, bench_dir: Path,
    bench_named: bool = False,
) -> tuple[pd.DataFrame, Path, dict[str, Any]]:  # fmt: skip
    """(the records, the output folder, the published numbers) edr-tables renders; each way it
    refuses, :class:`Refused` in one line."""
    if roots and out is None:
        raise Refused(
            "--runs needs --out: paper/ holds the committed scope only (edr-tables with no "
            "--runs renders it)"
        )
    if roots and out is not None and (project_paper := _projects_paper(out)) is not None:
        raise Refused(
            f"--out {out}: {project_paper} holds the committed scope only, rendered by edr-tables "
            "with no --runs; write your runs' tables into another folder"
        )
    empty = []
    for root in roots or ():
        if not root.is_dir():
            raise Refused(f"--runs {root}: no such folder")
        if next(root.rglob("run.json"), None) is None:
            empty.append(root)
    # a --runs folder without a record is a typo or a mistake, beside others that hold some, or
    # alone unless --bench was named: the bench tables alone are what was asked for then
    if empty and (len(empty) < len(roots or ()) or not bench_named):
        raise Refused(f"no records found under {empty[0]} (--runs: it holds no run.json)")
    published = load_published(published_path)
    if not roots:
        present = [p for p in COMMITTED_SCOPE if p.is_dir()]
        if present and len(present) < len(COMMITTED_SCOPE):
            missing = ", ".join(str(p) for p in COMMITTED_SCOPE if p not in present)
            raise Refused(
                f"paper/ is rendered from the committed records and the tiny sweeps; {missing} "
                "not found: `make paper` runs those sweeps, then renders paper/ (your own runs: "
                "edr-tables --runs DIR --out DIR)"
            )
    scope = roots or list(COMMITTED_SCOPE)
    runs = load_runs([p for p in scope if p.is_dir()])
    if runs.empty and not any(bench_dir.glob("*.json")):  # bench records alone render too
        raise Refused(f"no records found under {', '.join(map(str, [*scope, bench_dir]))}")
    return runs, out or PAPER, published


def _projects_paper(path: Path) -> Path | None:
    """The paper/ of a checkout of this project that ``path`` is or lies in, from whatever
    folder it is named (a paper/ with its README, beside the package's src/edr); None for a
    folder of that name elsewhere, which is the user's."""
    resolved = path.resolve()
    for folder in (resolved, *resolved.parents):
        if (
            folder.name == PAPER.name
            and (folder / "README.md").is_file()
            and (folder.parent / "src" / "edr").is_dir()
        ):
            return folder
    return None


if __name__ == "__main__":
    main()
