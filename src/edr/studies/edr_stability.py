"""How stable is learning EDR's parameters? Gradient norms and divergences, full BPTT against
truncated windows, on clips of T = 60 and T = 250 frames (the paper's section 5: "end-to-end
learning the EDR parameters seems to be quite unstable").

``python -m edr.studies.edr_stability`` fits a learnable EDR (half-life 1.0, beta, nu learnable) to the
events of a fixed one (the paper's half-life 3.8) on generated scenes, one seed per scene, with
Adam, in each parameterization (``log``, ``bounded``); per setting it reports the gradient
norm of the raw parameters at the start (median and coefficient of variation over seeds), the
runs that diverged (a non-finite loss, or a half-life leaving [0.1, 1000]) and the half-lives
reached. It writes a record,
``<out-dir>/edr_gradients_<host>_<time>.json``, and prints the table.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from pathlib import Path
from typing import Any

import torch

from edr.data import synthetic_scene
from edr.representations import EDR
from edr.store.atomic import write_json_atomic
from edr.store.records import bench_dir, git_revision, machine_info

TARGET_HALF_LIFE = 3.8


def fit(
    frames: int, window: int | None, parameterization: str, seed: int, steps: int, size: int
) -> dict[str, Any]:
    """One fit from half-life 1.0: the first gradient norm, whether it diverged, where it went."""
    clip = synthetic_scene(frames, size, size, seed=seed).unsqueeze(0)  # (1, T, 3, H, W)
    target = EDR(half_lives=(TARGET_HALF_LIFE,), color="gray")(clip).detach()
    learner = EDR(half_lives=(1.0,), color="gray", learnable=True, bptt_window=window,
                  parameterization=parameterization)  # fmt: skip
    optim = torch.optim.Adam(learner.parameters(), lr=0.05)
    first_norm, diverged_at = None, None
    for step in range(steps):
        loss = (learner(clip) - target).pow(2).mean()
        optim.zero_grad()
        loss.backward()
        norm = float(torch.cat([p.grad.flatten() for p in learner.parameters()]).norm())
        first_norm = norm if first_norm is None else first_norm
        tau = float(learner.half_lives.detach()[0])
        if not (math.isfinite(float(loss)) and math.isfinite(norm) and 0.1 < tau < 1000):
            diverged_at = step
            break
        optim.step()
    return {
        "seed": seed,
        "first_grad_norm": first_norm,
        "diverged_at": diverged_at,
        "half_life": float(learner.half_lives.detach()[0]),
        "beta": float(learner.betas.detach()[0]),
    }


def table(record: dict[str, Any]) -> str:
    lines = [
        "| T | BPTT | parameterization | runs | grad norm at start: median (CV) | diverged | "
        "half-life reached: median (min, max) |",
        "|---:|---|---|---:|---|---:|---|",
    ]
    for setting in record["settings"]:
        runs = setting["runs"]
        norms = [r["first_grad_norm"] for r in runs]
        lives = [r["half_life"] for r in runs if r["diverged_at"] is None]
        cv = statistics.pstdev(norms) / statistics.mean(norms) if statistics.mean(norms) else 0
        reached = "—"
        if lives:
            reached = f"{statistics.median(lives):.2f} ({min(lives):.2f}, {max(lives):.2f})"
        diverged = sum(r["diverged_at"] is not None for r in runs)
        lines.append(
            f"| {setting['frames']} | {setting['window'] or 'full'} | "
            f"{setting['parameterization']} | {len(runs)} | "
            f"{statistics.median(norms):.3g} ({cv:.2f}) | {diverged} | {reached} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m edr.studies.edr_stability",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--seeds", type=int, default=5, help="scenes (one fit each) per setting")
    parser.add_argument("--steps", type=int, default=100, help="Adam steps per fit")
    parser.add_argument("--size", type=int, default=48, help="frame side of the scenes")
    parser.add_argument("--window", type=int, default=10, help="the truncated BPTT window")
    parser.add_argument(
        "--out-dir",
        type=Path,
        default=bench_dir(),
        help="where the record is written (default: results/runs/bench, untracked)",
    )
    args = parser.parse_args(argv)
    stamp, machine = time.strftime("%Y-%m-%d_%H-%M-%S"), machine_info()
    settings = [
        {"frames": frames, "window": window, "parameterization": param,
         "runs": [fit(frames, window, param, seed, args.steps, args.size)
                  for seed in range(args.seeds)]}
        for frames in (60, 250)
        for window in (None, args.window)
        for param in ("log", "bounded")
    ]  # fmt: skip
    record = {"kind": "edr_gradients", "measured_at": stamp, "git": git_revision(),
              "machine": machine, "steps": args.steps, "size": args.size,
              "target_half_life": TARGET_HALF_LIFE, "settings": settings}  # fmt: skip
    path = write_json_atomic(
        args.out_dir / f"edr_gradients_{machine['hostname']}_{stamp}.json", record
    )
    print(table(record))
    print(f"record: {path}")


if __name__ == "__main__":
    main()
