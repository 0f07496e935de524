"""``edr-run``: the Hydra entry point. One run = one task with its representation, in a folder
named from its overrides; it ends by writing a run record (``run.json``) beside the run's
artifacts. Running the same command again skips a finished run and resumes an interrupted one.

    edr-run                                   # the demo on a generated video
    edr-run task.video=clip.avi task.frames=120
    edr-run -m task=kth representation=edr,edr_k3 seed=0,1 debug=tiny
"""

from __future__ import annotations

import contextlib
import errno
import inspect
import logging
import os
import sys
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import hydra
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.errors import CompactHydraException, InstantiationException
from hydra.types import RunMode
from hydra.utils import get_object, instantiate
from omegaconf import DictConfig, OmegaConf

from edr import CONF_DIR
from edr.checks import interrupts
from edr.checks.command_line import check_command_line
from edr.checks.config import ConfigError, Seed, Threads, check_config, path_problem
from edr.report.published import load_published, lookup
from edr.store.atomic import remove_partial_files
from edr.store.checkpoints import (
    START_OVER,
    UnreadableCheckpoint,
    WriteStopped,
    drop_checkpoint,
    progress,
    progress_text,
)
from edr.store.folders import (
    FOLDER_ROOM,
    Resume,
    SweepSummary,
    hold_folder,
    log_attempt,
    plan_attempt,
    refused_cells,
)
from edr.store.identity import job_dirname, run_identity, warn_ignored, with_root_symbols
from edr.store.job_files import open_run_log, write_job_config
from edr.store.records import (
    INTERRUPTED,
    RECORD_NAME,
    UnreadableRecord,
    check_flat,
    git_revision,
    machine_info,
    now,
    record_config,
    write_last_record,
    write_record,
)
from edr.tasks.seeds import seed_everything

# The entry point's own keys, checked like a task's arguments.
INTERNAL_GROUPS = {"hydra", "recognition", "paths"}  # composed by the configs, not picked by users
ENTRY_KEYS = {"seed": Seed, "threads": Threads | None, "resume": Resume, "scale": str}
log = logging.getLogger(__name__)

OmegaConf.register_new_resolver("edr.abspath", lambda p: str(Path(p).expanduser().resolve()))
# An environment variable's value; its default where it is unset or empty (``EDR_RESULTS=``
# must not mean the current folder).
OmegaConf.register_new_resolver("edr.env", lambda name, default: os.environ.get(name) or default)
OmegaConf.register_new_resolver("edr.job_dir", lambda overrides: job_dirname(overrides))
OmegaConf.register_new_resolver("edr.first", lambda *choices: next(c for c in choices if c))
OmegaConf.register_new_resolver("edr.groups", lambda: user_groups(Path(CONF_DIR)))


def user_groups(conf_dir: Path) -> str:
    """``group: option, option`` per line for the groups a user picks from (not Hydra's own,
    not the shared recognition base, not the per-task parts of ``debug``)."""
    lines = []
    for group in sorted(p for p in conf_dir.iterdir() if p.is_dir()):
        if group.name in INTERNAL_GROUPS:
            continue
        parts = group.name == "debug"  # debug/tiny_<task>.yaml: selected with debug=tiny
        options = sorted(f.stem for f in group.glob("*.yaml") if not (parts and "_" in f.stem))
        lines.append(f"  {group.name}: {', '.join(options)}")
    return "\n".join(lines)


def _hydra_context() -> tuple[dict[str, str], list[str]]:
    """(config group choices, command-line overrides) of the Hydra run, empty outside one."""
    if not HydraConfig.initialized():
        return {}, []
    hydra_cfg = HydraConfig.get()
    choices = {k: str(v) for k, v in hydra_cfg.runtime.choices.items() if "hydra" not in k}
    return choices, list(hydra_cfg.overrides.task)


def run(cfg: DictConfig) -> dict[str, Any]:
    """Run the task ``cfg`` describes in ``cfg.out_dir`` and return its flat metrics.

    Checks the config first; holds the folder (one writer at a time); skips a finished run of
    the same config, resumes from its checkpoint an interrupted one, refuses a folder holding
    another config.
    """
    interrupts.clear()  # a signal an earlier run in this process stopped on is not this run's
    check_config(cfg, entry=ENTRY_KEYS)
    out_dir = Path(cfg.out_dir)
    if problem := path_problem(out_dir, below=FOLDER_ROOM["run"]):
        raise ConfigError(f"out_dir={out_dir}: expected {problem}")
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ConfigError(f"cannot create the run folder {out_dir}: {error.strerror}") from None
    with hold_folder(out_dir):
        return _run_held(cfg, out_dir)


