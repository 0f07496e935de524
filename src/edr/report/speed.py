"""Tables of ``edr-bench`` records: Table 2's speed column (with the ratios) and what EDR costs
in the Atari loop. ``edr-bench`` prints them; ``edr-tables`` writes them to ``paper/``."""

from __future__ import annotations

import statistics
from pathlib import Path
from typing import Any

from edr.report.published import cite, lookup
from edr.report.render import uncommitted

# The learnable EDR's rows: forward+backward after one optimizer step (as in training), and
# inference of the same clip timed in turn with it (A B A B), which their ratio compares.
LEARNABLE = "EDR K=1 soft gray, learnable"
TRAIN_FUSED = "fused kernels, forward+backward, after one Adam step"
TRAIN_TORCH = "torch ops, forward+backward, after one Adam step"
INFERENCE_IN_TURN = "inference (fused kernel), in turn with fused forward+backward"
# Bench row names -> the representation names published.yaml uses.
# Bench rows -> the paper's speed figure of that representation (published.yaml's speed.fps)
PUBLISHED_ROW_NAMES = {
    "EDR K=1 soft gray": "edr",
    "GrayDiff": "graydiff",
    "RGBDiff": "rgbdiff",
    "MPEG flow": "mpeg_flow",
    "Farneback flow": "farneback",
    "TV-L1 flow": "tvl1",
    "Brox flow": "brox",
}
# Config names (representation/) -> the bench row that times them (name, implementation).
BENCH_ROWS = {
    "edr": ("EDR K=1 soft gray", "fused numba kernel"),
    "edr_k3": ("EDR K=3 soft gray", "fused numba kernel"),
    "graydiff": ("GrayDiff", None),
    "rgbdiff": ("RGBDiff", None),
    "fdr": ("FDR (RGB frames)", None),
    "mpeg_flow": ("MPEG flow", None),
    "farneback": ("Farneback flow", None),
    "tvl1": ("TV-L1 flow", None),
    "brox": ("Brox flow", None),
    "dvs": ("DVS simulator", None),
}


def bench_fps(
    rows: list[dict[str, Any]], name: str, implementation: str | None = None
) -> float | None:
    """Best fps among the rows called ``name`` (and, if given, with that implementation)."""
    found = [
        r["fps"]
        for r in rows
        if r["name"] == name and (implementation is None or r["implementation"] == implementation)
    ]
    return max(found) if found else None


def _ratio(a: float | None, b: float | None, fmt: str) -> str:
    return format(a / b, fmt) if a and b else "n/a"


def _run_ratios(rows: list[dict[str, Any]]) -> list[str]:
    """One bench run's ratios, in :data:`RATIOS`' order."""
    edr = bench_fps(rows, "EDR K=1 soft gray", "fused numba kernel")
    edr_k3 = bench_fps(rows, "EDR K=3 soft gray")
    edr_stream = bench_fps(rows, "EDR K=1 soft gray, streaming")
    # records from before the step (the parameters at their initial values) have the old names
    train_fused = bench_fps(rows, LEARNABLE, TRAIN_FUSED) or bench_fps(
        rows, LEARNABLE, "fused kernels, forward+backward"
    )
    train_torch = bench_fps(rows, LEARNABLE, TRAIN_TORCH) or bench_fps(
        rows, LEARNABLE, "torch ops, forward+backward"
    )
    # records before the pair was timed in turn: the inference row, timed on its own
    inference_in_turn = bench_fps(rows, LEARNABLE, INFERENCE_IN_TURN) or edr
    gray_diff = bench_fps(rows, "GrayDiff")
    tvl1, farneback = bench_fps(rows, "TV-L1 flow"), bench_fps(rows, "Farneback flow")
    brox = bench_fps(rows, "Brox flow")
    busy = "EDR K=1 soft gray, busy neighbour"
    busy_all = bench_fps(rows, busy, "fused numba kernel, all threads")
    busy_one = bench_fps(rows, busy, "fused numba kernel, 1 thread")
    long_edr = next(
        (
            r["name"]
            for r in rows
            if r["name"].startswith("EDR K=1 soft gray, ") and r["name"].endswith("-frame clip")
        ),
        "",
    )
    long_gray = long_edr.replace("EDR K=1 soft gray", "GrayDiff")
    plain = bench_fps(rows, long_edr, "fused kernel, plain call")
    kept = bench_fps(rows, long_edr, "fused kernel, plain call, glibc keeping freed memory")
    edr_out, gray_out = (
        bench_fps(rows, n, "fused kernel, into out=") for n in (long_edr, long_gray)
    )
    return [
        _ratio(edr, gray_diff, ".2f"),
        _ratio(edr_stream, gray_diff, ".2f"),
        _ratio(edr_k3, gray_diff, ".2f"),
        _ratio(train_fused, inference_in_turn, ".3f"),
        _ratio(train_fused, train_torch, ".1f") + "x",
        _ratio(edr, brox, ",.0f") + "x",
        _ratio(edr, tvl1, ",.0f") + "x",
        _ratio(edr, farneback, ",.0f") + "x",
        _ratio(busy_all, busy_one, ".2f"),
        _ratio(plain, kept, ".2f"),
        _ratio(edr_out, gray_out, ".2f"),
    ]


