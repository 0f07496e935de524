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

import math
from collections.abc import Iterator

import numpy as np
import torch
from numba import njit

from edr.checks.config import NonNegativeFloat, PositiveFloat, check_arguments
from edr.data.events.checks import EVENT_DTYPE
from edr.representations.base import (
    FULL_SCALE,
    Features,
    Representation,
    check_clip,
    on_off_picture,
    to_gray,
)

TILE_PIXELS = 1 << 18  # DVSCamera simulates this many pixels at a time (bounded memory)


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


# The most events the settings may make one pixel fire between two frames (a 0.2 threshold at
# eps 1 fires at most 28): past it one recording's events no longer fit in memory.
MAX_EVENTS_PER_FRAME = 100


class DVSSimulator:
    """Turns gray frames into DVS events; one call simulates one recording from its first frame.

    ``threshold_on/off``: contrast thresholds in log intensity; ``mismatch``: relative sigma of
    their per-pixel spread; ``refractory_us``; ``shot_noise_hz``: spurious events per pixel and
    second; ``fps``: frame rate that sets the timestamps; ``eps``: offset so that I = 0 is legal.
    """

    def __init__(
        self,
        threshold_on: PositiveFloat = 0.2,
        threshold_off: PositiveFloat = 0.2,
        mismatch: NonNegativeFloat = 0.0,
        refractory_us: NonNegativeFloat = 0.0,
        shot_noise_hz: NonNegativeFloat = 0.0,
        fps: PositiveFloat = 25.0,
        eps: PositiveFloat = 1.0,
        seed: int = 0,
    ) -> None:
        check_arguments(self, locals())
        peak = math.log1p(FULL_SCALE / eps)  # the largest log-intensity change between frames
        for name, threshold in (("threshold_on", threshold_on), ("threshold_off", threshold_off)):
            if peak / threshold > MAX_EVENTS_PER_FRAME:
                raise ValueError(
                    f"DVSSimulator: {name}={threshold:g}: expected at least "
                    f"{peak / MAX_EVENTS_PER_FRAME:.3g} with eps={eps:g}: a full-scale change "
                    f"would fire {peak / threshold:.3g} events a pixel between two frames (at "
                    f"most {MAX_EVENTS_PER_FRAME}, so that a recording fits in memory)"
                )
        if shot_noise_hz / fps > MAX_EVENTS_PER_FRAME:
            raise ValueError(
                f"DVSSimulator: shot_noise_hz={shot_noise_hz:g}: expected at most "
                f"{MAX_EVENTS_PER_FRAME * fps:g} at fps={fps:g} (at most "
                f"{MAX_EVENTS_PER_FRAME} noise events a pixel between two frames)"
            )
        self.threshold_on, self.threshold_off = threshold_on, threshold_off
        self.mismatch, self.refractory_us, self.shot_noise_hz = (
            mismatch,
            float(refractory_us),  # one compiled ``_crossings``, whether the config wrote 0 or 0.0
            shot_noise_hz,
        )
        self.fps, self.eps, self.seed = fps, eps, seed

    @property
    def frame_us(self) -> float:
        return 1e6 / self.fps

    def simulate(self, frames: np.ndarray) -> np.ndarray:
        """(T, H, W) gray intensities (0..255) -> events (EVENT_DTYPE), sorted by ``t``."""
        frames = self._checked(frames)
        chunks = [chunk[1:] for chunk in self.intervals(frames)]
        if not chunks:
            return np.zeros(0, EVENT_DTYPE)
        times, pixels, pol = (np.concatenate(parts) for parts in zip(*chunks, strict=True))
        order = np.argsort(times, kind="stable")
        w = frames.shape[2]
        events = np.empty(len(order), EVENT_DTYPE)
        events["t"] = np.floor(times[order]).astype(np.int64)
        events["x"] = pixels[order] % w
        events["y"] = pixels[order] // w
        events["p"] = pol[order]
        return events

    @staticmethod
    def _checked(frames: np.ndarray) -> np.ndarray:
        frames = np.asarray(frames)
        if frames.ndim != 3 or frames.shape[0] < 1:
            raise ValueError(f"frames must be (T, H, W) with T >= 1, got {frames.shape}")
        if not np.issubdtype(frames.dtype, np.number):
            raise ValueError(f"frames must be numbers, got {frames.dtype}")
        if frames.size and not (np.isfinite(frames).all() and frames.min() >= 0):
            raise ValueError(
                "frames must be finite intensities >= 0 (0..255); got "
                + ("NaN or inf" if not np.isfinite(frames).all() else f"min {frames.min():.4g}")
            )
        return frames

    def intervals(
        self, frames: np.ndarray, tile: int | None = None
    ) -> Iterator[tuple[int, np.ndarray, np.ndarray, np.ndarray]]:
        """The events of :meth:`simulate`, unsorted, in pieces: ``(k, t, pixel, polarity)``
        per frame interval ``k``, ``tile`` pixels at a time (every pixel at once when None),
        then the interval's shot noise. t (N,) float64 microseconds, pixel (N,) flat index
        y * W + x, polarity (N,) 1 ON / 0 OFF. Memory: a frame's log intensities and one
        tile's events, whatever the clip's length or the events' count."""
        frames = self._checked(frames)
        t_count, h, w = frames.shape
        pixels = h * w
        tile = tile or max(pixels, 1)
        rng = np.random.default_rng(self.seed)
        th_on, th_off = (
            np.maximum(th * (1.0 + self.mismatch * rng.standard_normal(pixels)), 0.01 * th)
            for th in (self.threshold_on, self.threshold_off)
        )
        log_next = self._log(frames[0])  # (P,)
        ref = log_next.copy()
        last_t = np.full(pixels, -np.inf)
        for k in range(t_count - 1):
            log_prev, log_next = log_next, self._log(frames[k + 1])
            t_prev = k * self.frame_us
            for start in range(0, pixels, tile):
                part = slice(start, start + tile)  # views: ref and last_t move on in place
                times, where, pol = _crossings(
                    log_prev[part], log_next[part], ref[part], th_on[part], th_off[part],
                    last_t[part], t_prev, self.frame_us, self.refractory_us,
                )  # fmt: skip
                yield k, times, where + start, pol
            if self.shot_noise_hz > 0:
                n_noise = rng.poisson(self.shot_noise_hz * self.frame_us * 1e-6 * pixels)
                yield (
                    k,
                    t_prev + self.frame_us * rng.random(n_noise),
                    rng.integers(0, pixels, n_noise),
                    rng.integers(0, 2, n_noise).astype(np.int8),
                )

    def _log(self, frame: np.ndarray) -> np.ndarray:
        """(H, W) intensities -> (P,) float64 log intensities."""
        return np.log(frame.reshape(-1).astype(np.float64) + self.eps)