def _run_held(cfg: DictConfig, out_dir: Path) -> dict[str, Any]:
    """:func:`run` in the folder it holds."""
    # ---- checks and the plan -----------------------------------------------------------------
    choices, overrides = _hydra_context()
    if not _in_sweep():  # a sweep says it once, before its first job (SweepSummary)
        warn_ignored(cfg, overrides)
    semantic, fingerprint, cell = run_identity(cfg)
    plan = plan_attempt(out_dir, fingerprint, semantic, cfg.resume)
    if plan.action == "skip":
        _checked(out_dir)
        log.info("%s: finished already with this config: skipped (resume=false reruns it)", out_dir)
        log_attempt(out_dir, "skipped", fingerprint)
        return plan.record["metrics"]
    seed_everything(cfg.seed)
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    target = get_object(cfg.task._target_)
    try:
        task = instantiate(cfg.task)  # a partial function of the task's own arguments
    except InstantiationException as error:
        raise ConfigError(" ".join(str(error).split())) from error
    arguments: dict[str, Any] = {"out_dir": out_dir, "seed": cfg.seed}
    if "resume" in inspect.signature(target).parameters:
        arguments["resume"] = plan.action == "resume"
    if plan.action == "resume":
        _check_resumable(out_dir, plan.record or {}, target, task)
    _checked(out_dir)
    write_job_config(cfg)
    if plan.extended:
        log.info("%s: extending it from its checkpoint (%s)", out_dir, "; ".join(plan.extended))
    elif plan.action == "resume":
        log.info("%s: resuming from its checkpoint", out_dir)

    # ---- the record, then the task -----------------------------------------------------------
    previous = plan.record or {}
    # paths under the results root are written from it: no machine's folder in a record
    portable = partial(with_root_symbols, roots={"results": cfg.paths.results})
    record: dict[str, Any] = {
        "status": "running",
        "task": choices.get("task", cfg.task._target_),
        "fingerprint": fingerprint,
        "cell": cell,
        "seed": cfg.seed,
        "scale": cfg.scale,
        "attempt": previous.get("attempt", 0) + 1 if plan.action == "resume" else 1,
        "resumed": plan.action == "resume",
        **({"extended": list(plan.extended)} if plan.extended else {}),
        "started_at": now(),
        "choices": choices,
        "overrides": overrides,
        "git": git_revision(),
        "machine": machine_info(),
        "config": portable(record_config(cfg)),  # the groups its task uses
        "semantic_config": semantic,
    }
    write_record(out_dir, record)
    started = time.perf_counter()
    results = portable(_attempt(out_dir, record, partial(task, **arguments), started))

    # ---- the finished record -----------------------------------------------------------------
    record.update(
        status="finished",
        data={k.removeprefix("data/"): v for k, v in results.items() if k.startswith("data/")},
        metrics=check_flat({k: v for k, v in results.items() if not k.startswith("data/")}),
        wall_time_s=round(time.perf_counter() - started, 3),
        ended_at=now(),
    )
    with interrupts.deferred():  # a signal now stops what comes next, once this run is written
        write_record(out_dir, record)
        log_attempt(out_dir, "resumed" if plan.action == "resume" else "ran", fingerprint,
                    git=record["git"])  # fmt: skip
        drop_checkpoint(
            out_dir, record["metrics"]
        )  # the record says finished: network.pt is enough
        log.info("%s", summary_line(record, out_dir))
    return record["metrics"]


def _checked(out_dir: Path) -> None:
    """Once ``out_dir`` passed the checks (a run refused before here leaves the folder as it
    found it): the partial files a writer killed mid-write left (SIGKILL, a power cut) removed,
    and the run's log opened (:mod:`edr.store.job_files`)."""
    remove_partial_files(out_dir)
    open_run_log()


