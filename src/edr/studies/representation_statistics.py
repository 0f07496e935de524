"""What each representation hands the network: the distribution of its output, per channel, on
the clips a recognition run trains on (why does EDR trail GrayDiff on generated video?).

``python -m edr.studies.representation_statistics`` decodes generated KTH-layout video (``make demo``'s
generator) and the real KTH clips (``../shared/real-video/kth``, or ``--real``) as
``experiment=kth_demo`` and ``kth_real`` do (gray, 53x40), cuts each video into consecutive
24-frame clips, runs every representation named (as ``conf/representation/<name>.yaml`` and,
after a colon, ``conf/ablation/<name>.yaml`` compose it: ``edr:fast_slow`` is the paper's two
timescales) on each clip, and reports per output channel its scale (RMS, mean |x| where non-zero,
99.9th percentile and largest |x|), its mean, and its sparsity (the share of exact zeros, and of
|x| below 1 % of the channel's RMS). It writes a record,
``results/bench/representation_statistics_<host>_<time>.json``, and prints the tables.
"""

from __future__ import annotations

import argparse
import os
import time
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

from edr import CONF_DIR
from edr.data.clips import VideoSource
from edr.data.datasets import kth, resolve_root
from edr.data.synthetic import write_synthetic_kth
from edr.representations import Representation
from edr.store.atomic import write_json_atomic
from edr.store.records import git_revision, machine_info

REPRESENTATIONS = ("fdr", "graydiff", "edr", "edr:fast_slow", "edr_sum")  # gray: RGBDiff = GrayDiff
REAL_VIDEO = os.environ.get("EDR_REAL_VIDEO", "../shared/real-video")


def representation(name: str) -> Representation:
    """``conf/representation/<name>.yaml``, with ``conf/ablation/<change>.yaml`` for
    ``<name>:<change>``, as ``edr-run representation=<name> ablation=<change>`` builds it."""
    group, _, ablation = name.partition(":")
    overrides = [f"representation={group}", *([f"ablation={ablation}"] if ablation else [])]
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        return instantiate(compose(config_name="config", overrides=overrides).representation)


def channel_statistics(outputs: torch.Tensor) -> list[dict[str, float]]:
    """(N, T, C, H, W) outputs -> per channel: scale, mean and sparsity."""
    rows = []
    for c in range(outputs.shape[2]):
        x = outputs[:, :, c].flatten().double()
        magnitude = x.abs()
        rms = float(x.pow(2).mean().sqrt())
        nonzero = magnitude[magnitude > 0]
        rows.append(
            {
                "rms": rms,
                "mean": float(x.mean()),
                "mean_abs_nonzero": float(nonzero.mean()) if len(nonzero) else 0.0,
                "p999_abs": float(torch.quantile(magnitude[:: max(1, len(x) // 2**24)], 0.999)),
                "max_abs": float(magnitude.max()),
                "zeros": float((x == 0).double().mean()),
                "below_1pct_rms": float((magnitude < 0.01 * rms).double().mean()),
            }
        )
    return rows


def clips_of(videos: list[np.ndarray], frames: int) -> torch.Tensor:
    """Consecutive ``frames``-frame clips of every (T, C, H, W) video -> (N, frames, C, H, W)."""
    return torch.from_numpy(
        np.stack([v[s : s + frames] for v in videos for s in range(0, len(v) - frames + 1, frames)])
    )


def measure(videos: list[np.ndarray], names: tuple[str, ...], frames: int) -> list[dict[str, Any]]:
    """Every representation of ``names`` over the clips of ``videos``: its channels' statistics."""
    clips = clips_of(videos, frames)  # (N, frames, 1, H, W) uint8
    found = []
    for name in names:
        layer = representation(name)
        with torch.no_grad():
            outputs = torch.cat([layer(batch) for batch in clips.split(16)])
        found.append({"representation": name, "clips": len(clips),
                      "channels": channel_statistics(outputs)})  # fmt: skip
    return found


def table(measured: list[dict[str, Any]]) -> str:
    lines = [
        "| representation | channel | RMS | mean | mean abs, non-zero | 99.9 % abs | max abs | "
        "exact zeros | below 1 % of RMS |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for row in measured:
        for c, s in enumerate(row["channels"]):
            lines.append(
                f"| {row['representation']} | {c} | {s['rms']:.3g} | {s['mean']:.3g} | "
                f"{s['mean_abs_nonzero']:.3g} | {s['p999_abs']:.3g} | {s['max_abs']:.3g} | "
                f"{100 * s['zeros']:.1f} % | {100 * s['below_1pct_rms']:.1f} % |"
            )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m edr.studies.representation_statistics",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--representations", nargs="+", default=list(REPRESENTATIONS),
                        help="conf/representation names, each optionally :<ablation>")  # fmt: skip
    parser.add_argument("--real", type=Path, default=Path(REAL_VIDEO) / "kth",
                        help="real KTH clips in KTH's layout (skipped when absent)")  # fmt: skip
    parser.add_argument("--persons", type=int, default=4, help="generated KTH persons (x6 videos)")
    parser.add_argument("--frames", type=int, default=24, help="frames per clip (the demo's)")
    parser.add_argument("--cache", type=Path, default=Path("results/cache"), help="decoded video")
    parser.add_argument("--out-dir", type=Path, default=Path("results/bench"), help="records")
    args = parser.parse_args(argv)
    names = tuple(args.representations)
    # make demo's generator (experiment=kth_demo): 40-frame videos, decoded as its runs decode
    generated = partial(write_synthetic_kth, persons=args.persons, scenarios=1, frames=40)
    sets = {"generated KTH layout (make demo's generator)": (
        resolve_root(None, generated, args.cache), 40)}  # fmt: skip
    if (args.real / "boxing").is_dir():
        sets["real KTH clips"] = (args.real, None)
    stamp, machine = time.strftime("%Y-%m-%d_%H-%M-%S"), machine_info()
    record: dict[str, Any] = {"kind": "representation_statistics", "measured_at": stamp,
                              "git": git_revision(), "machine": machine, "frames": args.frames,
                              "size": [53, 40], "data": {}}  # fmt: skip
    for label, (root, max_frames) in sets.items():
        source = VideoSource(args.cache, size=(53, 40), gray=True, max_frames=max_frames)
        videos = [np.asarray(source(v.path)) for v in kth(root, protocol="time").videos]
        record["data"][label] = {"root": str(root), "videos": len(videos),
                                 "representations": measure(videos, names, args.frames)}  # fmt: skip
        print(f"## {label}: {len(videos)} videos, {args.frames}-frame clips, gray 53x40\n")
        print(table(record["data"][label]["representations"]) + "\n")
    path = write_json_atomic(
        args.out_dir / f"representation_statistics_{machine['hostname']}_{stamp}.json", record
    )
    print(f"record: {path}")


if __name__ == "__main__":
    main()
