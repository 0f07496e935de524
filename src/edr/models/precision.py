"""In which precision a network computes on the CPU: float32, or bfloat16 autocast where the CPU
has bfloat16 units (Intel's AMX ``amx_bf16``, AVX-512 ``avx512_bf16``), chosen by timing.

Autocast runs the convolutions and matrix products in bfloat16 (oneDNN's AMX kernels) and keeps
the rest (sums, normalisation statistics, the loss) in float32; the parameters, their gradients
and the optimizer's state stay float32. ``auto`` takes bfloat16 only on a CPU that has the units
*and* where timing the network's own update in both precisions, in turns, shows bfloat16 faster:
emulated bfloat16 on a CPU without them is slower than float32.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from contextlib import AbstractContextManager
from pathlib import Path
from typing import Literal, get_args

import torch

Precision = Literal["float32", "bfloat16"]
PrecisionChoice = Precision | Literal["auto"]
PRECISION_CHOICES = (*get_args(Precision), "auto")
BF16_FLAGS = ("amx_bf16", "avx512_bf16")  # /proc/cpuinfo's flags of CPUs with bfloat16 units
MIN_GAIN = 0.05  # auto takes bfloat16 only if it cuts the timed step's median by this much
CPUINFO = Path("/proc/cpuinfo")


def autocast(precision: Precision) -> AbstractContextManager:
    """The context a forward pass runs in: bfloat16 autocast on the CPU, or nothing."""
    return torch.autocast("cpu", dtype=torch.bfloat16, enabled=precision == "bfloat16")


def bf16_units(cpuinfo: Path = CPUINFO) -> list[str]:
    """The bfloat16 units this CPU announces (of :data:`BF16_FLAGS`); [] where it has none or
    the system does not say (not Linux)."""
    try:
        text = cpuinfo.read_text()
    except OSError:
        return []
    flags = {
        word for line in text.splitlines() if line.startswith("flags") for word in line.split()
    }
    return [flag for flag in BF16_FLAGS if flag in flags]


def time_precisions(step: Callable[[Precision], None], rounds: int = 5) -> dict[Precision, float]:
    """Median ms of ``step(precision)`` for each precision, the two timed in turns after one
    untimed call each (a load drift then touches both alike)."""
    times: dict[Precision, list[float]] = {"float32": [], "bfloat16": []}
    for precision in times:
        step(precision)
    for _ in range(rounds):
        for precision, samples in times.items():
            start = time.perf_counter()
            step(precision)
            samples.append(1e3 * (time.perf_counter() - start))
    return {precision: statistics.median(samples) for precision, samples in times.items()}


def choose_precision(
    choice: PrecisionChoice, step: Callable[[Precision], None], cpuinfo: Path = CPUINFO
) -> tuple[Precision, dict[str, float]]:
    """``choice`` made concrete, and what decided it: ``auto`` is bfloat16 where the CPU has
    bfloat16 units and ``step`` (one update of the run's network, say) timed in both precisions
    is at least :data:`MIN_GAIN` faster in bfloat16; else float32. The second value holds the
    medians in ms (``float32_ms``, ``bfloat16_ms``) when they were timed."""
    if choice != "auto":
        return choice, {}
    if not bf16_units(cpuinfo):
        return "float32", {}
    times = time_precisions(step)
    gain = 1 - times["bfloat16"] / times["float32"]
    chosen: Precision = "bfloat16" if gain >= MIN_GAIN else "float32"
    return chosen, {"float32_ms": times["float32"], "bfloat16_ms": times["bfloat16"]}
