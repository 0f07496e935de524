"""``edr-bench``: every representation timed side by side, in one run, on the same clip.

    edr-bench                       # generated 320x240 clip, all cores
    edr-bench --video clip.avi      # a real decoded video (resized to 320x240)
    edr-bench --threads 1 --quick   # one thread, fewer repeats
    edr-bench --atari 16            # instead: Atari env steps/s with and without EDR
    edr-bench --events a.raw b.aedat4   # instead: read speed of event recordings (events/s)

Median throughput over ``--repeats`` timed calls after a warm-up call (which also compiles the
numba kernels). Writes a record only, ``<out-dir>/speed_<host>_<time>.json`` (with ``--atari``,
``atari_<host>_<time>.json``; with ``--events``, ``events_<host>_<time>.json``), and prints its
table. ``--out-dir`` is ``results/runs/bench/`` by default, which git ignores; the committed
records, from which ``edr-tables`` renders ``paper/table2_speed.md`` and
``paper/atari_edr_cost.md``, are written with ``--out-dir results/bench``
(``edr-tables --bench results/runs/bench`` renders yours).
"""

from __future__ import annotations

import argparse
import errno
import io
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager, nullcontext
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, get_args

import numba
import torch
from tqdm import tqdm

from edr.checks.config import (
    Allocation,
    ConfigError,
    Threads,
    check_allocations,
    mismatch,
    writable_folder_problem,
)
from edr.data import read_video, synthetic_scene
from edr.data.video import video_problem
from edr.models.paac import Core
from edr.models.precision import PRECISION_CHOICES
from edr.report.published import load_published
from edr.report.speed import INFERENCE_IN_TURN, LEARNABLE, TRAIN_FUSED, TRAIN_TORCH, speed_table
from edr.representations import (
    EDR,
    FDR,
    TVL1,
    BroxFlow,
    DVSCamera,
    EDRState,
    Farneback,
    GrayDiff,
    Representation,
    RGBDiff,
    decode_motion_vectors,
)
from edr.representations.mpeg_flow import encode_clip
from edr.store.atomic import write_json_atomic
from edr.store.records import BenchRow, bench_dir, git_revision, machine_info
from edr.studies.allocator import keep_freed_memory

K3 = (1.0, 3.8, 8.0)


def time_call(fn: Callable[[], object], repeats: int, warmup: int = 3) -> float:
    """Median wall time of ``fn()`` over ``repeats`` calls after ``warmup`` untimed ones."""
    return time_in_turn([fn], repeats, warmup)[0]


def time_in_turn(fns: list[Callable[[], object]], repeats: int, warmup: int = 3) -> list[float]:
    """Median wall time of each of ``fns``, called in turn (A B A B ...), so that a ratio of two
    of them holds under the machine's drift from one moment to the next."""
    for _ in range(warmup):
        for fn in fns:
            fn()
    times: list[list[float]] = [[] for _ in fns]
    for _ in range(repeats):
        for fn, spent in zip(fns, times, strict=True):
            start = time.perf_counter()
            fn()
            spent.append(time.perf_counter() - start)
    return [statistics.median(spent) for spent in times]


def stream(edr: EDR, frames: torch.Tensor, inplace: bool = False) -> None:
    """Feed (B, T, C, H, W) through ``edr.step`` one frame at a time, as an agent would; with
    ``inplace``, into one state buffer, as the RL transform does."""
    state: EDRState | None = None
    for t in range(frames.shape[1]):
        _, state = edr.step(frames[:, t], state, inplace=inplace)


def train_step(edr: EDR, clip: torch.Tensor, grad: torch.Tensor) -> None:
    """A learnable EDR's forward and backward through the clip, as a training step runs it:
    the events' gradient ``grad`` (dense, the shape of the events) comes from the network
    after it, and reaches the half-life, beta and thresholds. (A sum's gradient would be one
    broadcast value, which no network hands back.)"""
    edr.zero_grad(set_to_none=True)
    with torch.enable_grad():  # the bench times the other rows without autograd
        edr(clip).backward(grad)


