"""The paper's sweeps at tiny scale: the grid CI runs for every table (seeds 0 and 1 where a
table averages over seeds; fewer cells where the full grid would take minutes), all at
``debug=tiny`` on generated data. ``python -m edr.studies.tiny_sweeps DIR`` runs them all into
``DIR``; ``python -m edr.studies.tiny_sweeps DIR table2 demo`` only those named (the two whose
records ``paper/`` shows: ``edr.tables.COMMITTED_SCOPE``; ``make paper`` runs just these).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

# 100 agent steps per env on 2 envs: a lost life ends a training episode here, so Breakout has
# scores; one evaluation game a run (the table's spread is over the 2 seeds).
ATARI_TINY = ("task.env_steps=200", "task.optim.lr_decay_env_steps=200", "task.env.num_envs=2",
              "task.evaluation.plays=1", "task.evaluation.max_steps=50", "task.env.life_loss=true")  # fmt: skip
LTC_TINY = ("backbone.widths=[4,4,4,4,4]", "backbone.fc=16")
TINY_SWEEPS = {
    "table1": ("experiment=table1_atari", "game=pong,breakout", "task.env.inputs=fdr,fdr_edr",
               "seed=0,1", *ATARI_TINY),
    "table2": ("experiment=table2_ucf101", "representation=fdr,graydiff,edr", "seed=0", *LTC_TINY),
    "table3": ("task=event_camera", "seed=0,1"),
    "table4": ("experiment=table4_kth", "representation=fdr,edr",
               "backbone=lenet_lrcn,lenet_grurcn,lenet_ftrcn", "seed=0,1"),
    "appendix_a": ("task=dvs_transfer",),
    "ablation": ("experiment=ablation_edr", "ablation=paper,hard,sum", "seed=0"),
    "demo": ("task=representation_demo",),
}  # fmt: skip


def run_tiny_sweeps(
    out_dir: Path, env: dict[str, str] | None = None, names: list[str] | None = None
) -> None:
    """Run every tiny sweep (or those ``names`` names) with ``edr-run -m`` into
    ``out_dir/<name>``; raises if one fails, or if a name is not a tiny sweep."""
    unknown = sorted(set(names or ()) - set(TINY_SWEEPS))
    if unknown:
        raise SystemExit(
            f"no tiny sweep named {', '.join(unknown)}: they are {', '.join(TINY_SWEEPS)}"
        )
    edr_run = str(Path(sys.executable).parent / "edr-run")
    for name, overrides in TINY_SWEEPS.items():
        if names and name not in names:
            continue
        print(f"tiny sweep {name}: edr-run -m debug=tiny {' '.join(overrides)}", flush=True)
        subprocess.run(
            [edr_run, "-m", "debug=tiny", *overrides, f"hydra.sweep.dir={out_dir / name}"],
            env={**os.environ, **(env or {})}, check=True,
        )  # fmt: skip


if __name__ == "__main__":
    run_tiny_sweeps(
        Path(sys.argv[1]) if len(sys.argv) > 1 else Path("results/sweeps/tiny"),
        names=sys.argv[2:],
    )
