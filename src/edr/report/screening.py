"""Table 1's screening (``experiment=table1_screen``): which network and optimizer leave random
play in Pong fastest, judged by learning: the training score over env steps, the env steps to
reach -15 and 0, and, as diagnostics, the policy's entropy, the logits' spread across states and
conv1's dead units. One row per run; ``python -m edr.report.screening DIR`` writes
``DIR/screening.md`` from the records under DIR.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from edr.report.atari_curves import first_reaching, score_at
from edr.report.runs import load_runs, run_history
from edr.store.atomic import write_text_atomic
from edr.store.checkpoints import CHECKPOINT, load_checkpoint
from edr.store.identity import ADDED_DEFAULTS

MILESTONES = (250_000, 500_000, 1_000_000, 1_500_000)  # env steps at which the score is shown
TARGETS = (-15.0, 0.0)  # training scores whose first env step is shown
RANDOM_PLAY = -20.7  # Pong's random play (the paper's reference scores)


def _precision(run: pd.Series) -> str:
    """The precision a run trained in; a record from before the setting: float32."""
    for key in ("metrics.train/precision", "config.task.network.precision"):
        if pd.notna(run.get(key)):
            return str(run[key])
    return ADDED_DEFAULTS["edr.rl.settings.NetworkSettings"]["precision"]


def _steps(steps: int | None) -> str:
    return f"{steps / 1e6:.2f}M" if steps is not None else "—"


def _last(history: list[dict], key: str) -> float:
    values = [r[key] for r in history if key in r]
    return float(np.mean(values[-5:])) if values else np.nan  # the last 5 rows (50 updates)


def _history(record: str) -> list[dict]:
    """A run's history: its history.json once finished, else its checkpoint's (in progress)."""
    checkpoint = Path(record).parent / CHECKPOINT
    if history := run_history(record):
        return history
    return load_checkpoint(checkpoint)["history"] if checkpoint.is_file() else []


def screening_rows(runs: pd.DataFrame) -> pd.DataFrame:
    """One row per Atari run of ``runs`` (finished or not: a run in progress shows how far it got)."""
    rows = []
    for _, run in runs[runs["task"] == "atari"].iterrows():
        history = _history(run["record"])
        if not history:
            continue
        get = run.get
        optimizer = get("config.task.optim.name")
        lr = get("config.task.optim.lr")
        rows.append({
            "Network": get("config.task.network.core"),
            "Input norm": get("config.task.network.input_norm", "raw") or "raw",
            "Init": get("config.task.network.init"),
            "Optimizer": f"{optimizer} {lr:g}" if pd.notna(lr) and lr else f"{optimizer} (default lr)",
            "Entropy weight": get("config.task.loss.entropy_coeff"),
            "Critic weight": get("config.task.loss.critic_coeff"),
            "Precision": _precision(run),
            "Input": get("config.task.env.inputs"),
            "Seed": get("seed"),
            "Status": get("status"),
            "Env steps": f"{history[-1]['env_steps'] / 1e6:.2f}M",
            **{f"Score @{m / 1e6:g}M": score_at(history, m) for m in MILESTONES},
            **{f"Steps to {t:g}": _steps(first_reaching(history, t)) for t in TARGETS},
            "Entropy": _last(history, "train/entropy"),
            "Logit spread": _last(history, "train/logit_spread"),
            "conv1 dead": _last(history, "dead/trunk.1"),
            "Env steps/s": _last(history, "train/fps"),
            "Eval mean": get("metrics.eval/mean"),
        })  # fmt: skip
    return pd.DataFrame(rows)


def screening_markdown(runs: pd.DataFrame, source: Path) -> str:
    frame = screening_rows(runs)
    if frame.empty:
        return f"No Atari runs with a history under {source}.\n"
    frame = frame.sort_values(["Input", "Network", "Optimizer", "Seed"])
    text = frame.to_markdown(index=False, floatfmt=".2f", missingval="—")
    return "\n".join([
        f"# Table 1's screening: Pong, {len(frame)} runs under `{source}`",
        "",
        "Training score: the mean of the last 20 training episodes (random play "
        f"{RANDOM_PLAY}). Entropy (ln 6 = 1.79 is a uniform policy), logit spread (the "
        "logits' std across a rollout's states, averaged over actions; near 0 when the policy "
        "ignores the frames), conv1 dead and env steps/s: means of the last 50 updates (env "
        "steps/s depends on what else ran on the machine meanwhile). A run still in progress "
        "shows how far it got (Status). Machine: see each run.json.",
        "",
        text,
        "",
    ])  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m edr.report.screening", description=__doc__)
    parser.add_argument("folder", type=Path, help="the screening's sweep folder")
    args = parser.parse_args(argv)
    out = args.folder / "screening.md"
    write_text_atomic(out, screening_markdown(load_runs([args.folder]), args.folder))
    print(out.read_text())


if __name__ == "__main__":
    main()