def upstream_gradient(edr: EDR, clip: torch.Tensor) -> torch.Tensor:
    """A dense stand-in for the gradient a network sends back to ``edr``'s events of ``clip``."""
    with torch.no_grad():
        shape = edr(clip).shape
    return torch.randn(shape, generator=torch.Generator().manual_seed(0))


def trained_once(edr: EDR, clip: torch.Tensor, grad: torch.Tensor) -> EDR:
    """``edr`` after one Adam step on ``grad``: every parameter off its initial value, as in
    training (beta = 1 exactly takes a shorter path, with no logarithm or exponential)."""
    optimizer = torch.optim.Adam(edr.parameters(), lr=0.01)
    train_step(edr, clip, grad)
    optimizer.step()
    return edr


@dataclass
class Job:
    """One row to time: ``call()`` consumes ``frames`` input frames of ``frame_size``."""

    name: str
    implementation: str
    call: Callable[[], Any]
    frames: int
    frame_size: str
    busy_neighbour: bool = False  # time it while another process keeps one core busy
    in_turn_with: Job | None = None  # timed call by call in turn with this row: a ratio's pair


@contextmanager
def busy_neighbour() -> Iterator[None]:
    """One other process spinning on a core, as a parallel sweep job or a data loader would."""
    neighbour = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        time.sleep(0.3)  # let it get scheduled
        yield
    finally:
        neighbour.kill()
        neighbour.wait()


def on_one_thread(call: Callable[[], Any]) -> Callable[[], Any]:
    """``call`` with torch (and so the fused kernels) on one thread."""

    def run() -> Any:
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            return call()
        finally:
            torch.set_num_threads(threads)

    return run


def long_clip_jobs(long: torch.Tensor, label: str) -> list[Job]:
    """EDR K=1 and GrayDiff on a long clip (1, T, 3, H, W): the plain call and into ``out=``."""
    t, h, w = long.shape[1], long.shape[3], long.shape[4]
    out: list[Job] = []
    for name, rep, channels, frames in (
        ("EDR K=1 soft gray", EDR(color="gray"), 2, t),
        ("GrayDiff", GrayDiff(), 1, t - 1),
    ):
        buffer = torch.empty((1, frames, channels, h, w))
        out += [
            Job(f"{name}, {t}-frame clip", f"fused kernel, plain call{label}",
                lambda rep=rep: rep(long), t, f"{w}x{h}"),
            Job(f"{name}, {t}-frame clip", "fused kernel, into out=",
                lambda rep=rep, b=buffer: rep(long, out=b), t, f"{w}x{h}"),
        ]  # fmt: skip
    return out


