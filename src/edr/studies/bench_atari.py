"""``edr-bench --atari``: what EDR costs in the Atari loop. Env steps per second of the same
envs with and without EDR, the two taking turns, and ``task=atari``'s whole training loop with
FDR alone and with FDR+EDR; a record per backend, ``<out-dir>/atari_<backend>_<host>_<time>.json``.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from tqdm import tqdm

from edr.models.paac import Core
from edr.models.precision import PrecisionChoice
from edr.report.speed import atari_cost_table
from edr.representations import EDR
from edr.store.atomic import write_json_atomic
from edr.store.records import BenchRow, git_revision, machine_info


@dataclass
class AtariThroughput:
    """``edr-bench --atari``: the two configs' rows, and EDR's cost per pair of rollouts."""

    rows: list[BenchRow]  # FDR, then FDR + EDR; median over the timed rollouts
    main_cpu_ms: list[float]  # per row: the main process's CPU ms per agent step (median)
    costs: list[float]  # per pair of rollouts: 1 - (FDR+EDR steps/s) / (FDR steps/s), in %

    @property
    def cost(self) -> float:
        """EDR's cost in %: the median over pairs, which load drifts shared by a pair cancel."""
        return statistics.median(self.costs)


TRAIN_ROLLOUT_STEPS = 5  # task=atari's rollout length and frames per network input: they
TRAIN_FRAME_STACK = 4  # size its ring of observations (its network takes the last 4)
BACKEND_NAMES = {"envpool": "EnvPool (torchrl EnvBase)", "parallel": "torchrl ParallelEnv",
                 "serial": "torchrl SerialEnv"}  # fmt: skip


def training_throughput(
    game: str, num_envs: int, backend: str, env_steps: int, inputs: str = "fdr_edr",
    core: Core | None = None, precision: PrecisionChoice | None = None,
) -> tuple[float, float, dict[str, float]]:  # fmt: skip
    """Env steps/s of ``task=atari``'s training loop (``inputs``: FDR RGB + EDR gray or FDR RGB;
    ``core``: the network's, the task's default if None, with one frame per step for
    ``lenet_ftlstm``; ``precision`` the network's, the task's default if None; its defaults
    otherwise) over ``env_steps`` env steps: from the first rollout on, as its progress
    bar shows them, and steady (from a quarter of the way on, after the first updates compiled
    the EDR kernels and warmed the allocator: what a run of hours sees); and where the steady
    part's time went, ms per update by phase (``time/*_ms`` of its history)."""
    from edr.report.runs import read_history
    from edr.rl.settings import EnvSettings, EvalSettings, NetworkSettings
    from edr.tasks.atari import train_paac

    chosen = {"core": core, "precision": precision}
    network = NetworkSettings(**{k: v for k, v in chosen.items() if v is not None})
    with tempfile.TemporaryDirectory() as out_dir:
        env = EnvSettings(
            game=game, backend=backend, num_envs=num_envs, inputs=inputs,
            edr=EDR(color="gray") if inputs != "fdr" else None,
            frame_stack=1 if network.core == "lenet_ftlstm" else TRAIN_FRAME_STACK,
        )  # fmt: skip
        metrics = train_paac(
            out_dir=Path(out_dir), seed=0, env=env, network=network,
            env_steps=env_steps,
            evaluation=EvalSettings(plays=1, max_steps=1), checkpoint_every=10**9, logger=None,
        )  # fmt: skip
        history = read_history(Path(out_dir))
    fps = float(metrics["train/fps"])
    if len(history) < 2:
        return fps, fps, _phases(history)
    # each row's fps is cumulative from the first rollout: its elapsed time is env steps / fps
    elapsed = [row["env_steps"] / row["train/fps"] for row in history]
    warm = min(
        len(history) - 2,
        next(i for i, r in enumerate(history) if r["env_steps"] >= env_steps / 4),
    )
    steady = (history[-1]["env_steps"] - history[warm]["env_steps"]) / (elapsed[-1] - elapsed[warm])
    return fps, steady, _phases(history[warm + 1 :])


def _phases(rows: list[dict[str, float]]) -> dict[str, float]:
    """Mean ms per update of each phase over the history's ``rows``."""
    keys = [k for k in rows[0] if k.startswith("time/")] if rows else []
    return {k.removeprefix("time/"): statistics.mean(r[k] for r in rows) for k in keys}


