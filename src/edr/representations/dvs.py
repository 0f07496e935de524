"""A simulated event camera (DVS), and event lists binned to frames.

Model (as in ESIM / v2e, simplified): each pixel memorizes a reference log intensity
``L_ref``. Between two frames the log intensity is interpolated linearly; every time it moves
one contrast threshold away from ``L_ref``, an event fires at the interpolated crossing time
and ``L_ref`` moves by one threshold (so a big change gives several events per frame).
Options: per-pixel threshold mismatch (Gaussian, relative sigma), a refractory period (events
closer than it to the pixel's last event are dropped; the reference still moves) and shot noise
(spurious events, Poisson in time, uniform over pixels and polarity).

Events are a structured array with fields ``t`` (microseconds, int64), ``x``, ``y`` (int16) and
``p`` (int8: 1 ON, 0 OFF), sorted by time — the field names tonic uses.
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit

from edr.representations.base import (
    Features,
    Representation,
    check_clip,
    on_off_picture,
    to_gray,
)

EVENT_DTYPE = np.dtype([("t", np.int64), ("x", np.int16), ("y", np.int16), ("p", np.int8)])


@njit(cache=True)
def _crossings(log_prev, log_next, ref, th_on, th_off, last_t, t_prev, dt, refractory):
    """Events of one frame interval, in pixel order; updates ``ref`` and ``last_t`` in place.

    log_prev, log_next, ref, th_on, th_off, last_t: (P,) float64. Returns (t, pixel, polarity).
    """
    n_pix = log_prev.shape[0]
    capacity = 0
    for i in range(n_pix):
        d = log_next[i] - ref[i]
        capacity += int(d / th_on[i]) if d > 0 else int(-d / th_off[i])
    times = np.empty(capacity, np.float64)
    pixels = np.empty(capacity, np.int64)
    polarity = np.empty(capacity, np.int8)
    n = 0
    for i in range(n_pix):
        lp, ln, r = log_prev[i], log_next[i], ref[i]
        up = ln > r
        th = th_on[i] if up else th_off[i]
        step = th if up else -th
        span = ln - lp
        while (ln - r >= th) if up else (r - ln >= th):
            r += step
            frac = (r - lp) / span if span != 0.0 else 1.0
            # Inside [t_prev, t_prev + dt) on the microsecond grid, so binning by frame is exact.
            t = min(t_prev + dt * max(frac, 0.0), t_prev + dt - 1.0)
            if t - last_t[i] >= refractory:
                times[n] = t
                pixels[n] = i
                polarity[n] = 1 if up else 0
                n += 1
                last_t[i] = t
        ref[i] = r
    return times[:n], pixels[:n], polarity[:n]


class DVSSimulator:
    """Turns gray frames into DVS events; one call simulates one recording from its first frame.

    ``threshold_on/off``: contrast thresholds in log intensity; ``mismatch``: relative sigma of
    their per-pixel spread; ``refractory_us``; ``shot_noise_hz``: spurious events per pixel and
    second; ``fps``: frame rate that sets the timestamps; ``eps``: offset so that I = 0 is legal.
    """

    def __init__(
        self,
        threshold_on: float = 0.2,
        threshold_off: float = 0.2,
        mismatch: float = 0.0,
        refractory_us: float = 0.0,
        shot_noise_hz: float = 0.0,
        fps: float = 25.0,
        eps: float = 1.0,
        seed: int = 0,
    ) -> None:
        if threshold_on <= 0 or threshold_off <= 0:
            raise ValueError("contrast thresholds must be positive")
        if min(mismatch, refractory_us, shot_noise_hz) < 0 or fps <= 0 or eps <= 0:
            raise ValueError("mismatch, refractory_us, shot_noise_hz must be >= 0; fps, eps > 0")
        self.threshold_on, self.threshold_off = threshold_on, threshold_off
        self.mismatch, self.refractory_us, self.shot_noise_hz = (
            mismatch,
            refractory_us,
            shot_noise_hz,
        )
        self.fps, self.eps, self.seed = fps, eps, seed

    @property
    def frame_us(self) -> float:
        return 1e6 / self.fps

    def simulate(self, frames: np.ndarray) -> np.ndarray:
        """(T, H, W) gray intensities (0..255) -> events (EVENT_DTYPE), sorted by ``t``."""
        frames = np.asarray(frames)
        if frames.ndim != 3 or frames.shape[0] < 1:
            raise ValueError(f"frames must be (T, H, W) with T >= 1, got {frames.shape}")
        t_count, h, w = frames.shape
        rng = np.random.default_rng(self.seed)
        logs = np.log(frames.reshape(t_count, h * w).astype(np.float64) + self.eps)  # (T, P)
        th_on, th_off = (
            np.maximum(th * (1.0 + self.mismatch * rng.standard_normal(h * w)), 0.01 * th)
            for th in (self.threshold_on, self.threshold_off)
        )
        ref = logs[0].copy()
        last_t = np.full(h * w, -np.inf)
        chunks = []
        for k in range(t_count - 1):
            t_prev = k * self.frame_us
            times, pixels, pol = _crossings(
                logs[k], logs[k + 1], ref, th_on, th_off, last_t, t_prev, self.frame_us,
                self.refractory_us,
            )  # fmt: skip
            chunks.append((times, pixels, pol))
            if self.shot_noise_hz > 0:
                n_noise = rng.poisson(self.shot_noise_hz * self.frame_us * 1e-6 * h * w)
                chunks.append(
                    (
                        t_prev + self.frame_us * rng.random(n_noise),
                        rng.integers(0, h * w, n_noise),
                        rng.integers(0, 2, n_noise).astype(np.int8),
                    )
                )
        if not chunks:
            return np.zeros(0, EVENT_DTYPE)
        times, pixels, pol = (np.concatenate(parts) for parts in zip(*chunks, strict=True))
        order = np.argsort(times, kind="stable")
        events = np.empty(len(order), EVENT_DTYPE)
        events["t"] = np.floor(times[order]).astype(np.int64)
        events["x"] = pixels[order] % w
        events["y"] = pixels[order] // w
        events["p"] = pol[order]
        return events


def events_to_frames(
    events: np.ndarray,
    height: int,
    width: int,
    *,
    time_window: float | None = None,
    n_time_bins: int | None = None,
    event_count: int | None = None,
    t_start: float | None = None,
    t_end: float | None = None,
) -> np.ndarray:
    """Bin events to count frames (N, 2, H, W) float32, channel = polarity (0 OFF, 1 ON).

    Like ``tonic.transforms.ToFrame``: exactly one of ``time_window`` (microseconds per frame),
    ``n_time_bins`` (equal slices of [t_start, t_end)) or ``event_count`` (events per frame).
    ``t_start``/``t_end`` default to the first event and one past the last.
    """
    if sum(v is not None for v in (time_window, n_time_bins, event_count)) != 1:
        raise ValueError("give exactly one of time_window, n_time_bins, event_count")
    if len(events) and (events["x"].max() >= width or events["y"].max() >= height):
        raise ValueError(f"events fall outside the {width}x{height} sensor")
    if event_count is not None:
        n_frames = max(1, -(-len(events) // event_count))
        index = np.arange(len(events)) // event_count
    else:
        start = t_start if t_start is not None else float(events["t"][0]) if len(events) else 0.0
        end = t_end if t_end is not None else float(events["t"][-1]) + 1 if len(events) else 1.0
        if end <= start:
            raise ValueError(f"empty time range [{start}, {end})")
        if n_time_bins is not None:
            n_frames, window = n_time_bins, (end - start) / n_time_bins
        else:
            window = float(time_window)
            n_frames = max(1, int(np.ceil((end - start) / window)))
        index = np.floor((events["t"] - start) / window).astype(np.int64)
    frames = np.zeros((n_frames, 2, height, width), np.float32)
    keep = (index >= 0) & (index < n_frames)
    e = events[keep]
    np.add.at(frames, (index[keep], e["p"].astype(np.int64), e["y"], e["x"]), 1.0)
    return frames


class DVSCamera(Representation):
    """Event frames of a simulated DVS: (B, T, C, H, W) -> (B, T-1, 2, H, W), [ON, OFF] counts.

    One frame per interval between two video frames; the channel order matches EDR's so a
    network trained on EDR can take event-camera input directly (the paper's Appendix A).
    """

    features = Features(
        "every past frame (a per-pixel reference)", "no", "yes (contrast threshold)",
        "yes", "no", "no",
    )  # fmt: skip

    precompute = True

    def __init__(self, **simulator: float) -> None:
        super().__init__()
        self.simulator = DVSSimulator(**simulator)

    def out_channels(self, in_channels: int) -> int:
        return 2

    def out_frames(self, frames: int) -> int:
        return frames - 1

    def preview(self, out_t: torch.Tensor) -> np.ndarray:
        counts = out_t.detach().float().cpu().numpy()
        return on_off_picture(counts[0], counts[1])

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        check_clip(frames, min_frames=2, name="frames")
        gray = to_gray(frames.detach().cpu(), channel_dim=2)[:, :, 0].numpy()  # (B, T, H, W)
        b, t, h, w = gray.shape
        out = np.empty((b, t - 1, 2, h, w), np.float32)
        for i in range(b):
            events = self.simulator.simulate(gray[i])
            binned = events_to_frames(
                events, h, w, time_window=self.simulator.frame_us, t_start=0.0,
                t_end=(t - 1) * self.simulator.frame_us,
            )  # fmt: skip
            out[i] = binned[:, ::-1]  # tonic's [OFF, ON] -> EDR's [ON, OFF]
        return torch.from_numpy(out).to(frames.device)