# The ratio table's rows: what each compares, and the published.yaml speed key of the paper's
RATIOS = (
    ("EDR K=1 / GrayDiff", "edr_over_graydiff"),
    ("EDR K=1 streaming (per frame) / GrayDiff (per clip)", None),
    ("EDR K=3 / GrayDiff", None),
    ("EDR K=1 learnable, forward+backward (fused) / inference, timed in turn", None),
    ("EDR K=1 learnable, forward+backward: fused / torch ops", None),
    ("EDR K=1 / Brox", "edr_over_optical_flow"),
    ("EDR K=1 / TV-L1", None),
    ("EDR K=1 / Farneback", None),
    ("EDR K=1, busy neighbour: all threads / 1 thread", None),
    ("EDR K=1, long clip: plain call / glibc keeping freed memory", None),
    ("EDR K=1 / GrayDiff, long clip, both into out=", None),
)


def ratio_lines(runs: list[list[dict[str, Any]]], published: dict[str, Any]) -> list[str]:
    """A Markdown table of EDR's speed over GrayDiff's and the flows', each bench run's (the
    rows of every run given, one after another), beside the paper's ratios (``published``: the
    published numbers' ``speed`` section)."""
    per_run = [_run_ratios(rows) for rows in runs]
    lines = ["| Ratio | Ours | Paper |", "|---|---:|---:|"]
    for k, (name, paper) in enumerate(RATIOS):
        ours = " / ".join(ratios[k] for ratios in per_run)
        lines.append(f"| {name} | {ours} | {cite(published.get(paper)) if paper else '—'} |")
    return lines


def latest_batch(records: list[tuple[Path, dict[str, Any]]]) -> list[tuple[Path, dict[str, Any]]]:
    """The newest bench records of one code and machine (``records`` oldest first): the runs
    made in a row whose spread the speed table shows."""
    if not records:
        return []
    last = records[-1][1]

    def same(record: dict[str, Any]) -> bool:
        return record["git"] == last["git"] and record["machine"]["cpu"] == last["machine"]["cpu"]

    return [item for item in records if same(item[1])]


def _spread(values: list[float], fmt: str) -> str:
    """One figure of several runs: its median, and the range where there are more than one."""
    middle = format(statistics.median(values), fmt)
    if len(values) == 1:
        return middle
    return f"{middle} ({format(min(values), fmt)} - {format(max(values), fmt)})"


def speed_table(records: list[tuple[Path, dict[str, Any]]], published: dict[str, Any]) -> str:
    """Markdown for the speed column of Table 2 from the ``edr-bench`` records of one batch
    (:func:`latest_batch`: one code and machine): each row's median over the runs and their
    range, beside the paper's figures (``published``: the published numbers' ``speed``
    section); the ratios of every run."""
    record = records[-1][1]
    m = record["machine"]
    dirty = uncommitted([record["git"]])
    runs = len(records)
    lines = [
        "# Table 2, speed: representations per second, ours beside the paper's",
        "",
        f"- **Ours**: `edr-bench` on {m['cpu']} ({m['cpu_count']} cores), "
        f"{m['torch_threads']} torch / {m.get('numba_threads', '?')} numba threads "
        f"({m.get('numba_threading_layer', 'omp')}), "
        f"allocator: {m.get('allocator', '?')}, GPU: {m.get('gpu') or 'none'}; git `{record['git']}`; "
        f"{runs} run(s) in a row ({', '.join(r['measured_at'] for _, r in records)}), records "
        + ", ".join(f"`{path}`" for path, _ in records)
        + ".",
        *([f"- **Uncommitted code**: {dirty}."] if dirty else []),
        f"- **Data**: {record['clip']}; {record['frames_per_call']} frames per call "
        f"(slow flows: fewer, see Frames); each run's median of {record['repeats']} timed calls "
        f"after {record.get('warmup', 1)} warm-up call(s). "
        "Synthetic unless a video file is named: not a UCF-101 clip.",
        f"- **Ours (fps)**: the median over the {runs} run(s), with their range (min - max): "
        "this machine's spread from run to run.",
        "- **Published**: the paper's figure for that representation, on its own machine and code "
        "(GPU; MPEG flow's and TV-L1's cited by the paper from other work); '—' where the paper "
        "gives none.",
        "- fps counts input frames consumed per second (every env of a batch counted).",
        "- Busy neighbour rows: timed while the bench keeps one other process spinning on a core.",
        "",
        "| Representation | Implementation | Frame size | Frames | Ours (fps) | Published (fps) |",
        "|---|---|---|---:|---:|---:|",
    ]
    for r in record["rows"]:
        paper = lookup(published, "fps", PUBLISHED_ROW_NAMES.get(r["name"], ""))
        fps = [bench_fps(other["rows"], r["name"], r["implementation"]) for _, other in records]
        ours = _spread([f for f in fps if f is not None], ",.1f")
        lines.append(
            f"| {r['name']} | {r['implementation']} | {r['frame_size']} | {r['frames']} | "
            f"{ours} | {f'{paper:,.1f}' if paper else '—'} |"
        )
    lines += [
        "",
        f"Ratios, ours from each of the {runs} run(s) in turn (GrayDiff = its fastest "
        "implementation here):",
        "",
        *ratio_lines([r["rows"] for _, r in records], published),
        "",
    ]
    return "\n".join(lines)


