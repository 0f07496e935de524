"""Fused CPU kernels (numba) for inference: one pass over the pixels per frame, no temporaries.

The kernels split the pixels of each clip into chunks that fit in L1/L2 and give every
(batch row, chunk) to one thread, which then walks the frames in order: the EMA state of its
chunk stays in cache for the whole clip (``kernel_core.INFERENCE_CHUNK`` pixels a chunk).
They compute the same float32 expressions, in the same order, as the torch code in ``edr.py``
and ``frames.py``, so the two paths agree to rounding; the per-pixel steps (the intensity's
load, the EMA's step, the threshold) are :mod:`edr.representations.kernel_core`'s, which the
training kernels share.
``frame_kernel`` is ``edr_kernel`` for one streaming step that also writes FDR: an Atari
observation frame in one pass (``edr.rl.transform.ObservationFrame``).
Compiled code is cached on disk (``cache=True``): only the first call on a machine compiles.
Call them through ``launch``, which runs them on as many threads as torch uses, or on one for a
small call (:data:`PARALLEL_MIN_PIXELS`).

Threads: numba runs them on Intel TBB where the ``tbb`` wheel is installed (a dependency; loaded
here, as numba looks for it only on the library path). TBB's threads take work from a shared
pool and the launching thread does what no other thread has taken, so a thread the OS preempts
for a busy neighbour delays nothing it has not started. Under OpenMP every launch ends at a
barrier that waits for the preempted thread: with one busy process beside it on 2 cores the
2-thread kernel ran ~5-70x slower than on 1 thread. ``edr-bench`` reports the layer it ran on.
"""

from __future__ import annotations

import ctypes
import site
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numba
import numpy as np
import torch
from numba import njit, prange

from edr.representations.kernel_core import (
    INFERENCE_CHUNK,
    LUMA,
    ema_step,
    load_intensity,
    threshold,
)

# Fewer pixel-frames than this run on the launching thread alone. After a parallel launch TBB's
# worker spins ~1 ms of CPU before it sleeps, whatever the launch's size: a streaming env step
# of 16 Pong envs (113K pixels) took 0.25 ms on 1 thread and 0.23 ms on 2, plus that 1 ms taken
# from the emulator's threads on the other core (EDR then cost 16 % of env steps/s). Two threads
# save more than the spin only from ~1M pixel-frames on (0.28 ms at 0.9M, 1.8 ms at 3.6M).
PARALLEL_MIN_PIXELS = 1 << 21


def _load_tbb() -> str | None:
    """Load the ``tbb`` wheel's ``libtbb.so.12`` (it lives in ``<prefix>/lib``, which is not on the
    loader's path), so that numba's default layer order picks TBB; the path, or None."""
    for prefix in (sys.prefix, site.getuserbase()):
        path = Path(prefix) / "lib" / "libtbb.so.12"
        if path.is_file():
            try:
                ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)
            except OSError:
                continue
            return str(path)
    return None


TBB_LIBRARY = _load_tbb()

ZERO = np.float32(0.0)
ONE = np.float32(1.0)


def launch(kernel: Callable[..., None], pixels: int, *args: Any) -> None:
    """``kernel(*args)`` on ``torch.get_num_threads()`` numba threads, leaving torch's count as is;
    on one thread when the call covers fewer than ``PARALLEL_MIN_PIXELS`` pixel-frames.

    numba's OpenMP layer shares torch's libgomp and sets the pool to numba's own thread count on
    every launch, which would silently undo ``torch.set_num_threads`` (a ParallelEnv sets the main
    process to one thread so that its workers keep the cores; numba would make it two again).
    """
    threads = torch.get_num_threads()
    wanted = threads if pixels >= PARALLEL_MIN_PIXELS else 1
    numba.set_num_threads(min(wanted, numba.config.NUMBA_NUM_THREADS))
    try:
        kernel(*args)
    finally:
        if torch.get_num_threads() != threads:
            torch.set_num_threads(threads)


@njit(inline="always")
def _chunk(job, n_chunks, n_pix):
    """Work item ``job`` -> (batch row, first pixel, pixel count) of its chunk."""
    lo = (job % n_chunks) * INFERENCE_CHUNK
    return job // n_chunks, lo, min(INFERENCE_CHUNK, n_pix - lo)


