"""edr-eval: score an Atari run's network again: a finished run's ``network.pt`` (Table 1's kept
networks), or the latest checkpoint of a run stopped before its end, seeded, into a file of its
own beside the run's (never over the run's own evaluation).
``python -m edr.evaluate`` is the same command."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from edr.checks.config import Seed, mismatch
from edr.store.checkpoints import UnreadableCheckpoint
from edr.store.records import UnreadableRecord
from edr.tasks.rebuild import UntrustedRecord
from edr.tasks.run_folder import RefusedFolder


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="edr-eval",
        description="Score an Atari run's network again, in eval mode: a finished run's "
        "network.pt, or the latest checkpoint of a stopped or diverged run. Plays "
        "task.evaluation.plays games, or --plays, seeded by --seed (the run's own seed by "
        "default: the same seed gives the same scores). Writes <network|checkpoint>_eval_seed<S>"
        "_plays<N>.json beside the run's files and nothing else: the run's own evaluation "
        "(eval_scores.json, history.json, its curve) stays as it was. A folder a live run "
        "holds, one it cannot write into, or a record or file edr-run did not write is refused "
        "in one line before any game is played.",
        epilog="example: edr-eval results/runs/atari/<run> --plays 30 --seed 1",
    )
    parser.add_argument(
        "run_dir", type=Path, help="the run's folder (run.json, checkpoint.pt or network.pt)"
    )
    parser.add_argument("--plays", type=int, default=None, help="games (default: the run's)")
    parser.add_argument(
        "--seed",
        type=int,
        default=None,
        help="seeds the envs and the sampled actions (default: the run's seed)",
    )
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
    if args.seed is not None and (expected := mismatch(args.seed, Seed)):
        parser.exit(2, f"{parser.prog}: --seed={args.seed}: expected {expected}\n")
    if not Path(args.run_dir).exists():
        parser.exit(2, f"{parser.prog}: {args.run_dir}: no such folder: name a run folder "
                       "edr-run wrote (it holds run.json)\n")  # fmt: skip
    from edr.tasks.atari import evaluate_checkpoint  # torch, torchrl and the envs load here

    try:
        metrics = evaluate_checkpoint(
            args.run_dir, args.plays, args.trust_env_module, args.random_play, args.seed
        )
    except (
        RefusedFolder, UntrustedRecord, UnreadableRecord, UnreadableCheckpoint, FileNotFoundError
    ) as error:  # fmt: skip
        parser.exit(2, f"{parser.prog}: {error}\n")
    except FloatingPointError as error:  # a network whose weights are no longer numbers
        parser.exit(1, f"{parser.prog}: {args.run_dir}: {error}\n")
    print(json.dumps(metrics, indent=1))


if __name__ == "__main__":
    main()
