"""EDR's training path on the CPU: forward and backward as fused numba kernels.

:class:`FusedEDRFunction` is a ``torch.autograd.Function`` over intensities (already offset by
``eps`` and, for ``color="gray"``, converted to luma by torch, which differentiates that part).
Its forward runs every pixel's EMAs and events in one pass and keeps the events alone; its
backward recomputes a chunk's EMAs (cheap, and they stay in cache), then runs one reverse-time
scan per pixel that returns the gradients of the intensities
(so EDR can sit after a learned layer) and of alpha, beta and the two thresholds, from which
autograd reaches ``log_tau`` and the ``nu``s.

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

CHUNK = 256  # pixels a job runs through time together (vectorised across them)


@njit(parallel=True, cache=True)
def intensity_kernel(x, gray, eps, out):
    """x (B, T, C, P) uint8 or float -> out (B, T, C', P) = luma (``gray``) or x, + eps."""
    n_b, n_t, _, n_p = x.shape
    w_r, w_g, w_b = GRAY_WEIGHTS
    for bt in prange(n_b * n_t):
        b, t = bt // n_t, bt % n_t
        for c in range(out.shape[2]):
            dst = out[b, t, c]
            if gray:
                for p in range(n_p):
                    dst[p] = w_r * x[b, t, 0, p] + w_g * x[b, t, 1, p] + w_b * x[b, t, 2, p] + eps
            else:
                for p in range(n_p):
                    dst[p] = x[b, t, c, p] + eps


def intensities(frames: torch.Tensor, gray: bool, eps: float, dtype: torch.dtype) -> torch.Tensor:
    """(B, T, C, H, W) frames that need no gradient -> (B, T, C', H, W) intensities + eps in
    ``dtype`` (luma when ``gray``), in one pass (torch's conversion of uint8 video took longer
    than the EDR kernels themselves)."""
    b, t, c, h, w = frames.shape
    out = torch.empty((b, t, 1 if gray else c, h, w), dtype=dtype)
    x = frames.contiguous().view(b, t, c, h * w)
    kernels.launch(intensity_kernel, b * t * h * w, x.numpy(), gray, dtype_eps(eps, dtype),
                   out.view(b, t, -1, h * w).numpy())  # fmt: skip
    return out


def dtype_eps(eps: float, dtype: torch.dtype) -> np.floating:
    return np.float64(eps) if dtype == torch.float64 else np.float32(eps)


@njit(inline="always")
def _job(job, channels, n_chunks, pixels):
    b = job // (channels * n_chunks)
    c = (job // n_chunks) % channels
    lo = (job % n_chunks) * CHUNK
    return b, c, lo, min(pixels, lo + CHUNK)


# The kernels loop over a chunk's contiguous pixels innermost, in the intensities' own dtype,
# branch-free where they can: LLVM vectorises them (fastmath lets it reorder the sums).


@njit(parallel=True, cache=True, fastmath=True)
def forward_kernel(intensity, alpha, beta, on_th, off_th, log_form, hard, sum_k, out):
    """intensity (B, T, C, P) -> events out (B, T, C, K', 2, P). The EMAs live in a chunk's
    state (K, CHUNK) only, as in inference: the backward recomputes them (:func:`ema_chunk`)."""
    n_b, n_t, n_c, n_p = intensity.shape
    n_k = alpha.shape[0]
    n_chunks = (n_p + CHUNK - 1) // CHUNK
    for job in prange(n_b * n_c * n_chunks):
        b, c, lo, hi = _job(job, n_c, n_chunks, n_p)
        zero = intensity[b, 0, c, lo] * 0
        acc = np.empty(hi - lo, intensity.dtype)
        state = np.empty((n_k, hi - lo), intensity.dtype)  # e_k(t - 1); e(-1) = I(0)
        for k in range(n_k):
            state[k] = intensity[b, 0, c, lo:hi]
        for t in range(n_t):
            now = intensity[b, t, c, lo:hi]
            acc[:] = zero
            for k in range(n_k):
                cur = state[k]
                a, bk = alpha[k], beta[k]
                on, off = (
                    out[b, t, c, k % out.shape[3], 0, lo:hi],
                    out[b, t, c, k % out.shape[3], 1, lo:hi],
                )
                plain = not (sum_k or log_form) and bk == 1  # r = I / e: no log, no exp
                for j in range(hi - lo):
                    e = cur[j] + a * (now[j] - cur[j])
                    cur[j] = e
                    if plain:
                        r = now[j] / e
                    else:
                        x = bk * np.log(now[j] / e)
                        if sum_k:
                            acc[j] += x
                            continue
                        r = x if log_form else np.exp(x)
                    on[j] = one_if(r > on_th[k], zero) if hard else max(r - on_th[k], zero)
                    off[j] = one_if(r < off_th[k], zero) if hard else max(off_th[k] - r, zero)
            if sum_k:
                on, off = out[b, t, c, 0, 0, lo:hi], out[b, t, c, 0, 1, lo:hi]
                for j in range(hi - lo):
                    r = acc[j] if log_form else np.exp(acc[j])
                    on[j] = one_if(r > on_th[0], zero) if hard else max(r - on_th[0], zero)
                    off[j] = one_if(r < off_th[0], zero) if hard else max(off_th[0] - r, zero)


@njit(inline="always")
def ema_chunk(intensity, alpha, b, c, lo, hi):
    """The EMAs of one chunk's pixels through the clip, (T, K, n): recomputed by the backward
    (T x CHUNK values a timescale stay in cache) instead of stored by the forward."""
    n_t, n_k = intensity.shape[1], alpha.shape[0]
    ema = np.empty((n_t, n_k, hi - lo), intensity.dtype)
    for t in range(n_t):
        now = intensity[b, t, c, lo:hi]
        for k in range(n_k):
            prev = intensity[b, 0, c, lo:hi] if t == 0 else ema[t - 1, k]
            cur, a = ema[t, k], alpha[k]
            for j in range(hi - lo):
                cur[j] = prev[j] + a * (now[j] - prev[j])
    return ema


@njit(inline="always")
def one_if(condition, zero):
    return zero + 1 if condition else zero


@njit(inline="always")
def _fired(on, off, on_th, off_th, hard, log_form, i, e, bk):
    """Where an event fired: the response r and its log ratio ln(I / e). A soft event tells r
    itself; only a hard one makes r be computed again."""
    log_ratio = np.log(i / e)
    if hard:
        x = bk * log_ratio
        return (x if log_form else np.exp(x)), log_ratio
    return (on + on_th if on > 0 else off_th - off), log_ratio


@njit(parallel=True, cache=True, fastmath=True)
def backward_kernel(intensity, events, alpha, beta, on_th, off_th, log_form, hard, sum_k,
                    window, grad_out, grad_in, g_alpha, g_beta, g_on, g_off):  # fmt: skip
    """One reverse-time scan per pixel: grad_in (B, T, C, P), and per job the partial sums of
    the parameters' gradients g_alpha, g_beta (jobs, K), g_on, g_off (jobs, K'). Only where an
    event fired (``events``: the forward's output) does a response send a gradient, so
    logarithms are taken there alone. ``window`` > 0: the EMA's gradient does not cross from
    frame t to t - 1 where t is a multiple of it (truncated backpropagation through time, as if
    e(t - 1) were a constant)."""
    n_b, n_t, n_c, n_p = intensity.shape
    n_k = alpha.shape[0]
    n_chunks = (n_p + CHUNK - 1) // CHUNK
    for job in prange(n_b * n_c * n_chunks):
        b, c, lo, hi = _job(job, n_c, n_chunks, n_p)
        n = hi - lo
        zero = intensity[b, 0, c, lo] * 0
        ema = ema_chunk(intensity, alpha, b, c, lo, hi)  # (T, K, n)
        carry = np.zeros((n_k, n), intensity.dtype)  # g_e(t+1) (1 - a): what e(t) gets
        g_i = np.empty(n, intensity.dtype)
        g_x = np.empty(n, intensity.dtype)  # d loss / d (beta_k ln(I / e_k)), this t and k
        g_xe = np.empty(n, intensity.dtype)  # its part of d loss / d e_k: -g_x beta_k / e_k
        for t in range(n_t - 1, -1, -1):
            now = intensity[b, t, c, lo:hi]
            g_i[:] = zero
            cut = window > 0 and t % window == 0
            if sum_k:  # one response for every timescale: d loss / d (the summed log ratio)
                on_ev, off_ev = events[b, t, c, 0, 0, lo:hi], events[b, t, c, 0, 1, lo:hi]
                d_on, d_off = zero, zero
                for j in range(n):
                    g_x[j] = zero
                    if on_ev[j] != zero or off_ev[j] != zero:
                        x = zero
                        for k in range(n_k):
                            x += beta[k] * np.log(now[j] / ema[t, k, j])
                        r = x if log_form else np.exp(x)
                        g_on_out, g_off_out = (
                            grad_out[b, t, c, 0, 0, lo + j],
                            grad_out[b, t, c, 0, 1, lo + j],
                        )
                        above, below = r > on_th[0], r < off_th[0]
                        g_r = (g_on_out if above else zero) - (g_off_out if below else zero)
                        d_on -= g_on_out if above else zero
                        d_off += g_off_out if below else zero
                        g_x[j] = g_r if log_form else g_r * r
                g_on[job, 0] += d_on
                g_off[job, 0] += d_off
            for k in range(n_k):
                a, bk = alpha[k], beta[k]
                cur = ema[t, k]
                d_alpha, d_beta, d_on, d_off = zero, zero, zero, zero
                # Only where an event fired is g_x non-zero: the divisions are taken there alone.
                if not sum_k:
                    on_ev, off_ev = events[b, t, c, k, 0, lo:hi], events[b, t, c, k, 1, lo:hi]
                    for j in range(n):
                        g_xe[j] = zero
                        if on_ev[j] != zero or off_ev[j] != zero:
                            r, log_ratio = _fired(on_ev[j], off_ev[j], on_th[k], off_th[k], hard,
                                                  log_form, now[j], cur[j], bk)  # fmt: skip
                            g_on_out = grad_out[b, t, c, k, 0, lo + j]
                            g_off_out = grad_out[b, t, c, k, 1, lo + j]
                            above, below = on_ev[j] != zero, off_ev[j] != zero
                            g_r = (g_on_out if above else zero) - (g_off_out if below else zero)
                            d_on -= g_on_out if above else zero
                            d_off += g_off_out if below else zero
                            gx = g_r if log_form else g_r * r
                            d_beta += gx * log_ratio
                            g_i[j] += gx * bk / now[j]
                            g_xe[j] = gx * bk / cur[j]
                else:
                    for j in range(n):
                        g_xe[j] = zero
                        if g_x[j] != zero:
                            d_beta += g_x[j] * np.log(now[j] / cur[j])
                            g_i[j] += g_x[j] * bk / now[j]
                            g_xe[j] = g_x[j] * bk / cur[j]
                if t > 0:  # e(t) = e(t-1) + a (I(t) - e(t-1)): multiplies and adds only
                    prev = ema[t - 1, k]
                    keep = zero if cut else 1 - a
                    for j in range(n):
                        total = carry[k, j] - g_xe[j]
                        d_alpha += total * (now[j] - prev[j])
                        g_i[j] += total * a
                        carry[k, j] = total * keep
                else:  # e(0) = I(0)
                    for j in range(n):
                        g_i[j] += carry[k, j] - g_xe[j]
                g_alpha[job, k] += d_alpha
                g_beta[job, k] += d_beta
                if not sum_k:
                    g_on[job, k] += d_on
                    g_off[job, k] += d_off
            grad_in[b, t, c, lo:hi] = g_i


class FusedEDRFunction(torch.autograd.Function):
    """(intensity (B, T, C, P), alpha (K,), beta (K,), on_th (K',), off_th (K',)) ->
    events (B, T, C, K', 2, P); float32 or float64, CPU, contiguous."""

    @staticmethod
    def forward(ctx: Any, intensity, alpha, beta, on_th, off_th, log_form: bool, hard: bool,
                sum_k: bool, window: int = 0) -> torch.Tensor:  # fmt: skip
        b, t, c, p = intensity.shape
        k_out = on_th.shape[0]
        # on recycled memory, as inference's output: fresh tens of MB fault in page by page
        out = buffers.RECYCLED.empty((b, t, c, k_out, 2, p), intensity.dtype)
        params = [v.detach().contiguous().numpy() for v in (alpha, beta, on_th, off_th)]
        kernels.launch(forward_kernel, b * t * p * c, intensity.detach().numpy(), *params,
                       log_form, hard, sum_k, out.numpy())  # fmt: skip
        ctx.save_for_backward(intensity, out, alpha, beta, on_th, off_th)
        ctx.flags = (log_form, hard, sum_k, window)
        return out

    @staticmethod
    def backward(ctx: Any, grad_out: torch.Tensor):
        intensity, events, alpha, beta, on_th, off_th = ctx.saved_tensors
        log_form, hard, sum_k, window = ctx.flags
        b, t, c, p = intensity.shape
        jobs = b * c * ((p + CHUNK - 1) // CHUNK)
        dtype = intensity.dtype
        grad_in = buffers.RECYCLED.empty(tuple(intensity.shape), dtype)
        g_alpha, g_beta = (torch.zeros((jobs, alpha.shape[0]), dtype=dtype) for _ in range(2))
        g_on, g_off = (torch.zeros((jobs, on_th.shape[0]), dtype=dtype) for _ in range(2))
        params = [v.detach().to(dtype).contiguous().numpy() for v in (alpha, beta, on_th, off_th)]
        kernels.launch(
            backward_kernel, b * t * p * c, intensity.detach().numpy(), events.detach().numpy(), *params, log_form, hard, sum_k, window,
            grad_out.to(dtype).numpy(), grad_in.numpy(),  # as it comes: a sum's is one value
            g_alpha.numpy(), g_beta.numpy(), g_on.numpy(), g_off.numpy(),
        )  # fmt: skip
        sums = [g.sum(0).to(v.dtype) for g, v in zip((g_alpha, g_beta, g_on, g_off),
                                                      (alpha, beta, on_th, off_th), strict=True)]  # fmt: skip
        return (grad_in, *sums, None, None, None, None)


def fused_events(
    intensity: torch.Tensor,
    alpha: torch.Tensor,
    beta: torch.Tensor,
    on_th: torch.Tensor,
    off_th: torch.Tensor,
    *,
    log_form: bool,
    hard: bool,
    sum_k: bool,
    window: int = 0,
) -> torch.Tensor:
    """Differentiable EDR events of intensities (B, T, C, H, W) (offset by eps) ->
    (B, T, C * K' * 2, H, W), channels ordered as :class:`EDR`'s (channel, timescale, ON/OFF)."""
    b, t, c, h, w = intensity.shape
    dtype = intensity.dtype
    out = FusedEDRFunction.apply(
        intensity.contiguous().view(b, t, c, h * w), alpha.to(dtype), beta.to(dtype),
        on_th.to(dtype), off_th.to(dtype), log_form, hard, sum_k, window,
    )  # fmt: skip
    return out.view(b, t, -1, h, w)