@njit(parallel=True, cache=True)
def edr_kernel(
    x,
    interleaved,
    gray,
    eps,
    alpha,
    beta,
    on_th,
    off_th,
    log_form,
    hard,
    sum_k,
    ema_source,
    copy_state,
    ema,
    restart,
    out,
):
    """Run EDR over the frames of ``x``, carrying ``ema`` in place.

    x       (B, T, C_in, P), or (B, T, 1, P * C_in) with ``interleaved`` = C_in (0: planar);
            uint8 or float32 intensities without eps
    gray    convert 3 input channels to one luma channel
    alpha, beta  (K,) float32
    on_th, off_th  (K_out,) thresholds already in the domain of ``log_form``
    ema_source, copy_state  with ``copy_state``, each chunk's state is first copied from
            ``ema_source`` (B, C, K, P) into ``ema`` (rows that restart excepted)
    ema     (B, C, K, P) float32 state, updated in place
    restart (B,) bool: rows whose EMA restarts from the first frame of ``x``
    out     (B, T, C, K_out, 2, P) float32, K_out = 1 if ``sum_k`` else K; last-but-one axis ON, OFF
    """
    n_batch, n_frames = x.shape[0], x.shape[1]
    n_pix = x.shape[3] // interleaved if interleaved else x.shape[3]
    n_chan, n_k = ema.shape[1], ema.shape[2]
    n_chunks = (n_pix + INFERENCE_CHUNK - 1) // INFERENCE_CHUNK
    for job in prange(n_batch * n_chunks):
        b, lo, n = _chunk(job, n_chunks, n_pix)
        intensity = np.empty(n, np.float32)
        acc = np.empty(n, np.float32)
        if copy_state and not restart[b]:
            for c in range(n_chan):
                for k in range(n_k):
                    ema[b, c, k, lo : lo + n] = ema_source[b, c, k, lo : lo + n]
        for t in range(n_frames):
            for c in range(n_chan):
                load_intensity(x, b, t, c, lo, gray, interleaved, LUMA, eps, intensity)
                _edr_channel(
                    ema, b, c, lo, n, intensity, t == 0 and restart[b], alpha, beta, on_th,
                    off_th, log_form, hard, sum_k, acc, out, (b, t, c, lo),
                )  # fmt: skip


@njit(parallel=True, cache=True)
def frame_kernel(
    x,
    interleaved,
    fdr_slots,
    fdr_gray,
    edr_slots,
    edr_gray,
    eps,
    alpha,
    beta,
    on_th,
    off_th,
    log_form,
    hard,
    sum_k,
    ema,
    restart,
    out,
):
    """One step of B envs -> their observation frames, channels-last, in one pass: FDR (the
    pixels / 255), then EDR's events, carrying ``ema`` in place (``edr_kernel`` on one frame).

    x          (B, 1, C_in, P) uint8, or (B, 1, 1, P * C_in) with ``interleaved`` = C_in (0: planar)
    fdr_slots  a tuple of C_fdr zeros: 0 (no FDR), 1 (``fdr_gray``: luma) or C_in
    edr_slots  a tuple of C_edr = C * K_out * 2 zeros (EDR's channels, in ``edr_kernel``'s order
               (C, K_out, ON / OFF); empty: no EDR)
    ema        (B, C, K, P) float32; ``restart`` (B,) bool as in ``edr_kernel``
    out        (B, P * (C_fdr + C_edr)) float32: each pixel's channels together

    The channel counts come as the lengths of tuples because numba compiles those in as
    constants: each pixel's channels are then stored at a fixed stride, which LLVM vectorises
    (at a stride known only at run time the frame took 1.8x as long, 16 Pong envs).
    """
    n_batch = x.shape[0]
    n_pix = x.shape[3] // interleaved if interleaved else x.shape[3]
    n_chan, n_k = ema.shape[1], ema.shape[2]
    n_kout = 1 if sum_k else n_k
    n_fdr, n_edr = len(fdr_slots), len(edr_slots)
    n_chunks = (n_pix + INFERENCE_CHUNK - 1) // INFERENCE_CHUNK
    for job in prange(n_batch * n_chunks):
        b, lo, n = _chunk(job, n_chunks, n_pix)
        values = np.empty(n, np.float32)
        acc = np.empty(n, np.float32)
        events = np.empty((1, 1, n_chan, n_kout, 2, n), np.float32)  # as edr_kernel's out
        for c in range(n_chan):
            load_intensity(x, b, 0, c, lo, edr_gray, interleaved, LUMA, eps, values)
            _edr_channel(
                ema, b, c, lo, n, values, restart[b], alpha, beta, on_th, off_th, log_form,
                hard, sum_k, acc, events, (0, 0, c, 0),
            )  # fmt: skip
        frame = out[b, (n_fdr + n_edr) * lo : (n_fdr + n_edr) * (lo + n)]
        events_flat = events.reshape(n_edr, n)
        if n_fdr == 0 or not (fdr_gray or interleaved):  # FDR read from the pixels' planes
            _write_frame(frame, n, x[b, 0, :, lo : lo + n], events_flat, fdr_slots, edr_slots)
        else:  # FDR's values gathered first: luma, or the channels of interleaved pixels
            fdr = np.empty((n_fdr, n), np.float32)
            for c in range(n_fdr):
                load_intensity(x, b, 0, c, lo, fdr_gray, interleaved, LUMA, ZERO, fdr[c])
            _write_frame(frame, n, fdr, events_flat, fdr_slots, edr_slots)