def atari_throughput(
    game: str, num_envs: int, steps: int, repeats: int, warmup: int,
    obs_dtype: str = "float32", backend: str = "parallel",
) -> AtariThroughput:  # fmt: skip
    """Agent steps per second of ``num_envs`` parallel envs, with and without the EDR transform.

    Both use the paper's preset and RGB frames, one agent step's frame per observation, as
    ``task=atari`` builds its envs; the EDR run adds EDR on gray (Appendix C's 5 channels). Random actions; ``fps`` counts env steps of
    all envs. The two envs live side by side and take turns (in alternating order), so that load
    drifts hit both alike; each plays on from where its last rollout stopped, as in training.
    """
    from edr.rl.envs import make_atari_env  # ale-py and torchrl load only for this mode
    from edr.rl.rollout import observations_held

    configs = {"FDR RGB": None, "FDR RGB + EDR gray": EDR(color="gray")}
    envs = [
        make_atari_env(
            game,
            num_envs=num_envs,
            backend=backend,
            edr=edr,
            obs_dtype=obs_dtype,
            keep_inputs=False,  # as task=atari trains: the observation alone
            frame_ring=observations_held(TRAIN_ROLLOUT_STEPS, TRAIN_FRAME_STACK),
        )
        for edr in configs.values()
    ]
    data: list[Any] = []  # each env's latest tensordict: the streams go on across rollouts

    def play(j: int) -> None:  # as a collector steps: act, step, reset what ended; keep nothing
        env, td = envs[j], data[j]
        for _ in range(steps):
            _, td = env.step_and_maybe_reset(td.set("action", env.action_spec.rand()))
        data[j] = td

    wall: list[list[float]] = [[] for _ in envs]
    cpu: list[list[float]] = [[] for _ in envs]
    try:
        for j, env in enumerate(envs):
            env.set_seed(0)
            data.append(env.reset())
            for _ in range(warmup):
                play(j)
        for i in tqdm(range(repeats), desc="atari rollouts", unit="pair"):
            for j in (0, 1) if i % 2 == 0 else (1, 0):
                start, start_cpu = time.perf_counter(), time.process_time()
                play(j)
                wall[j].append(time.perf_counter() - start)
                cpu[j].append(time.process_time() - start_cpu)
    finally:
        for env in envs:
            env.close()
    implementation = f"{BACKEND_NAMES[backend]}, {num_envs} envs, paac preset"
    frames = steps * num_envs
    rows = [
        BenchRow(f"{game}: {name}, {obs_dtype}", implementation, frames, "84x84",
            statistics.median(t), frames / statistics.median(t))
        for name, t in zip(configs, wall, strict=True)
    ]  # fmt: skip
    return AtariThroughput(
        rows=rows,
        main_cpu_ms=[1e3 * statistics.median(c) / steps for c in cpu],
        costs=[100 * (1 - fdr / edr) for fdr, edr in zip(*wall, strict=True)],
    )


def run_atari_bench(args: argparse.Namespace, repeats: int) -> None:
    """The ``--atari`` mode of ``edr-bench``: a record per backend, then the cost table."""
    from edr.rl.settings import NetworkSettings

    stamp, machine = time.strftime("%Y-%m-%d_%H-%M-%S"), machine_info()
    core = args.network or NetworkSettings().core  # the record names the core it timed
    precision = args.precision or NetworkSettings().precision  # and the precision
    records = []
    for backend in args.backends.split(","):
        result = atari_throughput(
            args.game, args.atari, args.steps, repeats, args.warmup, args.obs_dtype, backend,
        )  # fmt: skip
        training = {}  # train_fps(_steady, _phases_ms): FDR + EDR, as before; train_fps_fdr...: FDR
        for inputs, key in (("fdr", "train_fps_fdr"), ("fdr_edr", "train_fps")):
            fps = (None, None, {})
            if args.train_frames:
                fps = training_throughput(
                    args.game, args.atari, backend, args.train_frames, inputs, core, precision
                )
            training[key], training[f"{key}_steady"], training[f"{key}_phases_ms"] = fps
        record = {"kind": "atari_throughput", "git": git_revision(), "measured_at": stamp,
                  "game": args.game, "num_envs": args.atari, "backend": backend,
                  "obs_dtype": args.obs_dtype,
                  "repeats": repeats, "warmup": args.warmup, "steps": args.steps,
                  "train_frames": args.train_frames, "network": core, "precision": precision, **training,
                  "machine": machine, **asdict(result), "cost": result.cost}  # fmt: skip
        name = f"atari_{backend}_{machine['hostname']}_{stamp}.json"
        records.append((write_json_atomic(args.out_dir / name, record), record))
        for r, cpu in zip(result.rows, result.main_cpu_ms, strict=True):
            print(
                f"{backend:9s} {r.name:40s} {r.fps:8.1f} env steps/s "
                f"({4 * r.fps:.0f} emulator frames/s), main process {cpu:.2f} CPU ms/step"
            )
        print(
            f"{backend:9s} EDR costs {result.cost:.1f} % of throughput (median of {repeats} "
            f"paired rollouts; {min(result.costs):.1f} to {max(result.costs):.1f} %)"
        )
        if args.train_frames:
            print(
                f"{backend:9s} training loop, env steps/s (steady): FDR "
                f"{training['train_fps_fdr']:.0f} ({training['train_fps_fdr_steady']:.0f}), "
                f"FDR + EDR {training['train_fps']:.0f} ({training['train_fps_steady']:.0f}); "
                f"over random actions (steady, FDR + EDR): "
                f"{training['train_fps_steady'] / result.rows[1].fps:.2f}"
            )
            for inputs, key in (("FDR", "train_fps_fdr"), ("FDR + EDR", "train_fps")):
                phases = training[f"{key}_phases_ms"]
                print(f"{backend:9s} {inputs} ms per update: " + ", ".join(
                    f"{name.removesuffix('_ms')} {ms:.1f}" for name, ms in phases.items()))  # fmt: skip
    print(atari_cost_table(records))
    print(f"records: {', '.join(str(p) for p, _ in records)} (edr-tables renders "
          "paper/atari_edr_cost.md from them)")  # fmt: skip
