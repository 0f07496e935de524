"""EDR's training path on the CPU: forward and backward as fused numba kernels.

:class:`FusedEDRFunction` is a ``torch.autograd.Function`` over intensities (already offset by
``eps`` and, for ``color="gray"``, converted to luma by torch, which differentiates that part).
Its forward runs every pixel's EMAs and events in one pass and keeps the EMAs (B, T, C, K, P);
its backward is one reverse-time scan per pixel that returns the gradients of the intensities
(so EDR can sit after a learned layer) and of alpha, beta and the two thresholds, from which
autograd reaches ``log_tau`` and the ``nu``s.

The recurrence, per pixel and timescale k (``e(-1) = I(0)``, so ``e(0) = I(0)``):
``e(t) = e(t-1) + a_k (I(t) - e(t-1))``; back in time the EMA's gradient ``g_e(t)`` collects
what the events at t sent it and ``(1 - a_k) g_e(t+1)``, and gives ``a_k g_e(t)`` to ``I(t)``
and ``g_e(t) (I(t) - e(t-1))`` to ``a_k``. A hard threshold's 0/1 events take the soft one's
gradient as their surrogate (``d ON / d r = [r > on]``, ``d OFF / d r = -[r < off]``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch
from numba import njit, prange

from edr.representations import kernels

CHUNK = 256  # pixels a job runs through time together (vectorised across them)


@njit(inline="always")
def _job(job, channels, n_chunks, pixels):
    b = job // (channels * n_chunks)
    c = (job // n_chunks) % channels
    lo = (job % n_chunks) * CHUNK
    return b, c, lo, min(pixels, lo + CHUNK)


@njit(inline="always")
def _events(r, on_th, off_th, hard):
    """(ON, OFF) of a response ``r``."""
    if hard:
        return (1.0 if r > on_th else 0.0), (1.0 if r < off_th else 0.0)
    return max(r - on_th, 0.0), max(off_th - r, 0.0)


@njit(parallel=True, cache=True)
def forward_kernel(intensity, alpha, beta, on_th, off_th, log_form, hard, sum_k, ema, out):
    """intensity (B, T, C, P) -> ema (B, T, C, K, P) and events out (B, T, C, K', 2, P)."""
    n_b, n_t, n_c, n_p = intensity.shape
    n_k = alpha.shape[0]
    n_chunks = (n_p + CHUNK - 1) // CHUNK
    for job in prange(n_b * n_c * n_chunks):
        b, c, lo, hi = _job(job, n_c, n_chunks, n_p)
        for t in range(n_t):
            for k in range(n_k):
                a = alpha[k]
                for p in range(lo, hi):
                    prev = intensity[b, 0, c, p] if t == 0 else ema[b, t - 1, c, k, p]
                    ema[b, t, c, k, p] = prev + a * (intensity[b, t, c, p] - prev)
            if sum_k:
                for p in range(lo, hi):
                    s = 0.0
                    for k in range(n_k):
                        s += beta[k] * math.log(intensity[b, t, c, p] / ema[b, t, c, k, p])
                    r = s if log_form else math.exp(s)
                    out[b, t, c, 0, 0, p], out[b, t, c, 0, 1, p] = _events(
                        r, on_th[0], off_th[0], hard
                    )
            else:
                for k in range(n_k):
                    for p in range(lo, hi):
                        log_ratio = math.log(intensity[b, t, c, p] / ema[b, t, c, k, p])
                        r = beta[k] * log_ratio if log_form else math.exp(beta[k] * log_ratio)
                        out[b, t, c, k, 0, p], out[b, t, c, k, 1, p] = _events(
                            r, on_th[k], off_th[k], hard
                        )


@njit(inline="always")
def _response_grad(r, g_on, g_off, on_th, off_th):
    """d loss / d r from the events' gradients, and the thresholds' (surrogate for hard)."""
    g_r, g_on_th, g_off_th = 0.0, 0.0, 0.0
    if r > on_th:
        g_r += g_on
        g_on_th -= g_on
    if r < off_th:
        g_r -= g_off
        g_off_th += g_off
    return g_r, g_on_th, g_off_th


@njit(parallel=True, cache=True)
def backward_kernel(intensity, ema, alpha, beta, on_th, off_th, log_form, sum_k, grad_out,
                    grad_in, g_alpha, g_beta, g_on, g_off):  # fmt: skip
    """One reverse-time scan per pixel: grad_in (B, T, C, P), and per job the partial sums of
    the parameters' gradients g_alpha, g_beta (jobs, K), g_on, g_off (jobs, K')."""
    n_b, n_t, n_c, n_p = intensity.shape
    n_k = alpha.shape[0]
    n_chunks = (n_p + CHUNK - 1) // CHUNK
    for job in prange(n_b * n_c * n_chunks):
        b, c, lo, hi = _job(job, n_c, n_chunks, n_p)
        carry = np.zeros((n_k, hi - lo), intensity.dtype)  # g_e(t+1) (1 - a): to e(t)
        g_e = np.zeros(n_k, intensity.dtype)
        for t in range(n_t - 1, -1, -1):
            for j in range(hi - lo):
                p = lo + j
                i = intensity[b, t, c, p]
                g_i = 0.0
                if sum_k:
                    s = 0.0
                    for k in range(n_k):
                        s += beta[k] * math.log(i / ema[b, t, c, k, p])
                    r = s if log_form else math.exp(s)
                    g_r, d_on, d_off = _response_grad(
                        r, grad_out[b, t, c, 0, 0, p], grad_out[b, t, c, 0, 1, p], on_th[0],
                        off_th[0],
                    )  # fmt: skip
                    g_on[job, 0] += d_on
                    g_off[job, 0] += d_off
                    g_s = g_r if log_form else g_r * r
                    for k in range(n_k):
                        e = ema[b, t, c, k, p]
                        g_beta[job, k] += g_s * math.log(i / e)
                        g_i += g_s * beta[k] / i
                        g_e[k] = -g_s * beta[k] / e
                else:
                    for k in range(n_k):
                        e = ema[b, t, c, k, p]
                        log_ratio = math.log(i / e)
                        r = beta[k] * log_ratio if log_form else math.exp(beta[k] * log_ratio)
                        g_r, d_on, d_off = _response_grad(
                            r, grad_out[b, t, c, k, 0, p], grad_out[b, t, c, k, 1, p], on_th[k],
                            off_th[k],
                        )  # fmt: skip
                        g_on[job, k] += d_on
                        g_off[job, k] += d_off
                        g_x = g_r if log_form else g_r * r  # d loss / d (beta ln(I / e))
                        g_beta[job, k] += g_x * log_ratio
                        g_i += g_x * beta[k] / i
                        g_e[k] = -g_x * beta[k] / e
                for k in range(n_k):
                    total = g_e[k] + carry[k, j]
                    if t > 0:
                        g_alpha[job, k] += total * (i - ema[b, t - 1, c, k, p])
                        g_i += total * alpha[k]
                        carry[k, j] = total * (1.0 - alpha[k])
                    else:  # e(0) = I(0)
                        g_i += total
                grad_in[b, t, c, p] = g_i


class FusedEDRFunction(torch.autograd.Function):
    """(intensity (B, T, C, P), alpha (K,), beta (K,), on_th (K',), off_th (K',)) ->
    events (B, T, C, K', 2, P); float32 or float64, CPU, contiguous."""

    @staticmethod
    def forward(ctx: Any, intensity, alpha, beta, on_th, off_th, log_form: bool, hard: bool,
                sum_k: bool) -> torch.Tensor:  # fmt: skip
        b, t, c, p = intensity.shape
        k, k_out = alpha.shape[0], on_th.shape[0]
        ema = intensity.new_empty((b, t, c, k, p))
        out = intensity.new_empty((b, t, c, k_out, 2, p))
        params = [v.detach().contiguous().numpy() for v in (alpha, beta, on_th, off_th)]
        kernels.launch(forward_kernel, b * t * p * c, intensity.detach().numpy(), *params,
                       log_form, hard, sum_k, ema.numpy(), out.numpy())  # fmt: skip
        ctx.save_for_backward(intensity, ema, alpha, beta, on_th, off_th)
        ctx.flags = (log_form, sum_k)
        return out

    @staticmethod
    def backward(ctx: Any, grad_out: torch.Tensor):
        intensity, ema, alpha, beta, on_th, off_th = ctx.saved_tensors
        log_form, sum_k = ctx.flags
        b, t, c, p = intensity.shape
        jobs = b * c * ((p + CHUNK - 1) // CHUNK)
        dtype = intensity.dtype
        grad_in = torch.empty_like(intensity)
        g_alpha, g_beta = (torch.zeros((jobs, alpha.shape[0]), dtype=dtype) for _ in range(2))
        g_on, g_off = (torch.zeros((jobs, on_th.shape[0]), dtype=dtype) for _ in range(2))
        params = [v.detach().to(dtype).contiguous().numpy() for v in (alpha, beta, on_th, off_th)]
        kernels.launch(
            backward_kernel, b * t * p * c, intensity.detach().numpy(), ema.numpy(), *params,
            log_form, sum_k, grad_out.to(dtype).contiguous().numpy(), grad_in.numpy(),
            g_alpha.numpy(), g_beta.numpy(), g_on.numpy(), g_off.numpy(),
        )  # fmt: skip
        sums = [g.sum(0).to(v.dtype) for g, v in zip((g_alpha, g_beta, g_on, g_off),
                                                      (alpha, beta, on_th, off_th), strict=True)]  # fmt: skip
        return (grad_in, *sums, None, None, None)


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
) -> torch.Tensor:
    """Differentiable EDR events of intensities (B, T, C, H, W) (offset by eps) ->
    (B, T, C * K' * 2, H, W), channels ordered as :class:`EDR`'s (channel, timescale, ON/OFF)."""
    b, t, c, h, w = intensity.shape
    dtype = intensity.dtype
    out = FusedEDRFunction.apply(
        intensity.contiguous().view(b, t, c, h * w), alpha.to(dtype), beta.to(dtype),
        on_th.to(dtype), off_th.to(dtype), log_form, hard, sum_k,
    )  # fmt: skip
    return out.view(b, t, -1, h, w)