@njit(inline="always")
def _write_frame(frame, n, fdr, events, fdr_slots, edr_slots):
    """frame (n * C) channels-last <- FDR ``fdr`` (C_fdr, n) / 255, then ``events`` (C_edr, n)."""
    n_fdr, n_edr = len(fdr_slots), len(edr_slots)
    stride = n_fdr + n_edr
    for i in range(n):
        for c in range(n_fdr):
            frame[stride * i + c] = np.float32(fdr[c, i]) / np.float32(255.0)
        for j in range(n_edr):
            frame[stride * i + n_fdr + j] = events[j, i]


@njit(inline="always")
def _edr_channel(ema, b, c, lo, n, intensity, first, alpha, beta, on_th, off_th, log_form, hard,
                 sum_k, acc, out, at):  # fmt: skip
    """Channel c of one frame at pixels lo..lo+n of row b: its EMAs ``ema[b, c, :]`` move on
    (restarting from ``intensity`` (n,) when ``first``) and its events go to ``out[ob, ot, oc,
    k, ON / OFF, olo:olo+n]``, (ob, ot, oc, olo) = ``at``."""
    ob, ot, oc, olo = at
    if first:
        for k in range(ema.shape[2]):
            ema[b, c, k, lo : lo + n] = intensity
    if sum_k:
        acc[:] = ZERO
        for k in range(ema.shape[2]):
            _ema_log_sum(ema[b, c, k, lo : lo + n], intensity, alpha[k], beta[k], acc)
        on = out[ob, ot, oc, 0, 0, olo : olo + n]
        off = out[ob, ot, oc, 0, 1, olo : olo + n]
        _sum_events(acc, on_th[0], off_th[0], log_form, hard, on, off)
        return
    for k in range(ema.shape[2]):
        on = out[ob, ot, oc, k, 0, olo : olo + n]
        off = out[ob, ot, oc, k, 1, olo : olo + n]
        _ema_events(
            ema[b, c, k, lo : lo + n], intensity, alpha[k], beta[k], on_th[k], off_th[k],
            log_form, hard, on, off,
        )  # fmt: skip


@njit(inline="always")
def _ema_events(em, intensity, a, bk, hi_th, lo_th, log_form, hard, on, off):
    """One timescale: ``em`` (n,) moves toward ``intensity`` (n,) by ``a``; the ON / OFF events
    of the ratio ``intensity / em`` (its ``bk`` power, or ``bk`` log) into ``on`` and ``off``."""
    if not log_form and bk == ONE and not hard:
        # The paper's default (ratio form, beta 1, soft): the hot loop.
        for i in range(intensity.shape[0]):
            e = ema_step(em[i], a, intensity[i])
            em[i] = e
            on[i], off[i] = threshold(intensity[i] / e, hi_th, lo_th, False, ZERO)
        return
    for i in range(intensity.shape[0]):
        e = ema_step(em[i], a, intensity[i])
        em[i] = e
        ratio = intensity[i] / e
        if log_form:
            r = bk * np.log(ratio)
        elif bk == ONE:
            r = ratio
        else:
            r = ratio**bk
        on[i], off[i] = threshold(r, hi_th, lo_th, hard, ZERO)


@njit(inline="always")
def _ema_log_sum(em, intensity, a, bk, acc):
    """One timescale of a summed response: ``em`` moves on; ``acc += bk * log(intensity / em)``."""
    for i in range(intensity.shape[0]):
        e = ema_step(em[i], a, intensity[i])
        em[i] = e
        acc[i] += bk * np.log(intensity[i] / e)


@njit(inline="always")
def _sum_events(acc, hi_th, lo_th, log_form, hard, on, off):
    """The events of a summed log response ``acc`` (its exp unless ``log_form``)."""
    for i in range(acc.shape[0]):
        r = acc[i] if log_form else np.exp(acc[i])
        on[i], off[i] = threshold(r, hi_th, lo_th, hard, ZERO)


@njit(parallel=True, cache=True)
def gray_diff_kernel(x, scale, out):
    """Consecutive differences of luma, ``out[:, t] = scale * (gray(x[:, t+1]) - gray(x[:, t]))``.

    x   (B, T, C_in, P) uint8 or float32, C_in 1 or 3
    out (B, T-1, 1, P) float32
    """
    n_batch, n_frames, n_in, n_pix = x.shape
    gray = n_in == 3
    n_chunks = (n_pix + INFERENCE_CHUNK - 1) // INFERENCE_CHUNK
    for job in prange(n_batch * n_chunks):
        b, lo, n = _chunk(job, n_chunks, n_pix)
        prev = np.empty(n, np.float32)
        cur = np.empty(n, np.float32)
        load_intensity(x, b, 0, 0, lo, gray, 0, LUMA, ZERO, prev)
        for t in range(1, n_frames):
            load_intensity(x, b, t, 0, lo, gray, 0, LUMA, ZERO, cur)
            o = out[b, t - 1, 0, lo : lo + n]
            for i in range(n):
                o[i] = scale * (cur[i] - prev[i])
                prev[i] = cur[i]