def jobs(clip: torch.Tensor, flow_frames: int, atari: torch.Tensor) -> list[Job]:
    """Every row: clip (1, T, 3, H, W) uint8 video, atari (N, T, 1, 84, 84) uint8 frames."""
    t, h, w = clip.shape[1], clip.shape[3], clip.shape[4]
    size = f"{w}x{h}"
    few = clip[:, :flow_frames]
    encoded = encode_clip(clip[0].permute(0, 2, 3, 1).numpy()).getvalue()

    def whole(name: str, implementation: str, rep: Representation, x: torch.Tensor = clip) -> Job:
        return Job(name, implementation, lambda: rep(x), x.shape[1], size)

    gray = EDR(color="gray")
    grad = upstream_gradient(gray, clip)  # the learnable rows' events have the same shape
    fused, torch_ops = (
        trained_once(EDR(color="gray", learnable=True, fast=fast), clip, grad)
        for fast in (True, False)
    )
    return [
        whole("EDR K=1 soft gray", "fused numba kernel", gray),
        Job(
            "EDR K=1 soft gray, streaming",
            "fused kernel, step() per frame",
            lambda: stream(gray, clip),
            t,
            size,
        ),
        Job(
            "EDR K=1 soft gray, streaming",
            "fused kernel, step(inplace=True) per frame",
            lambda: stream(gray, clip, inplace=True),
            t,
            size,
        ),
        whole("EDR K=3 soft gray", "fused numba kernel", EDR(half_lives=K3, color="gray")),
        whole("EDR K=1 soft RGB", "fused numba kernel", EDR()),
        whole("EDR K=1 soft gray", "torch ops (autograd path)", EDR(color="gray", fast=False)),
        Job(
            LEARNABLE,
            TRAIN_FUSED,
            lambda: train_step(fused, clip, grad),
            t,
            size,
            in_turn_with=Job(LEARNABLE, INFERENCE_IN_TURN, lambda: gray(clip), t, size),
        ),
        Job(
            LEARNABLE,
            TRAIN_TORCH,
            lambda: train_step(torch_ops, clip, grad),
            t,
            size,
        ),
        *(
            Job(f"{name}, busy neighbour", f"fused numba kernel, {threads}", call, t, size, True)
            for name, rep in (("EDR K=1 soft gray", gray), ("GrayDiff", GrayDiff()))
            for threads, call in (
                ("all threads", lambda rep=rep: rep(clip)),
                ("1 thread", on_one_thread(lambda rep=rep: rep(clip))),
            )
        ),
        whole("GrayDiff", "fused numba kernel", GrayDiff()),
        whole("GrayDiff", "torch ops", GrayDiff(fast=False)),
        whole("RGBDiff", "torch ops", RGBDiff()),
        whole("FDR (RGB frames)", "torch ops", FDR()),
        Job(
            "MPEG flow",
            "PyAV decode, export_mvs",
            lambda: decode_motion_vectors(io.BytesIO(encoded)),
            t,
            size,
        ),
        whole("DVS simulator", "numba events + binning", DVSCamera(), few),
        whole("Farneback flow", "OpenCV", Farneback(), few),
        whole("TV-L1 flow", "OpenCV contrib", TVL1(), few),
        whole("Brox flow", "torch, CPU, pairs batched", BroxFlow(), few),
        Job(
            "EDR K=1 soft gray, Atari batch",
            f"fused kernel, step(inplace=True) per frame, {atari.shape[0]} envs",
            lambda: stream(gray, atari, inplace=True),
            atari.shape[0] * atari.shape[1],
            f"{atari.shape[0]} x 84x84",
        ),
    ]