def check_events(events: np.ndarray, height: int, width: int) -> np.ndarray:
    """``events`` with polarity as 0 (OFF) / 1 (ON); ``ValueError`` naming the field otherwise.

    Accepted: a structured array with fields ``t``, ``x``, ``y``, ``p`` (tonic's names and
    ``EVENT_DTYPE``); polarity 0/1, -1/1 (-1 is OFF) or bool; ``x`` in [0, width), ``y`` in
    [0, height); ``t`` sorted (``np.sort(events, order="t")`` sorts a list that is not).
    """
    if not isinstance(events, np.ndarray):
        raise ValueError(
            f"events must be a structured numpy array (fields t, x, y, p), got "
            f"{type(events).__name__}"
        )
    for name, size in (("height", height), ("width", width)):
        if isinstance(size, bool) or not isinstance(size, int | np.integer) or size < 1:
            raise ValueError(f"{name} must be a positive integer, got {size!r}")
    names = getattr(events.dtype, "names", None) or ()
    missing = [f for f in ("t", "x", "y", "p") if f not in names]
    if missing:
        raise ValueError(f"events need the fields t, x, y, p; missing {missing}")
    for field in ("x", "y"):
        if not np.issubdtype(events.dtype[field], np.integer):
            raise ValueError(f"events {field} must be integers, got {events.dtype[field]}")
    if np.issubdtype(events.dtype["t"], np.floating) and not np.isfinite(events["t"]).all():
        raise ValueError("events t must be finite (NaN or inf found)")
    for field, size, axis in (("x", width, "width"), ("y", height, "height")):
        if len(events) and (events[field].min() < 0 or events[field].max() >= size):
            raise ValueError(
                f"events {field} must lie in [0, {size}) (the sensor's {axis}); got "
                f"{events[field].min()}..{events[field].max()}"
            )
    polarities = set(np.unique(events["p"]).tolist())
    if not polarities <= {0, 1} and not polarities <= {-1, 1}:
        raise ValueError(f"events p must be 0/1, -1/1 or bool; got the values {sorted(polarities)}")
    if len(events) > 1 and (np.diff(events["t"]) < 0).any():
        raise ValueError('events t must be sorted; np.sort(events, order="t") sorts them')
    if -1 in polarities:
        events = events.copy()
        events["p"] = events["p"] > 0
    return events


