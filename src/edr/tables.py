"""``edr-tables``: the paper's tables regenerated from the records our runs wrote.

    edr-tables                      # every table whose records exist, into paper/
    edr-tables --runs results/sweeps/kth_demo --out results/sweeps/kth_demo/table4.md

Each table says where its numbers come from (data, scale, machine, records) and puts the
published numbers beside ours, never in their place.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from edr.atomic import write_text_atomic
from edr.records import read_record

# The paper's KTH accuracy we can cite, by (representation, backbone) config names.
PUBLISHED_KTH = {("edr", "nin_ftrcn"): 94.4}
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
    return write_text_atomic(path, speed_table(record, source))


def atari_cost_table(records: list[tuple[Path, dict[str, Any]]]) -> str:
    """Markdown: one row per ``edr-bench --atari`` record, EDR's cost in env steps per second."""
    paired = [(p, r) for p, r in records if "costs" in r]
    lines = [
        "# What EDR costs in the Atari loop: env steps per second with and without it",
        "",
        "`edr-bench --atari ENVS`: a torchrl ParallelEnv of ENVS games, paac preset, random",
        "actions, played as a collector plays them; FDR RGB vs FDR RGB + EDR on gray (Appendix C's",
        "5 channels per frame), both stacked over the frames given, in the observation dtype given.",
        "The two envs take turns; the cost is the median over pairs of rollouts of",
        "1 - (FDR+EDR steps/s) / (FDR steps/s), with the pairs' range. The goal is at most 5 %.",
        "Main CPU: CPU milliseconds the main process",
        "spends per agent step, FDR / FDR + EDR (torchrl's ParallelEnv spins while its workers run).",
        "",
        "| Game | Envs | Frames stacked | Observation | FDR (steps/s) | FDR + EDR (steps/s) | EDR costs | Pairs | Main CPU (ms/step) | Machine | Measured, git | Record |",
        "|---|---:|---:|---|---:|---:|---:|---|---|---|---|---|",
    ]
    for path, r in paired:
        fdr, edr = r["rows"]
        costs, m = r["costs"], r["machine"]
        lines.append(
            f"| {r['game']} | {r['num_envs']} | {r['frame_stack']} | "
            f"{r.get('obs_dtype', 'float32')} | {fdr['fps']:,.1f} | "
            f"{edr['fps']:,.1f} | {r['cost']:.1f} % | {len(costs)}: {min(costs):.1f} to "
            f"{max(costs):.1f} % | {' / '.join(f'{ms:.1f}' for ms in r['main_cpu_ms'])} | "
            f"{m['cpu']} ({m['cpu_count']} cores), GPU: {m.get('gpu') or 'none'} | "
            f"{r['measured_at']}, `{r['git']}` | `{path.name}` |"
        )
    older = [p.name for p, r in records if "costs" not in r]
    if older:
        lines += ["", f"Older records, from before paired timing, not shown: {', '.join(older)}."]
    return "\n".join([*lines, ""])


def write_atari_cost_table(bench_dir: Path, path: Path) -> Path | None:
    """The table of every ``atari_*.json`` record in ``bench_dir``, oldest first; None if none."""
    found = sorted(bench_dir.glob("atari_*.json"), key=lambda p: p.stat().st_mtime)
    if not found:
        return None
    return write_text_atomic(path, atari_cost_table([(p, read_record(p)) for p in found]))


def recognition_table(records: list[tuple[Path, dict[str, Any]]], title: str) -> str:
    """Markdown: one row per (representation, backbone), accuracy averaged over seeds."""
    groups: dict[tuple[str, str, bool], list[tuple[Path, dict[str, Any]]]] = {}
    for path, record in records:
        choice = record.get("choices", {})
        key = (
            choice.get("representation", "?"),
            choice.get("backbone", "?"),
            record["data"]["synthetic"],
        )
        groups.setdefault(key, []).append((path, record))
    lines = [
        f"# {title}",
        "",
        "Video accuracy on the test split (10 crops, averaged softmax), mean over the runs listed.",
        "**Data** says whether the runs used the real data set or the generated one in its layout;",
        "generated results are not the paper's data set and are never comparable to its numbers.",
        "",
        "| Representation | Backbone | Data | Videos (train/test) | Runs | Accuracy (%) | Chance (%) | Published (%) | Machine |",
        "|---|---|---|---|---:|---:|---:|---:|---|",
    ]
    for (rep, backbone, synthetic), runs in sorted(groups.items()):
        metrics = [r["metrics"] for _, r in runs]
        data = runs[0][1]["data"]
        accuracy = 100 * sum(m["eval/accuracy"] for m in metrics) / len(metrics)
        published = PUBLISHED_KTH.get((rep, backbone)) if not synthetic else None
        machine = runs[0][1]["machine"]
        lines.append(
            f"| {rep} | {backbone} | {'generated (synthetic)' if synthetic else 'real'} | "
            f"{data['train_videos']}/{data['test_videos']} | {len(runs)} | {accuracy:.1f} | "
            f"{100 * metrics[0]['eval/chance']:.1f} | {published if published else '—'} | "
            f"{machine['cpu']}, GPU: {machine.get('gpu') or 'none'} |"
        )
    lines += ["", "Records:", ""] + [f"- `{path}`" for path, _ in records] + [""]
    return "\n".join(lines)


def task_records(root: Path, task: str) -> list[tuple[Path, dict[str, Any]]]:
    """Every finished run record under ``root`` (runs and sweeps) of ``task``, oldest first."""
    found = [
        (p, read_record(p)) for p in sorted(root.rglob("run.json"), key=lambda p: p.stat().st_mtime)
    ]
    return [(p, r) for p, r in found if r.get("task") == task and r.get("status") == "finished"]


def newest(pattern: str, root: Path) -> Path | None:
    found = sorted(root.glob(pattern), key=lambda p: p.stat().st_mtime)
    return found[-1] if found else None


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="edr-tables", description=__doc__.split("\n\n")[0])
    parser.add_argument("--results", type=Path, default=Path("results"), help="where runs wrote")
    parser.add_argument("--paper", type=Path, default=Path("paper"), help="where tables go")
    parser.add_argument("--runs", type=Path, help="only the KTH runs under this folder (a sweep)")
    parser.add_argument(
        "--out", type=Path, help="with --runs: where its table goes (else printed only)"
    )
    args = parser.parse_args(argv)
    if args.runs:
        records = task_records(args.runs, "kth")
        if not records:
            raise SystemExit(f"no KTH run records under {args.runs}")
        text = recognition_table(records, f"Table 4 style: KTH runs under {args.runs}")
        print(text)
        if args.out:
            print(f"wrote {write_text_atomic(args.out, text)}")
        return
    written = []
    speed = newest("bench/speed_*.json", args.results)
    if speed is None:
        print(f"no speed record under {args.results}/bench: run edr-bench first")
    else:
        written.append(
            write_speed_table(read_record(speed), args.paper / "table2_speed.md", str(speed))
        )
    atari = write_atari_cost_table(args.results / "bench", args.paper / "atari_edr_cost.md")
    if atari is not None:
        written.append(atari)
    kth_runs = task_records(args.results, "kth")
    if kth_runs:
        text = recognition_table(kth_runs, "Table 4: KTH, ours beside the paper's")
        written.append(write_text_atomic(args.paper / "table4_kth.md", text))
    for path in written:
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
