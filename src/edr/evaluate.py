"""edr-eval: score an Atari run's network again: a finished run's ``network.pt`` (Table 1's kept
networks), or the latest checkpoint of a run stopped before its end.
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
        description="Score an Atari run's network again, in eval mode: a finished run's "
        "network.pt (writes network_eval.json only: the run's own evaluation stays) or the latest "
        "checkpoint of a stopped or diverged run (writes checkpoint_eval.json; for a stopped run "
        "also eval_scores.json, history.json and the training curve, beside its run.json). Plays "
        "task.evaluation.plays games, or --plays.",
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
    parser.add_argument(
        "--random-play",
        action="store_true",
        help="also play random actions on the same games (random/ metrics: score, game length, "
        "clipped return), the yardstick for a game the network plays worse than chance",
    )
    return parser


def main(argv: list[str] | None = None) -> None:
    parser = _parser()
    args = parser.parse_args(argv)
    if args.plays is not None and args.plays < 1:
        parser.exit(2, f"{parser.prog}: --plays={args.plays}: expected a number >= 1\n")
    from edr.tasks.atari import evaluate_checkpoint  # torch, torchrl and the envs load here

    try:
        metrics = evaluate_checkpoint(
            args.run_dir, args.plays, args.trust_env_module, args.random_play
        )
    except (UntrustedRecord, UnreadableRecord, UnreadableCheckpoint, FileNotFoundError) as error:
        parser.exit(2, f"{parser.prog}: {error}\n")
    except FloatingPointError as error:  # a network whose weights are no longer numbers
        parser.exit(1, f"{parser.prog}: {args.run_dir}: {error}\n")
    print(json.dumps(metrics, indent=1))


if __name__ == "__main__":
    main()