def _attempt(out_dir: Path, record: dict[str, Any], task: Callable[[], Any], started: float) -> Any:
    """``task()``'s results; where it raises, ``record`` (written as running) says how it ended
    (``interrupted``: it resumes; ``failed`` with the error) before the error goes on."""
    try:
        return task()
    except BaseException as error:
        interrupted = isinstance(error, KeyboardInterrupt)  # stopped, not failed: it resumes
        record.update(
            status=INTERRUPTED if interrupted else "failed",
            **({} if interrupted else {"error": f"{type(error).__name__}: {error}"}),
            wall_time_s=round(time.perf_counter() - started, 3),
            ended_at=now(),
        )
        if interrupted:  # what the next attempt continues from (None: it starts over)
            record["resumes_from"] = progress(out_dir)
            _say_where_it_resumes(out_dir, record["resumes_from"])
        with interrupts.deferred():  # a second Ctrl-C does not cut the record short
            unwritten = write_last_record(out_dir, record)
            if unwritten:  # a full disk: said once, beside the task's own error, not chained to it
                log.warning("%s: the record could not say so (%s)", out_dir / "run.json", unwritten)
            with contextlib.suppress(OSError):
                log_attempt(out_dir, record["status"], record["fingerprint"], git=record["git"])
        raise


def _check_resumable(out_dir: Path, record: dict[str, Any], target: Any, task: Any) -> None:
    """What a resumed run continues from, checked before its record is rewritten, as edr-eval
    checks a folder (:mod:`edr.tasks.run_folder`): the record's status and fields as edr-run
    writes them, and where the task says how (its ``check_resumable``: Atari's, a recognition
    run's or DVS transfer's checkpoint against its network), the checkpoint; one line naming
    the file, the folder as it was (its ``run.log`` and ``.hydra/`` too:
    :mod:`edr.store.job_files`)."""
    from edr.tasks.run_folder import check_record_fields  # numba's kernels: for a resume only

    check_record_fields(out_dir / RECORD_NAME, record, START_OVER)
    if (check := getattr(target, "check_resumable", None)) is not None:
        check(out_dir, **task.keywords)


def headline(metrics: dict[str, Any]) -> str:
    """The one result a reader looks for first, with what chance or random play would score."""
    if "train/diverged_step" in metrics:  # no accuracy or score: what a network of NaNs gives
        reason = metrics.get("train/diverged_reason", "the loss is not a number")
        return f"diverged at training step {metrics['train/diverged_step']} ({reason})"
    if "eval/accuracy" in metrics:
        chance = metrics.get("eval/chance")
        against = f" (chance {100 * chance:.1f} %)" if chance is not None else ""
        return f"accuracy {100 * metrics['eval/accuracy']:.1f} %{against}"
    if "eval/mean" in metrics:
        if "eval/random_mean" in metrics:  # games cut short: random play under the same cap
            against = (
                f", random play {metrics['eval/random_mean']:+.1f} on the same games, "
                f"also cut at {metrics['eval/max_steps']} steps"
            )
        else:
            game = metrics.get("data/game")
            random_play = lookup(load_published(), "atari_reference_scores", game, "random")
            against = f", random play {random_play:+g}" if random_play is not None else ""
        return (
            f"mean score {metrics['eval/mean']:+.1f} over {metrics['eval/plays']} games "
            f"(min {metrics['eval/min']:+g}, max {metrics['eval/max']:+g}{against})"
        )
    rates = {k.split("/")[0]: v for k, v in metrics.items() if k.endswith("/events_per_s")}
    if rates:
        return "events/s " + ", ".join(f"{name} {rate:.3g}" for name, rate in rates.items())
    return f"{len(metrics)} metrics"


def summary_line(record: dict[str, Any], out_dir: Path) -> str:
    """``kth #3 finished: accuracy 56.7 % (chance 16.7 %) · results/...``: the end of a run."""
    job = f" #{HydraConfig.get().job.num}" if _in_sweep() else ""
    found = headline({**record["metrics"], **{f"data/{k}": v for k, v in record["data"].items()}})
    return f"{record['task']}{job} finished: {found} · {out_dir}"


def _in_sweep() -> bool:
    return HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN


def main() -> None:
    """The command line checked (a typo or a bad value: one line, before Hydra makes a run
    folder), then Hydra's app."""
    try:
        check_command_line(sys.argv[1:], CONF_DIR, lambda cfg: check_config(cfg, entry=ENTRY_KEYS))
    except ConfigError as error:
        print(f"edr-run: {error}", file=sys.stderr)
        raise SystemExit(2) from None
    hydra_app()