def _parser() -> argparse.ArgumentParser:
    """edr-bench's options: the representations' speed (default), --atari or --events."""
    parser = argparse.ArgumentParser(prog="edr-bench", description=__doc__.split("\n\n")[0])
    parser.error = lambda message: parser.exit(  # type: ignore[method-assign]
        2, f"edr-bench: {message} (edr-bench --help lists the flags)\n"
    )  # one line, as every refusal, not argparse's usage block
    parser.add_argument("--video", type=Path, help="a real video to time on (default: generated)")
    parser.add_argument("--frames", type=int, default=32, help="frames per call (clip length)")
    parser.add_argument("--flow-frames", type=int, default=6, help="frames per call for slow flows")
    parser.add_argument(
        "--long-frames", type=int, default=250, help="frames of the long clip (plain call, out=)"
    )
    parser.add_argument("--height", type=int, default=240, help="frame height of the timed clip")
    parser.add_argument("--width", type=int, default=320, help="frame width of the timed clip")
    parser.add_argument("--atari-batch", type=int, default=32, help="envs in the Atari-like batch")
    parser.add_argument("--repeats", type=int, default=7, help="timed calls per row (median)")
    parser.add_argument("--threads", type=int, default=None, help="CPU threads (default: all)")
    parser.add_argument("--warmup", type=int, default=3, help="untimed calls before timing")
    parser.add_argument(
        "--quick", action="store_true",
        help="a smoke test of seconds: 2 repeats, 1 warm-up call, small clips (what you set "
        "yourself stays)",
    )  # fmt: skip
    parser.add_argument(
        "--atari", type=int, metavar="ENVS", default=0,
        help="instead: env steps/s of ENVS parallel Atari envs with and without the EDR transform",
    )  # fmt: skip
    parser.add_argument(
        "--events", type=Path, nargs="+", metavar="FILE",
        help="instead: events/s read_recording reads from these recordings (any format)",
    )  # fmt: skip
    parser.add_argument("--game", default="Pong", help="the Atari game for --atari")
    parser.add_argument(
        "--backends", default="envpool,parallel",
        help="the env backends --atari compares, in one run (comma-separated)",
    )  # fmt: skip
    parser.add_argument(
        "--train-frames", type=int, default=32_000,
        help="env steps of task=atari's training loop timed per backend (--atari; 0: skip)",
    )  # fmt: skip
    parser.add_argument(
        "--network", default=None, choices=get_args(Core),
        help="the training loop's core (--atari; default: task=atari's)",
    )  # fmt: skip
    parser.add_argument(
        "--precision", default=None, choices=PRECISION_CHOICES,
        help="the training loop's network precision (--atari; default: task=atari's)",
    )  # fmt: skip
    parser.add_argument(
        "--steps", type=int, default=200, help="agent steps per timed rollout (--atari)"
    )
    parser.add_argument(
        "--obs-dtype",
        choices=["float32", "float16"],
        default="float32",
        help="the observation's dtype, float32 as task=atari trains (--atari)",
    )
    parser.add_argument(
        "--out-dir",
        type=Path,
        default=bench_dir(),
        help="where the record is written (default: results/runs/bench, untracked)",
    )
    return parser


# --quick's sizes, where the command line does not set them: seconds a row, every row timed
QUICK = {"repeats": 2, "warmup": 1, "frames": 4, "flow_frames": 2, "long_frames": 9,
         "height": 48, "width": 64, "atari_batch": 2}  # fmt: skip
AT_LEAST = {"repeats": 1, "warmup": 0, "frames": 2, "flow_frames": 2, "long_frames": 2,
            "height": 16, "width": 16, "atari_batch": 1, "steps": 1, "train_frames": 0,
            "atari": 0}  # fmt: skip


def _settings(parser: argparse.ArgumentParser, argv: list[str] | None) -> argparse.Namespace:
    """The options, --quick's sizes filled in where not given; one line (exit 2) for a value
    that cannot work, before the minutes of timing: a count below what can be timed
    (``--repeats 0``: no call to take a median of), more threads than cores, a game or backend
    that does not exist, a ``--video`` that is no video of two frames, sizes whose arrays
    together exceed the memory available, an ``--out-dir`` the record cannot be written into."""
    args = parser.parse_args(argv)
    if args.quick:
        for key, value in QUICK.items():
            if getattr(args, key) == parser.get_default(key):  # not set on the command line
                setattr(args, key, value)
    try:
        _check_values(args)
    except ConfigError as error:
        parser.exit(2, f"edr-bench: {error}\n")
    return args


def _flag(key: str, value: Any) -> str:
    return f"--{key.replace('_', '-')}={value}"


def _check_values(args: argparse.Namespace) -> None:
    """:class:`ConfigError` naming the first flag whose value cannot work."""
    for key, low in AT_LEAST.items():
        if getattr(args, key) < low:
            raise ConfigError(f"{_flag(key, getattr(args, key))}: expected a number >= {low}")
    if args.threads is not None and (expected := mismatch(args.threads, Threads)):
        raise ConfigError(f"--threads={args.threads}: expected {expected}")
    if args.video is not None and (problem := video_problem(args.video)):
        raise ConfigError(f"--video={args.video}: expected {problem}")
    if args.atari:
        from edr.rl.envs import AtariGame  # ale-py and torchrl load only for this mode
        from edr.studies.bench_atari import BACKEND_NAMES

        if expected := mismatch(args.game, AtariGame):
            raise ConfigError(f"--game={args.game}: expected {expected}")
        backends = args.backends.split(",")
        wrong = [b for b in backends if b not in BACKEND_NAMES]
        if wrong:
            raise ConfigError(
                f"--backends={args.backends}: expected backends among {', '.join(BACKEND_NAMES)}, "
                f"comma-separated ({wrong[0]!r} is none)"
            )
    check_allocations(planned_allocations(args))
    if problem := writable_folder_problem(args.out_dir):
        raise ConfigError(f"--out-dir={args.out_dir}: expected {problem}")


