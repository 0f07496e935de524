"""A float64 NumPy transcription of the paper's Eq. 1-3, written apart from the library code."""

from __future__ import annotations

import numpy as np


def edr_reference(
    frames: np.ndarray,
    half_lives: list[float],
    beta: list[float],
    nu_on: list[float],
    nu_off: list[float],
    threshold: str,
    return_form: str,
    combine: str,
    eps: float,
    color: str,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """frames (B, T, C, H, W) -> (events (B, T, C'*2*K', H, W), response, (on_th, off_th)).

    ``response`` (B, T, C', K', H, W) is what gets thresholded, for tests that skip ties.
    """
    x = frames.astype(np.float64)
    if color == "gray" and x.shape[2] == 3:
        x = 0.299 * x[:, :, 0:1] + 0.587 * x[:, :, 1:2] + 0.114 * x[:, :, 2:3]
    intensity = x + eps  # (B, T, C, H, W)
    n_b, n_t, n_c, h, w = intensity.shape
    k = len(half_lives)
    alpha = np.array([1 - 2 ** (-1 / tau) for tau in half_lives])
    beta = np.array(beta, dtype=np.float64)
    events = []
    responses = []
    ema = np.empty((n_b, n_c, k, h, w))
    for t in range(n_t):
        i_t = intensity[:, t]  # (B, C, H, W)
        for j in range(k):
            if t == 0:
                ema[:, :, j] = i_t
            else:
                ema[:, :, j] = ema[:, :, j] + alpha[j] * (i_t - ema[:, :, j])
        ratio = i_t[:, :, None] / ema  # (B, C, K, H, W)
        if combine == "sum":
            log_sum = np.sum(beta[None, None, :, None, None] * np.log(ratio), axis=2, keepdims=True)
            response = log_sum if return_form == "log" else np.exp(log_sum)
        elif return_form == "log":
            response = beta[None, None, :, None, None] * np.log(ratio)
        else:
            response = ratio ** beta[None, None, :, None, None]
        on_th = 1 + np.array(nu_on)
        off_th = 1 - np.array(nu_off)
        if return_form == "log":
            on_th, off_th = np.log(on_th), np.log(off_th)
        on_th_b = on_th[None, None, :, None, None]
        off_th_b = off_th[None, None, :, None, None]
        if threshold == "hard":
            on = (response > on_th_b).astype(np.float64)
            off = (response < off_th_b).astype(np.float64)
        else:
            on = np.maximum(response - on_th_b, 0)
            off = np.maximum(off_th_b - response, 0)
        pairs = np.stack([on, off], axis=3)  # (B, C, K', 2, H, W)
        events.append(pairs.reshape(n_b, -1, h, w))
        responses.append(response)
    return np.stack(events, axis=1), np.stack(responses, axis=1), (on_th, off_th)