class JobFailed(CompactHydraException):
    """A submitit job's config error, handed back to the sweep that waits for the job's result,
    which prints it as one line (a job that exits leaves no result, and without Slurm accounting
    the sweep would wait for it forever)."""


# Errors of the disk a run writes to, or of what stands on it where a file goes (a folder made
# there during the run), not of the suite: said in one line, as refusals are.
DISK_ERRORS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EACCES, errno.EIO,
               errno.EISDIR, errno.ENOTDIR}  # fmt: skip


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="config")
def hydra_app(cfg: DictConfig) -> None:
    """How a run ends, in one place. Refused (a bad value, an unreadable record or checkpoint,
    a folder held or of another config): one line, exit 2, before any work. Failed: the record
    says ``failed`` with the reason (written by :func:`run`); a disk's error is one line, exit 1,
    anything else its traceback. In a sweep, a refused or failed cell is one line and the sweep
    goes on to its other cells and its summary line (:class:`edr.store.folders.SweepSummary`), which
    counts it and ends the sweep with exit 1. Inside a submitit job (Slurm), a refusal goes back
    to the waiting sweep as one line (:class:`JobFailed`)."""
    in_job = bool(os.environ.get("SUBMITIT_EXECUTOR"))  # a Slurm or local submitit job
    if in_job:  # submitit ignores SIGTERM; scancel, a time limit or preemption end it as kill does
        interrupts.install()
    try:
        run(cfg)
    except (ConfigError, UnreadableRecord, UnreadableCheckpoint) as error:  # one line, no trace
        log.error("%s", error)
        if in_job:
            raise JobFailed(str(error)) from None
        if not _in_sweep():
            raise SystemExit(2) from None
        refused_cells.append(_folder_of(cfg))
    except OSError as error:
        if not (isinstance(error, WriteStopped) or error.errno in DISK_ERRORS or _in_sweep()):
            raise
        log.error("failed: %s", " ".join(str(error).split()))
        if not _in_sweep():
            raise SystemExit(1) from None
    except Exception as error:
        if not _in_sweep():
            raise
        log.error("failed: %s: %s", type(error).__name__, " ".join(str(error).split()))


def _folder_of(cfg: DictConfig) -> Path | None:
    """The run folder ``cfg`` names; None where its ``out_dir`` does not resolve."""
    try:
        folder = OmegaConf.select(cfg, "out_dir")
    except Exception:  # an interpolation that fails: the refusal said it
        return None
    return Path(folder) if isinstance(folder, str) and folder.strip() else None


def _say_where_it_resumes(out_dir: Path, checkpoint: dict[str, Any] | None) -> None:
    """One line on what running the command again does for this stopped run."""
    if checkpoint is None:
        log.warning("%s: stopped before its first checkpoint: running the same command again "
                    "starts it over", out_dir)  # fmt: skip
    else:
        counters = progress_text(checkpoint)
        log.warning("%s: running the same command again continues from %s (%s)", out_dir,
                    checkpoint["checkpoint"], counters or "its saved state")  # fmt: skip


def cli() -> None:
    """The ``edr-run`` command: Hydra's app, with Ctrl-C or SIGTERM ending in one line instead
    of a trace (exit status 130 or 143, as the shell reports those signals), on the first one
    (:mod:`edr.checks.interrupts`); a sweep says its summary line before it."""
    interrupts.install()
    try:
        main()
    except ValueError as error:  # Hydra could not open the run's log file: a folder not writable
        if "Unable to configure handler" not in str(error):
            raise
        cause = error.__cause__ or error
        print(
            f"edr-run: cannot write the run's log in its folder ({cause}): make the results "
            "folder writable, or move results with EDR_RESULTS=<folder> (or paths.results=...)",
            file=sys.stderr,
        )
        raise SystemExit(2) from None
    except KeyboardInterrupt as error:
        SweepSummary.interrupted()  # a sweep's line comes, whatever stopped it
        print(
            "\ninterrupted: run the same command again to resume (finished runs are skipped, "
            "interrupted ones continue from their last checkpoint; one stopped before its first "
            "starts over)",
            file=sys.stderr,
        )
        raise SystemExit(143 if isinstance(error, interrupts.Terminated) else 130) from None


if __name__ == "__main__":
    cli()
