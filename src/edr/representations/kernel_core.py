"""EDR's per-pixel arithmetic, written once for every numba kernel: the intensity a pixel feeds
EDR, the EMA's step and the events of a response. The inference kernels
(:mod:`edr.representations.kernels`) and the training kernels
(:mod:`edr.representations.edr_grad`) both take them from here; the torch path in ``edr.py``
stays the readable reference that both are tested against.

They are ``inline="always"`` helpers: numba copies each into its caller, which compiles it with
its own flags (the training kernels' ``fastmath``), so the same source keeps each kernel's
results. They compute in the dtype of what they are given: float32 for inference, the training
path's compute dtype (float32 or float64) there.

numba's disk cache (``cache=True``) checks only the file of the kernel itself: after editing this
module, delete ``representations/__pycache__/*.nbi`` and ``*.nbc``, or the kernels run the old
helpers.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from edr.representations.base import GRAY_WEIGHTS

# Pixels one job of a kernel walks through the clip together, frame after frame. Inference
# carries only its chunk's EMA state, (K, n): 16 KiB of float32 per timescale at 4096 pixels,
# which stays in L1/L2 for the whole clip. The training backward recomputes and holds its
# chunk's EMAs for every frame, (T, K, n): at 1024 pixels that is 128 KiB per timescale for 32
# frames, kept in L2 (4 KiB rows stream from memory); the training forward shares its job
# layout. The backward's partial sums of the parameters' gradients are per job: another
# training chunk changes their last bits.
INFERENCE_CHUNK = 4096
TRAINING_CHUNK = 1024

LUMA = np.array(GRAY_WEIGHTS, np.float32)  # inference's luma weights, in its float32


@njit(inline="always")
def load_intensity(x, b, t, c, lo, gray, interleaved, weights, eps, dst):
    """dst (n,) = the intensity of channel c of frame t of row b (the luma of the three channels
    by ``weights`` (3,), when ``gray``) at pixels lo..lo+n, + eps.

    x is (B, T, C, P) planar, or (B, T, 1, P * C) with ``interleaved`` = C channels per pixel
    (0: planar); uint8 or float, read as it comes (converting the video first cost as much as
    a kernel's own work). The arithmetic is in the dtype of ``weights`` and ``eps`` (numba
    widens uint8 and float32 pixels to it).
    """
    n = dst.shape[0]
    if interleaved:
        # Flat indexing: numba's 2-D indexing of (P, C) was 5x slower here.
        px = x[b, t, 0, interleaved * lo : interleaved * (lo + n)]
        if gray:
            for i in range(n):
                dst[i] = (
                    weights[0] * px[3 * i] + weights[1] * px[3 * i + 1] + weights[2] * px[3 * i + 2]
                ) + eps
        else:
            for i in range(n):
                dst[i] = px[interleaved * i + c] + eps
    elif gray:
        red, green, blue = x[b, t, 0, lo : lo + n], x[b, t, 1, lo : lo + n], x[b, t, 2, lo : lo + n]
        for i in range(n):
            dst[i] = (weights[0] * red[i] + weights[1] * green[i] + weights[2] * blue[i]) + eps
    else:
        src = x[b, t, c, lo : lo + n]
        for i in range(n):
            dst[i] = src[i] + eps


@njit(inline="always")
def ema_step(prev, a, now):
    """The EMA's one step, e(t) = e(t-1) + a (I(t) - e(t-1)): inference, the training forward
    and the backward's recomputation of it all take it from here."""
    return prev + a * (now - prev)


@njit(inline="always")
def threshold(r, on_th, off_th, hard, zero):
    """The (ON, OFF) events of a response r: r - on_th above on_th and off_th - r below off_th
    (soft), or 1 there (hard); ``zero`` is 0 in the events' dtype."""
    if hard:
        one = zero + np.float32(1.0)  # zero's own dtype
        return (one if r > on_th else zero), (one if r < off_th else zero)
    return (r - on_th if r > on_th else zero), (off_th - r if r < off_th else zero)