EVENTS_CHANNELS = 6  # the widest row's events: EDR K=3 soft gray and EDR K=1 soft RGB, 2 x 3
WORKER_BYTES = 50 * 2**20  # a spawned Python with torch imported holds more than this


def planned_allocations(args: argparse.Namespace) -> list[Allocation]:
    """Lower bounds of the arrays a bench holds at once, each with the flags that size it: the
    timed clip (uint8, a float32 copy, the widest row's float32 events, the learnable rows'
    gradient), the long clip (twice while it is cut, its two out= buffers per pass) and the
    Atari-like batch; with ``--atari``, each backend's observation rings and worker processes."""
    size = f"--height={args.height}, --width={args.width}"
    if args.atari:
        from edr.rl.rollout import observations_held

        rings = 2 * args.atari * observations_held(5, 4) * 5 * 84 * 84 * 4  # FDR + EDR, float32
        workers = 2 * args.atari * WORKER_BYTES if "parallel" in args.backends.split(",") else 0
        return [
            Allocation(f"--atari={args.atari}", "the envs' observation rings", rings),
            Allocation(
                f"--atari={args.atari}",
                f"{2 * args.atari} env worker processes (backend parallel), at least 50 MiB each",
                workers,
            ),
        ]
    if args.events:
        return []
    pixels, long = (
        args.frames * args.height * args.width,
        args.long_frames * args.height * args.width,
    )
    return [
        Allocation(f"--frames={args.frames}, {size}", f"the timed clip of {args.frames} frames, "
                   "its float32 copy, a row's events and the learnable rows' gradient",
                   pixels * (3 + 3 * 4 + EVENTS_CHANNELS * 4 + 2 * 4)),
        Allocation(f"--long-frames={args.long_frames}, {size}", f"the long clip of "
                   f"{args.long_frames} frames, cut from its repeats, and its out= buffers",
                   long * (2 * 3 + 2 * (2 + 1) * 4)),
        Allocation(f"--atari-batch={args.atari_batch}, --frames={args.frames}",
                   "the Atari-like batch", args.atari_batch * args.frames * 84 * 84),
    ]  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    """``edr-bench``: a refused value is one line, exit 2, before any timing; a record that
    cannot be written (a full disk) one line, exit 1."""
    parser = _parser()
    args = _settings(parser, argv)
    try:
        _bench(parser, args)
    except ConfigError as error:  # a setting only the run finds (a game EnvPool lacks)
        parser.exit(2, f"edr-bench: {error}\n")
    except OSError as error:
        if error.errno not in DISK_ERRORS:
            raise
        parser.exit(1, f"edr-bench: cannot write under --out-dir={args.out_dir}: "
                       f"{error.strerror} ({error.filename or args.out_dir})\n")  # fmt: skip


# errors of the disk the record goes to
DISK_ERRORS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EACCES, errno.EIO}


