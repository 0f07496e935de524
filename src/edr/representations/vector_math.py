"""ln and exp over a chunk of float32 values, written so that LLVM vectorises the loop.

numba compiles ``np.log`` and ``np.exp`` in a loop to one scalar libm call per element (its
vectorised SVML calls need an SVML-patched llvmlite, which the PyPI wheels are not). The
training kernels of :mod:`edr.representations.edr_grad` take a logarithm, and once beta has
moved off 1 an exponential, of every pixel of every frame; as scalar calls those took longer
than the rest of the kernels together. Here both are bit arithmetic and a short polynomial
(float32: within 2.5e-7 relative of the float64 result); float64 arrays, which the gradient
tests use, go through ``np.log`` and ``np.exp``.

Both functions are ``inline="always"`` helpers for other numba kernels; ``out`` may be ``x``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

LN2 = np.float32(0.6931472)
LN2_HI, LN2_LO = np.float32(0.693359375), np.float32(-2.12194440e-4)  # LN2_HI exact in 10 bits
LOG2E = np.float32(1.4426950)
SQRT2 = np.float32(1.4142135)
EXP_MAX, EXP_MIN = np.float32(88.0), np.float32(-87.0)  # 2^n stays a normal float32


@njit(inline="always")
def log_into(x, out):
    """out = ln(x), x (n,) positive and finite, contiguous. float32: x = 2^e m with m in
    [sqrt(2)/2, sqrt(2)), ln x = e ln 2 + 2 atanh(s), s = (m - 1) / (m + 1), by its series."""
    if x.itemsize == 8:
        for j in range(x.shape[0]):
            out[j] = np.log(x[j])
        return
    one, two = np.float32(1), np.float32(2)
    bits, mantissa = x.view(np.int32), out.view(np.int32)
    for j in range(x.shape[0]):  # the exponent first: out may be x
        exponent = np.float32((bits[j] >> 23) - 127)
        mantissa[j] = (bits[j] & 0x007FFFFF) | 0x3F800000  # out[j] = m in [1, 2)
        m = out[j]
        big = m > SQRT2
        m, exponent = (m / two, exponent + one) if big else (m, exponent)
        s = (m - one) / (m + one)  # |s| < 0.172: four terms leave < 1e-9
        z = s * s
        odd = z * (np.float32(1 / 5) + z * (np.float32(1 / 7) + z * np.float32(1 / 9)))
        out[j] = exponent * LN2 + two * s * (one + z * (np.float32(1 / 3) + odd))


@njit(inline="always")
def exp_into(x, out, scale):
    """out = exp(x), x (n,) finite, contiguous; ``scale`` (n,) float32 scratch. float32:
    exp x = 2^n exp(g), n = round(x / ln 2), g = x - n ln 2 in [-0.35, 0.35] by its Taylor
    series to g^7 (< 6e-9); x is clamped to [-87, 88], where 2^n is a normal float32."""
    if x.itemsize == 8:
        for j in range(x.shape[0]):
            out[j] = np.exp(x[j])
        return
    one, half = np.float32(1), np.float32(0.5)
    power = scale.view(np.int32)
    for j in range(x.shape[0]):
        v = min(max(x[j], EXP_MIN), EXP_MAX)
        n = np.floor(v * LOG2E + half)
        g = (v - n * LN2_HI) - n * LN2_LO
        power[j] = (np.int32(n) + 127) << 23  # scale[j] = 2^n
        taylor = one + g * (one + g * (half + g * (np.float32(1 / 6) + g * (
            np.float32(1 / 24) + g * (np.float32(1 / 120) + g * (
                np.float32(1 / 720) + g * np.float32(1 / 5040)))))))  # fmt: skip
        out[j] = taylor * scale[j]