def _windows(
    events: np.ndarray,
    time_window: float | None,
    event_count: int | None,
    n_time_bins: int | None,
    n_event_bins: int | None,
    overlap: float,
    include_incomplete: bool,
    start_time: float | None,
    end_time: float | None,
) -> tuple[np.ndarray, np.ndarray]:
    """(start, end) event indices of every frame, as tonic's slicers cut them."""
    t = events["t"]
    n = len(events)
    round_n = np.ceil if include_incomplete else np.floor
    if time_window is not None:
        stride = time_window - overlap
        if stride <= 0:
            raise ValueError(
                f"overlap ({overlap}) must be smaller than time_window ({time_window})"
            )
        start = t[0] if start_time is None else start_time
        end = t[-1] if end_time is None else end_time
        frames = max(int(round_n((end - start - time_window) / stride) + 1), 1)
        begins = np.arange(frames) * stride + start
        return np.searchsorted(t, begins), np.searchsorted(t, begins + time_window)
    if event_count is not None:
        stride = event_count - overlap
        if stride <= 0:
            raise ValueError(
                f"overlap ({overlap}) must be smaller than event_count ({event_count})"
            )
        count = min(event_count, n)
        frames = int(round_n((n - count) / stride) + 1)
        begins = (np.arange(frames) * stride).astype(np.int64)
        return begins, begins + count
    if not 0 <= overlap < 1:
        raise ValueError(f"overlap is a fraction of a bin here: 0 <= overlap < 1, got {overlap}")
    if n_time_bins is not None:
        window = (t[-1] - t[0]) // n_time_bins * (1 + overlap)
        begins = np.arange(n_time_bins) * window * (1 - overlap) + t[0]
        return np.searchsorted(t, begins), np.searchsorted(t, begins + window)
    count = int(n // n_event_bins * (1 + overlap))
    begins = np.arange(n_event_bins) * int(count * (1 - overlap))
    return begins, begins + count


def events_to_frames(
    events: np.ndarray,
    height: int,
    width: int,
    *,
    time_window: float | None = None,
    event_count: int | None = None,
    n_time_bins: int | None = None,
    n_event_bins: int | None = None,
    overlap: float = 0.0,
    include_incomplete: bool = False,
    start_time: float | None = None,
    end_time: float | None = None,
    dtype: np.dtype | type = np.int16,
) -> np.ndarray:
    """Bin events to count frames (N, 2, H, W), channel = polarity (0 OFF, 1 ON), as
    ``tonic.transforms.ToFrame(sensor_size=(width, height, 2), ...)`` does, frame for frame.

    Exactly one of ``time_window`` (timestamp units per frame), ``event_count`` (events per
    frame), ``n_time_bins`` or ``n_event_bins``. ``overlap``: in timestamp units, events, or (for
    the bin counts) a fraction of a bin. A last, incomplete window or count is dropped unless
    ``include_incomplete``; windows start at ``start_time`` (default: the first event) and end
    by ``end_time`` (default: the last event); an event on a window's end belongs to the next.
    ``dtype``: tonic's int16 by default. Events: see :func:`check_events`.
    """
    chosen = [v for v in (time_window, event_count, n_time_bins, n_event_bins) if v is not None]
    if len(chosen) != 1:
        raise ValueError("give exactly one of time_window, event_count, n_time_bins, n_event_bins")
    if chosen[0] <= 0:
        raise ValueError(f"the window, count or number of bins must be positive, got {chosen[0]}")
    for name, value in (("event_count", event_count), ("n_time_bins", n_time_bins),
                        ("n_event_bins", n_event_bins)):  # fmt: skip
        if value is not None and (isinstance(value, bool) or value != int(value)):
            raise ValueError(f"{name} must be a whole number, got {value}")
    if not np.issubdtype(np.dtype(dtype), np.signedinteger) and np.dtype(dtype).kind != "f":
        raise ValueError(
            f"dtype must be a signed integer or float type (counts must not wrap), got {dtype}"
        )
    events = check_events(events, height, width)
    if not len(events) and (time_window is None or start_time is None or end_time is None):
        raise ValueError("no events: binning them needs time_window, start_time and end_time")
    begins, ends = _windows(events, time_window, event_count, n_time_bins, n_event_bins,
                            overlap, include_incomplete, start_time, end_time)  # fmt: skip
    frames = np.zeros((len(begins), 2, height, width), dtype)
    for i, (a, b) in enumerate(zip(begins, ends, strict=True)):
        e = events[a:b]
        np.add.at(frames, (i, e["p"].astype(np.int64), e["y"], e["x"]), 1)
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
        out = np.zeros((b, t - 1, 2, h * w), np.float32)
        frame_us = self.simulator.frame_us
        for i in range(b):  # binned as they come: never the clip's whole event list at once
            for _, times, pixels, pol in self.simulator.intervals(gray[i], TILE_PIXELS):
                # the bin events_to_frames gives an event at floor(t) (time_window = frame_us)
                bins = np.minimum(np.floor(times) // frame_us, t - 2).astype(np.int64)
                np.add.at(out[i], (bins, 1 - pol.astype(np.int64), pixels), 1.0)  # [ON, OFF]
        return torch.from_numpy(out.reshape(b, t - 1, 2, h, w)).to(frames.device)