def atari_cost_table(records: list[tuple[Path, dict[str, Any]]]) -> str:
    """Markdown: one row per ``edr-bench --atari`` record, EDR's cost in env steps per second."""
    paired = [(p, r) for p, r in records if "costs" in r]
    lines = [
        "# What EDR costs in the Atari loop: env steps per second with and without it",
        "",
        "`edr-bench --atari ENVS`: ENVS games on each backend (EnvPool's C++ threads in one",
        "process, or torchrl's ParallelEnv, a process per env), paac preset, random actions, played",
        "as a collector plays them; FDR RGB vs FDR RGB + EDR on gray (Appendix C's 5 channels per",
        "frame), both stacked by the env over the frames given (1: none, as `task=atari` builds its",
        "envs since 2026-12-01: its network takes the last 4 frames as they come; the records",
        "before stacked 4 in the env), in the observation dtype given.",
        "The two envs take turns; the cost is the median over pairs of rollouts of",
        "1 - (FDR+EDR steps/s) / (FDR steps/s), with the pairs' range. The goal is at most 5 %.",
        "Main CPU: CPU milliseconds the main process",
        "spends per agent step, FDR / FDR + EDR (torchrl's ParallelEnv spins while its workers run;",
        "EnvPool's threads, in the main process, spin while the main thread works between steps).",
        "Training: env steps/s of `task=atari`'s whole loop on the Envs column's envs (FDR+EDR,",
        "the Network column's core, its other defaults at that git revision;",
        "in brackets the same loop with FDR alone, timed just before, in the records that have it)",
        "on that backend, over the env steps given, as its progress bar reports them (from the",
        "first rollout on, kernel compilation included), then steady: from a quarter of the way on.",
        "",
        "| Game | Backend | Envs | Frames the env stacks | Observation | FDR (steps/s) | FDR + EDR (steps/s) | EDR costs | Pairs | Main CPU (ms/step) | Network | Training (steps/s) | Machine | Measured, git | Record |",
        "|---|---|---:|---:|---|---:|---:|---:|---|---|---|---:|---|---|---|",
    ]
    for path, r in paired:
        fdr, edr = r["rows"]
        costs, m = r["costs"], r["machine"]
        train = f"{r['train_fps']:,.0f} over {r['train_frames']:,}" if r.get("train_fps") else "—"
        if r.get("train_fps_steady"):
            train += f"; {r['train_fps_steady']:,.0f} steady"
        if r.get("train_fps_fdr"):
            train += f" (FDR: {r['train_fps_fdr']:,.0f}; {r['train_fps_fdr_steady']:,.0f} steady)"
        lines.append(
            f"| {r['game']} | {r.get('backend', 'parallel')} | {r['num_envs']} | {r.get('frame_stack', 1)} | "
            f"{r.get('obs_dtype', 'float32')} | {fdr['fps']:,.1f} | "
            f"{edr['fps']:,.1f} | {r['cost']:.1f} % | {len(costs)}: {min(costs):.1f} to "
            f"{max(costs):.1f} % | {' / '.join(f'{ms:.1f}' for ms in r['main_cpu_ms'])} | "
            f"{r.get('network', 'the default then')} | {train} | "
            f"{m['cpu']} ({m['cpu_count']} cores), GPU: {m.get('gpu') or 'none'} | "
            f"{r['measured_at']}, `{r['git']}` | `{path.name}` |"
        )
    if dirty := uncommitted(r["git"] for _, r in paired):
        lines += ["", f"Uncommitted code: {dirty}."]
    older = [p.name for p, r in records if "costs" not in r]
    if older:
        lines += ["", f"Older records, from before paired timing, not shown: {', '.join(older)}."]
    return "\n".join([*lines, ""])
