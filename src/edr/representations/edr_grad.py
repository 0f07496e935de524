"""EDR's training path on the CPU: forward and backward as fused numba kernels.

:class:`FusedEDRFunction` is a ``torch.autograd.Function`` over frames: video as it comes
(uint8 or float, converted to luma and offset by ``eps`` inside the kernels, as inference does),
or intensities that torch computed and needs the gradient of (EDR after a learned layer). Its
forward runs every pixel's EMAs and events in one pass and keeps nothing but its inputs;
its backward recomputes a chunk's EMAs and responses (cheap: they stay in cache, and the
events need not be read back from memory), then runs one reverse-time scan per pixel that
returns the gradients of the intensities, when they need one (so EDR can sit after a learned
layer), and of alpha, beta and the two thresholds, from which autograd reaches ``log_tau`` and
the ``nu``s. Both are memory-bound, with their logarithms and exponentials vectorised
(:mod:`edr.representations.vector_math`).

The recurrence, per pixel and timescale k (``e(-1) = I(0)``, so ``e(0) = I(0)``):
``e(t) = e(t-1) + a_k (I(t) - e(t-1))``; back in time the EMA's gradient ``g_e(t)`` collects
what the events at t sent it and ``(1 - a_k) g_e(t+1)``, and gives ``a_k g_e(t)`` to ``I(t)``
and ``g_e(t) (I(t) - e(t-1))`` to ``a_k``. A hard threshold's 0/1 events take the soft one's
gradient as their surrogate (``d ON / d r = [r > on]``, ``d OFF / d r = -[r < off]``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from numba import njit, prange

from edr.representations import buffers, kernels
from edr.representations.base import GRAY_WEIGHTS
from edr.representations.kernel_core import TRAINING_CHUNK, ema_step, load_intensity, threshold
from edr.representations.vector_math import exp_into, log_into


@njit(inline="always")
def _job(job, channels, n_chunks, pixels):
    b = job // (channels * n_chunks)
    c = (job // n_chunks) % channels
    lo = (job % n_chunks) * TRAINING_CHUNK
    return b, c, lo, min(pixels, lo + TRAINING_CHUNK)


# The kernels loop over a chunk's contiguous pixels innermost, in the compute dtype (weights'),
# branch-free (selects, loads first), so LLVM vectorises them; fastmath lets it reorder the sums.
# The forward and the backward compute a response with the same helpers, in the same order, so
# the backward finds the events where the forward fired them without reading them back.


@njit(inline="always")
def _ratios(now, prev, a, cur, ratio):
    """One EMA step of a timescale, cur (n,) = e(t) from prev = e(t - 1) (may be cur), and
    ratio (n,) = I(t) / e(t)."""
    for j in range(now.shape[0]):
        e = ema_step(prev[j], a, now[j])
        cur[j] = e
        ratio[j] = now[j] / e


@njit(inline="always")
def _response(ratio, x, plain, log_form, r, scratch):
    """The response of a ratio (n,) and x (n,) = beta ln(ratio) (or a sum of those over the
    timescales): ``ratio`` itself when ``plain`` (ratio form, beta 1: x is not needed), x in the
    log form, exp(x) (into r) in the ratio form."""
    if plain:
        return ratio
    if log_form:
        return x
    exp_into(x, r, scratch)
    return r


@njit(inline="always")
def _threshold_chunk(r, on_th, off_th, hard, zero, on, off):
    """ON and OFF events (n,) of a response r (n,), by :func:`threshold`."""
    if hard:  # two loops: a select on ``hard`` inside one kept LLVM from vectorising it
        for j in range(r.shape[0]):
            on[j], off[j] = threshold(r[j], on_th, off_th, True, zero)
        return
    for j in range(r.shape[0]):
        on[j], off[j] = threshold(r[j], on_th, off_th, False, zero)


@njit(parallel=True, cache=True, fastmath=True)
def forward_kernel(frames, gray, weights, eps, alpha, beta, on_th, off_th, log_form, hard, sum_k,
                   out):  # fmt: skip
    """frames (B, T, C_in, P) -> events out (B, T, C, K', 2, P), C = 1 (``gray``: the luma of
    three channels, by ``weights``) or C_in, computed in the dtype of ``weights``. The EMAs live
    in a chunk's state (K, TRAINING_CHUNK) only, as in inference: the backward recomputes them
    (:func:`ema_chunk`)."""
    n_b, n_t, n_c, _, _, n_p = out.shape
    n_k = alpha.shape[0]
    n_chunks = (n_p + TRAINING_CHUNK - 1) // TRAINING_CHUNK
    for job in prange(n_b * n_c * n_chunks):
        b, c, lo, hi = _job(job, n_c, n_chunks, n_p)
        zero = weights[0] * 0
        work = np.empty((6, hi - lo), weights.dtype)
        now, ratio, x, acc, r, scratch = work[0], work[1], work[2], work[3], work[4], work[5]
        state = np.empty((n_k, hi - lo), weights.dtype)  # e_k(t - 1); e(-1) = I(0)
        for t in range(n_t):
            load_intensity(frames, b, t, c, lo, gray, 0, weights, eps, now)
            if t == 0:
                for k in range(n_k):
                    state[k] = now
            acc[:] = zero
            for k in range(n_k):
                _ratios(now, state[k], alpha[k], state[k], ratio)
                plain = not (sum_k or log_form) and beta[k] == 1  # r = I / e: no log, no exp
                if not plain:  # x = beta ln(I / e)
                    log_into(ratio, x)
                    for j in range(hi - lo):
                        x[j] *= beta[k]
                if sum_k:
                    for j in range(hi - lo):
                        acc[j] += x[j]
                else:
                    resp = _response(ratio, x, plain, log_form, r, scratch)
                    _threshold_chunk(resp, on_th[k], off_th[k], hard, zero,
                                     out[b, t, c, k, 0, lo:hi], out[b, t, c, k, 1, lo:hi])  # fmt: skip
            if sum_k:
                resp = _response(ratio, acc, False, log_form, r, scratch)
                _threshold_chunk(resp, on_th[0], off_th[0], hard, zero,
                                 out[b, t, c, 0, 0, lo:hi], out[b, t, c, 0, 1, lo:hi])  # fmt: skip


@njit(inline="always")
def ema_chunk(frames, gray, weights, eps, alpha, b, c, lo, hi):
    """The EMAs of one chunk's pixels through the clip, (T, K, n): recomputed by the backward
    (they stay in cache) instead of stored by the forward. (Their ratios I / e are taken again
    frame by frame: a second (T, K, n) array fell out of cache on long clips.)"""
    n_t, n_k = frames.shape[1], alpha.shape[0]
    ema = np.empty((n_t, n_k, hi - lo), weights.dtype)
    now = np.empty(hi - lo, weights.dtype)
    for t in range(n_t):
        load_intensity(frames, b, t, c, lo, gray, 0, weights, eps, now)
        for k in range(n_k):
            prev = now if t == 0 else ema[t - 1, k]
            cur, a = ema[t, k], alpha[k]
            for j in range(hi - lo):
                cur[j] = ema_step(prev[j], a, now[j])
    return ema


@njit(parallel=True, cache=True, fastmath=True)
def backward_kernel(frames, gray, weights, eps, alpha, beta, on_th, off_th, log_form, sum_k,
                    window, grad_out, want_input, grad_in, g_alpha, g_beta, g_on, g_off):  # fmt: skip
    """One reverse-time scan per pixel: grad_in (B, T, C, P) (when ``want_input``), and per job
    the partial sums of the parameters' gradients g_alpha, g_beta (jobs, K), g_on, g_off
    (jobs, K'). A hard event takes the soft one's gradient as its surrogate, so the scan is the
    same for both. ``window`` > 0: the EMA's gradient does not cross from frame t to t - 1 where
    t is a multiple of it (truncated backpropagation through time, as if e(t - 1) were a
    constant)."""
    n_b, n_t, n_c, _, _, n_p = grad_out.shape
    n_k = alpha.shape[0]
    n_chunks = (n_p + TRAINING_CHUNK - 1) // TRAINING_CHUNK
    for job in prange(n_b * n_c * n_chunks):
        b, c, lo, hi = _job(job, n_c, n_chunks, n_p)
        n = hi - lo
        zero = weights[0] * 0
        ema = ema_chunk(frames, gray, weights, eps, alpha, b, c, lo, hi)  # (T, K, n)
        ratio = np.empty((n_k, n), weights.dtype)  # I / e_k at this t
        log_ratio = np.empty((n_k, n), weights.dtype)  # ln(I / e_k)
        carry = np.zeros((n_k, n), weights.dtype)  # g_e(t+1) (1 - a): what e(t) gets
        work = np.empty((7, n), weights.dtype)
        now, g_i, inv_now, g_x, x, r, scratch = (work[0], work[1], work[2], work[3], work[4],
                                                 work[5], work[6])  # fmt: skip
        for t in range(n_t - 1, -1, -1):
            load_intensity(frames, b, t, c, lo, gray, 0, weights, eps, now)
            for j in range(n):
                g_i[j] = zero
                inv_now[j] = 1 / now[j]
            if sum_k:
                x[:] = zero
            for k in range(n_k):
                for j in range(n):
                    ratio[k, j] = now[j] / ema[t, k, j]  # as the forward's _ratios
                log_into(ratio[k], log_ratio[k])
                if sum_k:
                    for j in range(n):
                        x[j] += beta[k] * log_ratio[k, j]
            cut = window > 0 and t % window == 0
            if sum_k:  # one response of every timescale: g_x = d loss / d (their summed x)
                resp = _response(ratio[0], x, False, log_form, r, scratch)
                d_on, d_off = _events_grad(resp, grad_out[b, t, c, 0, 0, lo:hi],
                                           grad_out[b, t, c, 0, 1, lo:hi], on_th[0], off_th[0],
                                           log_form, zero, g_x)  # fmt: skip
                g_on[job, 0] += d_on
                g_off[job, 0] += d_off
            for k in range(n_k):
                a, bk = alpha[k], beta[k]
                if not sum_k:  # g_x = d loss / d (beta_k ln(I / e_k))
                    for j in range(n):
                        x[j] = bk * log_ratio[k, j]
                    plain = not log_form and bk == 1
                    resp = _response(ratio[k], x, plain, log_form, r, scratch)
                    d_on, d_off = _events_grad(resp, grad_out[b, t, c, k, 0, lo:hi],
                                               grad_out[b, t, c, k, 1, lo:hi], on_th[k],
                                               off_th[k], log_form, zero, g_x)  # fmt: skip
                    g_on[job, k] += d_on
                    g_off[job, k] += d_off
                # x = beta ln(I / e): d x / d I = beta / I, d x / d e = -beta / e = -beta r / I;
                # e(t) = e(t-1) + a (I(t) - e(t-1)); e(0) = I(0): a gradient of 1 to I(0)
                prev = ema[t - 1, k] if t > 0 else now
                a_t = a if t > 0 else zero + 1
                keep = zero if cut else 1 - a
                d_alpha, d_beta = zero, zero
                for j in range(n):
                    g_xi = g_x[j] * bk * inv_now[j]
                    total = carry[k, j] - g_xi * ratio[k, j]
                    d_alpha += total * (now[j] - prev[j])
                    d_beta += g_x[j] * log_ratio[k, j]
                    g_i[j] += g_xi + total * a_t
                    carry[k, j] = total * keep
                g_alpha[job, k] += d_alpha
                g_beta[job, k] += d_beta
            if want_input:
                grad_in[b, t, c, lo:hi] = g_i


@njit(inline="always")
def _events_grad(r, g_on_out, g_off_out, on_th, off_th, log_form, zero, g_x):
    """g_x (n,) = d loss / d x of a response r (n,) (r = x, or exp(x) in the ratio form), from
    its events' gradients (n,): d ON / d r = [r > on_th], d OFF / d r = -[r < off_th] (a hard
    event's surrogate too); returns the thresholds' gradients."""
    d_on, d_off = zero, zero
    for j in range(r.shape[0]):
        rj, g_on_j, g_off_j = r[j], g_on_out[j], g_off_out[j]  # loads first, then selects
        g_on_j = g_on_j if rj > on_th else zero
        g_off_j = g_off_j if rj < off_th else zero
        d_on -= g_on_j
        d_off += g_off_j
        g_x[j] = (g_on_j - g_off_j) if log_form else (g_on_j - g_off_j) * rj
    return d_on, d_off


class FusedEDRFunction(torch.autograd.Function):
    """(frames (B, T, C_in, P), alpha (K,), beta (K,), on_th (K',), off_th (K',)) -> events
    (B, T, C, K', 2, P), in alpha's dtype (float32 or float64), CPU, contiguous. The frames
    (uint8 or float) become intensities inside the kernels: their luma when ``gray`` (C = 1),
    plus ``eps``. They get a gradient only as intensities already: float, ``gray`` off."""

    @staticmethod
    def forward(ctx: Any, frames, alpha, beta, on_th, off_th, log_form: bool, hard: bool,
                sum_k: bool, window: int = 0, gray: bool = False,
                eps: float = 0.0) -> torch.Tensor:  # fmt: skip
        b, t, c_in, p = frames.shape
        dtype, c = alpha.dtype, 1 if gray else c_in
        # on recycled memory, as inference's output: fresh tens of MB fault in page by page
        out = buffers.RECYCLED.empty((b, t, c, on_th.shape[0], 2, p), dtype)
        source = _source(frames, gray, eps, dtype)
        params = [v.detach().contiguous().numpy() for v in (alpha, beta, on_th, off_th)]
        kernels.launch(forward_kernel, b * t * p * c, *source, *params, log_form, hard, sum_k,
                       out.numpy())  # fmt: skip
        ctx.save_for_backward(frames, alpha, beta, on_th, off_th)
        ctx.flags = (log_form, sum_k, window, gray, eps)
        return out

    @staticmethod
    def backward(ctx: Any, grad_out: torch.Tensor):
        frames, alpha, beta, on_th, off_th = ctx.saved_tensors
        log_form, sum_k, window, gray, eps = ctx.flags
        b, t, c, _, _, p = grad_out.shape
        jobs = b * c * ((p + TRAINING_CHUNK - 1) // TRAINING_CHUNK)
        dtype = alpha.dtype
        want_input = ctx.needs_input_grad[0]  # frames straight from a video need none
        grad_in = buffers.RECYCLED.empty((b, t, c, p) if want_input else (1, 1, 1, 1), dtype)
        g_alpha, g_beta = (torch.zeros((jobs, alpha.shape[0]), dtype=dtype) for _ in range(2))
        g_on, g_off = (torch.zeros((jobs, on_th.shape[0]), dtype=dtype) for _ in range(2))
        params = [v.detach().contiguous().numpy() for v in (alpha, beta, on_th, off_th)]
        kernels.launch(
            backward_kernel, b * t * p * c, *_source(frames, gray, eps, dtype), *params,
            log_form, sum_k, window,
            grad_out.to(dtype).contiguous().numpy(),  # one layout, one compiled kernel
            want_input, grad_in.numpy(),
            g_alpha.numpy(), g_beta.numpy(), g_on.numpy(), g_off.numpy(),
        )  # fmt: skip
        sums = [g.sum(0).to(v.dtype) for g, v in zip((g_alpha, g_beta, g_on, g_off),
                                                      (alpha, beta, on_th, off_th), strict=True)]  # fmt: skip
        return (grad_in if want_input else None, *sums, None, None, None, None, None, None)


def _source(frames: torch.Tensor, gray: bool, eps: float, dtype: torch.dtype) -> tuple:
    """What the kernels read the intensities from: (frames, gray, luma weights, eps), the last
    two in the compute dtype."""
    np_dtype = np.float64 if dtype == torch.float64 else np.float32
    weights = np.array(GRAY_WEIGHTS, np_dtype)
    return frames.detach().numpy(), gray, weights, np_dtype(eps)


def fused_events(
    frames: torch.Tensor,
    alpha: torch.Tensor,
    beta: torch.Tensor,
    on_th: torch.Tensor,
    off_th: torch.Tensor,
    *,
    log_form: bool,
    hard: bool,
    sum_k: bool,
    window: int = 0,
    gray: bool = False,
    eps: float = 0.0,
    dtype: torch.dtype = torch.float32,
) -> torch.Tensor:
    """Differentiable EDR events of frames (B, T, C, H, W) (uint8 or float; their luma when
    ``gray``, + ``eps``) -> (B, T, C' * K' * 2, H, W) in ``dtype``, channels ordered as
    :class:`EDR`'s (channel, timescale, ON/OFF)."""
    b, t, c, h, w = frames.shape
    out = FusedEDRFunction.apply(
        frames.contiguous().view(b, t, c, h * w), alpha.to(dtype), beta.to(dtype),
        on_th.to(dtype), off_th.to(dtype), log_form, hard, sum_k, window, gray, eps,
    )  # fmt: skip
    return out.view(b, t, -1, h, w)
