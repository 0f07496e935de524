"""edr-eval: score an Atari run's latest checkpoint, for a run stopped before its end (or
scored again with more games), or a finished run's ``network.pt`` (Table 1's kept networks).
``python -m edr.evaluate`` is the same command."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from edr.store.checkpoints import UnreadableCheckpoint
from edr.store.records import UnreadableRecord
from edr.tasks.rebuild import UntrustedRecord


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="edr-eval",
        description="Score an Atari run's network again, in eval mode: its latest checkpoint "
        "(writes eval_scores.json, history.json, the training curve and checkpoint_eval.json "
        "beside its run.json) or, in a folder without one, its network.pt (writes "
        "network_eval.json only). Plays task.evaluation.plays games, or --plays.",
        epilog="example: edr-eval results/runs/atari/<run> --plays 30",
    )
    parser.add_argument(
        "run_dir", type=Path, help="the run's folder (run.json, checkpoint.pt or network.pt)"
    )
    parser.add_argument("--plays", type=int, default=None, help="games (default: the run's)")
    parser.add_argument(
        "--trust-env-module",
        action="store_true",
        help="import the module the record names (task.env.env_module): it runs its code",
    )
    return parser


def main(argv: list[str] | None = None) -> None:
    parser = _parser()
    args = parser.parse_args(argv)
    if args.plays is not None and args.plays < 1:
        parser.exit(2, f"{parser.prog}: --plays={args.plays}: expected a number >= 1\n")
    from edr.tasks.atari import evaluate_checkpoint  # torch, torchrl and the envs load here

    try:
        metrics = evaluate_checkpoint(args.run_dir, args.plays, args.trust_env_module)
    except (UntrustedRecord, UnreadableRecord, UnreadableCheckpoint, FileNotFoundError) as error:
        parser.exit(2, f"{parser.prog}: {error}\n")
    print(json.dumps(metrics, indent=1))


if __name__ == "__main__":
    main()