def _bench(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """The mode the flags chose."""
    repeats = args.repeats
    if args.threads:
        torch.set_num_threads(args.threads)
    if args.atari:
        from edr.studies.bench_atari import (
            run_atari_bench,  # ale-py, EnvPool and torchrl load only here
        )

        run_atari_bench(args, repeats)
    elif args.events:
        from edr.data.events.checks import RecordingError
        from edr.studies.bench_events import run_events_bench

        try:
            run_events_bench(args, repeats)
        except RecordingError as error:  # a folder, a missing or unreadable file: one line
            parser.exit(2, f"edr-bench: {error}\n")
    else:
        run_speed_bench(args, repeats)


def run_speed_bench(args: argparse.Namespace, repeats: int) -> None:
    """Every representation's frames/s on one clip (Table 2's speed column), printed beside the
    paper's and written as a record."""
    clip, source = _timed_clip(args)
    repeat = -(-args.long_frames // clip.shape[1])  # the clip played again until long enough
    long = clip.repeat(1, repeat, 1, 1, 1)[:, : args.long_frames].contiguous()
    atari = torch.randint(0, 256, (args.atari_batch, args.frames, 1, 84, 84), dtype=torch.uint8)
    todo = jobs(clip, min(args.flow_frames, clip.shape[1]), atari) + long_clip_jobs(long, "")
    # The process's allocator as users have it; the last rows again with glibc keeping freed
    # memory (allocator.keep_freed_memory, process-wide, so only after everything else).
    kept = long_clip_jobs(long, ", glibc keeping freed memory")[::2]
    rows = _time_rows(todo, kept, repeats, args.warmup)
    record = {
        "kind": "speed",
        "clip": source,
        "frames_per_call": clip.shape[1],
        "repeats": repeats,
        "warmup": args.warmup,
        "git": git_revision(),
        "measured_at": time.strftime("%Y-%m-%d_%H-%M-%S"),
        "machine": _speed_machine(),
        "rows": [asdict(r) for r in rows],
    }
    name = f"speed_{record['machine']['hostname']}_{record['measured_at']}.json"
    path = write_json_atomic(args.out_dir / name, record)
    print(speed_table([(path, record)], load_published().get("speed", {})))
    print(f"record: {path} (edr-tables renders paper/table2_speed.md from the latest record)")


def _timed_clip(args: argparse.Namespace) -> tuple[torch.Tensor, str]:
    """The clip every row times, (1, T, 3, H, W) uint8: ``--video`` decoded, or a generated
    scene; and its description."""
    size = (args.width, args.height)
    if args.video:
        clip = read_video(args.video, max_frames=args.frames, size=size)
        source = f"{args.video.name} (decoded, resized to {args.width}x{args.height})"
    else:
        clip = synthetic_scene(args.frames, args.height, args.width)
        source = f"generated scene, {args.width}x{args.height}"
    return clip.unsqueeze(0).contiguous(), source


def _time_rows(todo: list[Job], kept: list[Job], repeats: int, warmup: int) -> list[BenchRow]:
    """Each job timed (with its pair in turn, beside a busy neighbour where it asks), then the
    ``kept`` jobs once glibc keeps freed memory (skipped elsewhere)."""
    rows: list[BenchRow] = []
    with torch.no_grad():
        for job in (bar := tqdm([*todo, *kept], desc="edr-bench", unit="row")):
            bar.set_postfix_str(job.name)
            if kept and job is kept[0] and not keep_freed_memory():
                break  # not glibc: nothing to compare with
            pair = [job] if job.in_turn_with is None else [job, job.in_turn_with]
            with busy_neighbour() if job.busy_neighbour else nullcontext():
                spent = time_in_turn([j.call for j in pair], repeats, warmup=warmup)
            rows += [
                BenchRow(j.name, j.implementation, j.frames, j.frame_size, s, j.frames / s)
                for j, s in zip(pair, spent, strict=True)
            ]
    return rows


def _speed_machine() -> dict[str, Any]:
    """The machine, with numba's threads and the allocator the rows ran under."""
    machine = machine_info()
    machine["numba_threads"] = numba.get_num_threads()
    machine["numba_threading_layer"] = numba.threading_layer()
    machine["allocator"] = "process default (glibc: freed memory kept only in the last rows)"
    return machine


if __name__ == "__main__":
    main()
