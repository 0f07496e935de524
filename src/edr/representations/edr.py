"""EDR: the thresholded exponential moving average of intensity returns (the paper's Eq. 1-3).

Per pixel x, per timescale k with half-life tau_k (frames)::

    alpha_k  = 1 - 2 ** (-1 / tau_k)
    ema_k(t) = ema_k(t-1) + alpha_k * (I(t) - ema_k(t-1)),   ema_k(0) = I(0)
    ratio form  R_k = (I(t) / ema_k(t)) ** beta_k         thresholds 1 + nu_on, 1 - nu_off
    log form    r_k = beta_k * ln(I(t) / ema_k(t))         thresholds ln(1 + nu_on), ln(1 - nu_off)
    soft        ON = relu(R - on_th),  OFF = relu(off_th - R)
    hard        ON = [R > on_th],      OFF = [R < off_th]

with ``I = intensity + eps``. ``combine="sum"`` first sums the K weighted log-ratios (as the
authors' code did) and thresholds once; ``combine="separate"`` gives each timescale its own
ON/OFF pair. Output channel order: for each input channel c, for each timescale k, [ON, OFF].
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from typing import Any, Literal, NamedTuple

import numpy as np
import torch
from torch import nn

from edr.checks.config import (
    BelowOne,
    NonNegativeFloat,
    PositiveFloat,
    PositiveInt,
    check_arguments,
)
from edr.representations import buffers, kernels
from edr.representations.base import (
    FULL_SCALE,
    Features,
    Representation,
    check_clip,
    check_frame,
    on_off_picture,
    to_gray,
)
from edr.representations.edr_grad import fused_events

OUT_DTYPES = {"float32": torch.float32, "float16": torch.float16, "bfloat16": torch.bfloat16,
              "float64": torch.float64}  # fmt: skip


class EDRState(NamedTuple):
    """Streaming state of :class:`EDR`: the EMA of every channel and timescale."""

    ema: torch.Tensor  # (B, C, K, H, W) float32, intensities + eps


def _per_timescale(value: float | Sequence[float], k: int, name: str) -> torch.Tensor:
    """A scalar or one value per timescale -> (k,) float32."""
    values = [float(value)] * k if isinstance(value, int | float) else [float(v) for v in value]
    if len(values) != k:
        raise ValueError(f"{name} has {len(values)} values; give one, or one per timescale ({k})")
    return torch.tensor(values, dtype=torch.float32)


TAU_RANGE = (0.25, 64.0)  # half-lives in frames that parameterization="bounded" can reach


def _overflow_problem(
    eps: float, betas: Sequence[float], log_form: bool, summed: bool, dtype: torch.dtype
) -> str | None:
    """Where eps or beta would take EDR's arithmetic past ``dtype``: the largest return is a
    pixel at full scale over an EMA at eps, ``(1 + 255/eps)``; the ratio form raises it to beta
    (the sum of the betas with ``combine="sum"``), the log form multiplies its log by beta."""
    info = torch.finfo(dtype)
    name = str(dtype).removeprefix("torch.")
    # the smallest eps whose largest return is a finite number (and eps itself a normal one)
    least = max(info.tiny, FULL_SCALE / math.expm1(math.log(info.max)))
    if eps < least:
        return (
            f"eps={eps!r}: expected at least {least:.3g}: a pixel of {FULL_SCALE:g} over an EMA "
            f"at eps is a return of {1 + FULL_SCALE / eps:.3g}, past {name}'s largest number"
        )
    peak = math.log1p(FULL_SCALE / eps)  # the largest |ln(I / ema)| an intensity reaches
    beta = sum(betas) if summed else max(betas)
    bound = (info.max if log_form else math.log(info.max)) / peak
    if beta > bound:
        what = f"{peak:.3g} * beta" if log_form else f"(1 + {FULL_SCALE:g}/eps) ** beta"
        return (
            f"beta={beta:g}{' summed' if summed else ''}: expected at most {bound:.6g} with "
            f"eps={eps:g}: past it the largest return, {what}, overflows {name}"
        )
    return None


def _alpha(tau: float) -> float:
    return -math.expm1(-math.log(2) / tau)  # 1 - 2 ** (-1 / tau), exact for tiny and huge tau


def _events_possible(taus: Sequence[float], betas: Sequence[float], nu_on: Sequence[float],
                     nu_off: Sequence[float], eps: float, summed: bool,
                     dtype: torch.dtype) -> bool:  # fmt: skip
    """Whether any input makes an event: the largest returns, a dark pixel turning full scale
    (ON) or the reverse (OFF), cross a threshold; each return at least the dtype's resolution."""
    resolution = torch.finfo(dtype).eps
    ups, downs = [], []
    for tau, beta in zip(taus, betas, strict=True):
        keep = 1 - _alpha(tau)  # of the EMA's last value
        ups.append(beta * math.log1p(keep * FULL_SCALE / (eps + (1 - keep) * FULL_SCALE)))
        downs.append(beta * math.log1p(keep * FULL_SCALE / eps))
    if summed:
        ups, downs = [sum(ups)], [sum(downs)]
    off_crossings = [-math.log1p(-n) if n < 1 else math.inf for n in nu_off]
    return any(u > max(math.log1p(n), resolution) for u, n in zip(ups, nu_on, strict=True)) or any(
        d > max(c, resolution) for d, c in zip(downs, off_crossings, strict=True)
    )


def _listed(values: Sequence[float]) -> str:
    return "[" + ", ".join(f"{v:g}" for v in values) + "]"


def _scales_problem(taus: list[float], betas: list[float], nu_on: list[float],
                    nu_off: list[float], eps: float, summed: bool,
                    dtype: torch.dtype) -> str | None:  # fmt: skip
    """A half-life whose EMA cannot move in ``dtype``, or a half-life, eps or beta and
    thresholds under which no input makes an event (EDR all zeros)."""
    info = torch.finfo(dtype)
    name = str(dtype).removeprefix("torch.")
    settings = (betas, nu_on, nu_off, eps, summed, dtype)
    off = -math.log1p(-min(nu_off)) if min(nu_off) < 1 else 0.0
    crossing = max(math.log1p(min(nu_on)), off, info.eps)  # the smallest log-return that counts
    exponent = crossing / (sum(betas) if summed else max(betas))
    largest = FULL_SCALE / math.expm1(exponent) if exponent < math.log(info.max) else 0.0
    if eps > FULL_SCALE and eps > largest > info.eps:  # no EMA, however slow, makes an event
        return (
            f"eps={eps:g}: expected at most {largest:.4g} with beta={_listed(betas)}, "
            f"nu_on={_listed(nu_on)}, nu_off={_listed(nu_off)}: past it no return, at most "
            f"(1 + {FULL_SCALE:g}/eps) ** beta, crosses a threshold, and every event would be 0"
        )
    # the longest half-life whose EMA still moves: alpha * 255 at least half a step at 255 + eps
    step = 2.0 ** math.floor(math.log2(FULL_SCALE + eps)) * info.eps  # a float step there
    longest = -math.log(2) / math.log1p(-min(step / 2 / FULL_SCALE, 0.5))
    if max(taus) > longest:
        return (
            f"half_lives={_listed(taus)}: expected each at most {longest:.3g} frames: past it "
            f"alpha * {FULL_SCALE:g} is under half a {name} step at {FULL_SCALE:g} + eps, and the "
            "EMA never leaves the first frame"
        )
    if _events_possible(taus, *settings):
        return None
    if _events_possible([longest] * len(taus), *settings):  # a slower EMA would make events
        low, high = min(taus), longest  # the shortest half-life that does, by bisection
        for _ in range(100):
            middle = math.sqrt(low * high)
            low, high = (
                (low, middle)
                if _events_possible([middle] * len(taus), *settings)
                else (middle, high)
            )
        return (
            f"half_lives={_listed(taus)}: expected each at least {high:.3g} frames with "
            f"eps={eps:g}, beta={_listed(betas)}: shorter, the EMA follows each frame so closely "
            "that no return crosses a threshold, and every event would be 0"
        )
    return (
        f"beta={_listed(betas)}: expected a beta, or thresholds (nu_on={_listed(nu_on)}, "
        f"nu_off={_listed(nu_off)}), that a return can cross with eps={eps:g}: the largest, "
        f"(1 + {FULL_SCALE:g}/eps) ** beta, stays inside them, and every event would be 0"
    )


class KernelArgs(NamedTuple):
    """An EDR layer's settings as the numba kernels take them (one source for every caller)."""

    gray: bool  # convert RGB to luma first
    eps: np.float32  # intensity offset
    alpha: np.ndarray  # (K,) float32 EMA rates
    beta: np.ndarray  # (K,) float32
    on_th: np.ndarray  # (K,) float32 ON thresholds (ratio or log form)
    off_th: np.ndarray  # (K,) float32 OFF thresholds
    log: bool  # log-ratio form
    hard: bool  # 0/1 indicators instead of the excess
    sum_k: bool  # sum the K log-ratios, threshold once

    @classmethod
    def unused(cls) -> KernelArgs:
        """Placeholders for a kernel call that computes no EDR."""
        none = np.zeros(1, np.float32)
        return cls(False, np.float32(0), none, none, none, none, False, False, False)


class EDR(Representation):
    """Retinomorphic event-driven representation, as a learnable layer and a streaming filter.

    ``forward``: (B, T, C, H, W) -> (B, T, C' * 2 * K', H, W), C' = 1 if ``color="gray"``
    else C, K' = 1 if ``combine="sum"`` else K. ``step``: the same, one frame at a time.
    Under ``torch.no_grad()`` on the CPU (uint8 or float32 input) both use a fused numba kernel.

    Arguments (each checked; a bad one raises ``ValueError`` naming it): ``half_lives`` > 0
    frames, one number (one timescale) or one per timescale; ``beta`` > 0 (a ``beta`` <= 0 would
    swap ON and OFF or erase them, so it is refused); ``nu_on`` >= 0 and 0 <= ``nu_off`` < 1, one
    or one per timescale; ``eps`` > 0, the offset that keeps ratio and log finite at I = 0 on
    every path and in the gradients; ``out_dtype``: the output's dtype on every path and device
    (float32 unless asked; the EMA state is float32, float64 with ``out_dtype="float64"``).
    """

    features = Features(
        "every past frame, weighted by half-lives tau_k", "yes (EMA per timescale)",
        "yes (nu_on, nu_off; soft or hard)", "yes", "no", "optional (learnable=true)",
    )  # fmt: skip

    def __init__(
        self,
        half_lives: PositiveFloat | Sequence[PositiveFloat] = (3.8,),
        beta: PositiveFloat | Sequence[PositiveFloat] = 1.0,
        nu_on: NonNegativeFloat | Sequence[NonNegativeFloat] = 0.05,
        nu_off: BelowOne | Sequence[BelowOne] = 0.05,
        threshold: Literal["soft", "hard"] = "soft",
        return_form: Literal["ratio", "log"] = "ratio",
        combine: Literal["separate", "sum"] = "separate",
        eps: PositiveFloat = 1.0,
        learnable: bool = False,
        color: Literal["keep", "gray"] = "keep",
        fast: bool = True,
        bptt_window: PositiveInt | None = None,
        parameterization: Literal["log", "bounded"] = "log",
        out_dtype: Literal["float32", "float16", "bfloat16", "float64"] = "float32",
    ) -> None:
        super().__init__()
        check_arguments(self, locals())
        if problem := EDR.settings_problem(locals()):
            raise ValueError(f"EDR: {problem}")
        half_lives = (
            [float(half_lives)] if isinstance(half_lives, int | float) else list(half_lives)
        )
        k = len(half_lives)
        k_out = 1 if combine == "sum" else k
        nu_on_t = _per_timescale(nu_on, k_out, "nu_on")
        nu_off_t = _per_timescale(nu_off, k_out, "nu_off")

        self.threshold, self.return_form, self.combine, self.color = (
            threshold,
            return_form,
            combine,
            color,
        )
        self.eps, self.learnable, self.fast = float(eps), learnable, fast
        self.bptt_window = bptt_window  # training: gradients cross at most this many frames
        self.out_dtype = OUT_DTYPES[out_dtype]
        self._compute_dtype = torch.float64 if out_dtype == "float64" else torch.float32
        self.k = k
        self._param_cache: tuple[tuple, tuple] | None = None
        self.parameterization = parameterization
        taus = torch.tensor(half_lives, dtype=torch.float32)
        if parameterization == "log":  # tau = exp(log_tau): every half-life stays positive
            raw = (("log_tau", taus.log()), ("beta", _per_timescale(beta, k, "beta")),
                   ("nu_on", nu_on_t), ("nu_off", nu_off_t))  # fmt: skip
        else:  # each value a sigmoid into its range, beta through exp: none can leave its range
            if not all(TAU_RANGE[0] < h < TAU_RANGE[1] for h in half_lives) or (nu_on_t >= 1).any():
                raise ValueError(
                    f"EDR: parameterization='bounded' takes half-lives in {TAU_RANGE} and nu_on < 1"
                )
            span = TAU_RANGE[1] - TAU_RANGE[0]
            raw = (("tau_logit", torch.logit((taus - TAU_RANGE[0]) / span)),
                   ("log_beta", _per_timescale(beta, k, "beta").log()),
                   ("nu_on_logit", torch.logit(nu_on_t)), ("nu_off_logit", torch.logit(nu_off_t)))  # fmt: skip
        self._raw_names = tuple(name for name, _ in raw)
        for name, value in raw:
            if learnable:
                self.register_parameter(name, nn.Parameter(value))
            else:
                self.register_buffer(name, value)

    @staticmethod
    def settings_problem(values: Mapping[str, Any]) -> str | None:
        """``key=value: expected ...`` for settings no single range shows: half-lives, betas or
        thresholds of the wrong count, eps or beta past what the arithmetic holds
        (:func:`_overflow_problem`), a half-life whose EMA cannot move, and settings under which
        every event is 0 (:func:`_scales_problem`); None where they work. Checked by the
        constructor, and by ``edr-run`` before any work (``check_together``)."""
        lives, summed = values["half_lives"], values["combine"] == "sum"
        taus = [float(lives)] if isinstance(lives, int | float) else [float(t) for t in lives]
        if not taus:
            return "half_lives=[]: expected at least one half-life"
        if summed and not all(isinstance(values[n], int | float) for n in ("nu_on", "nu_off")):
            return 'nu_on: expected one number for nu_on and nu_off: combine="sum" thresholds once'
        k_out = 1 if summed else len(taus)
        counts = {"beta": len(taus), "nu_on": k_out, "nu_off": k_out}
        given = {n: values[n] if isinstance(values[n], Sequence) else [values[n]] * k for n, k
                 in counts.items()}  # fmt: skip
        if wrong := next((n for n, k in counts.items() if len(given[n]) != k), None):
            return f"{wrong}={list(given[wrong])}: expected one value, or one per timescale ({counts[wrong]})"
        betas, nu_on, nu_off = ([float(v) for v in given[n]] for n in counts)
        dtype = torch.float64 if values["out_dtype"] == "float64" else torch.float32
        eps = float(values["eps"])
        return _overflow_problem(eps, betas, values["return_form"] == "log", summed, dtype) or (
            _scales_problem(taus, betas, nu_on, nu_off, eps, summed, dtype)
        )

    # ---- sizes -------------------------------------------------------------------------------
    def state_channels(self, in_channels: int) -> int:
        """C' of the state (B, C', K, H, W) and of the events: 1 on gray, else the input's."""
        return 1 if self.color == "gray" else in_channels

    def out_channels(self, in_channels: int) -> int:
        return self.state_channels(in_channels) * 2 * (1 if self.combine == "sum" else self.k)

    def preview(self, out_t: torch.Tensor) -> np.ndarray:
        """ON events (summed over channels and timescales) in green, OFF in red."""
        pairs = out_t.detach().float().cpu().reshape(-1, 2, *out_t.shape[-2:]).sum(0).numpy()
        return on_off_picture(pairs[0], pairs[1])

    def _raw(self) -> tuple[torch.Tensor, ...]:
        """The stored tensors (parameters when learnable), in the order of ``_raw_names``."""
        return tuple(getattr(self, name) for name in self._raw_names)

    @property
    def half_lives(self) -> torch.Tensor:
        """(K,) half-lives in frames."""
        if self.parameterization == "log":
            return self.log_tau.exp()
        return TAU_RANGE[0] + (TAU_RANGE[1] - TAU_RANGE[0]) * torch.sigmoid(self.tau_logit)

    @property
    def betas(self) -> torch.Tensor:
        """(K,) the ratio's exponents (the log-ratio's weights)."""
        return self.beta if self.parameterization == "log" else self.log_beta.exp()

    def settings_now(self) -> dict[str, float]:
        """``{"edr/tau_0": ..., "edr/beta_0": ..., "edr/nu_on_0": ..., "edr/nu_off_0": ...}``:
        the layer's settings as numbers, one per timescale (what a learnable layer learned)."""
        with torch.no_grad():
            named = {"tau": self.half_lives, "beta": self.betas, **dict(zip(("nu_on", "nu_off"),
                     self.nus(), strict=True))}  # fmt: skip
        return {
            f"edr/{name}_{i}": float(v)
            for name, t in named.items()
            for i, v in enumerate(t.detach())
        }

    def out_of_range(self) -> str | None:
        """The first value a learnable layer's parameters walked to where the layer no longer
        works, or None: a half-life or beta not > 0 (beta <= 0 swaps or erases ON and OFF), a
        nu_off of 1 or more (its OFF threshold is 0 or less), NaN anywhere, or a beta past what
        float32 holds (:func:`_overflow_problem`)."""
        with torch.no_grad():
            nu_on, nu_off = self.nus()
            rules = (("tau", self.half_lives, "> 0", lambda v: v > 0),
                     ("beta", self.betas, "> 0", lambda v: v > 0),
                     ("nu_on", nu_on, "a number", torch.isfinite),
                     ("nu_off", nu_off, "< 1", lambda v: v < 1))  # fmt: skip
            for name, values, expected, holds in rules:
                for i, ok in enumerate(holds(values).tolist()):  # NaN holds no rule
                    if not ok:
                        return (
                            f"EDR's {name}_{i} = {float(values[i]):.4g} left its range ({expected})"
                        )
            return _overflow_problem(
                self.eps, self.betas.tolist(), self.return_form == "log", self.combine == "sum",
                self._compute_dtype,
            )  # fmt: skip

    def nus(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(K',) nu_on and nu_off."""
        if self.parameterization == "log":
            return self.nu_on, self.nu_off
        return torch.sigmoid(self.nu_on_logit), torch.sigmoid(self.nu_off_logit)

    @property
    def alpha(self) -> torch.Tensor:
        """(K,) EMA weights, alpha_k = 1 - 2 ** (-1 / tau_k)."""
        return 1.0 - torch.pow(2.0, -1.0 / self.half_lives)

    def thresholds(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(K',) ON and OFF thresholds in the domain of ``return_form``."""
        nu_on, nu_off = self.nus()
        on, off = 1.0 + nu_on, 1.0 - nu_off
        if self.return_form == "log":
            return torch.log(on), torch.log(off)
        return on, off

    # ---- public API --------------------------------------------------------------------------
    def forward(self, frames: torch.Tensor, out: torch.Tensor | None = None) -> torch.Tensor:
        """(B, T, C, H, W) uint8 or float -> (B, T, C' * 2 * K', H, W) in ``out_dtype``.

        ``out``: a tensor of that shape and dtype to write the events into (and return), so
        that repeated calls reuse one buffer; without it, big outputs come from recycled memory
        (:mod:`edr.representations.buffers`).
        """
        check_clip(frames, name="frames", dtype=self._compute_dtype)
        if self.learnable and (problem := self.out_of_range()) is not None:
            warnings.warn(  # training records this as a divergence; a caller should hear it too
                f"{problem}: the events this layer gives are not EDR's (NaN thresholds give "
                "none at all)",
                RuntimeWarning,
                stacklevel=2,
            )
        b, t, c, h, w = frames.shape
        shape = (b, t, self.out_channels(c), h, w)
        if self.can_fuse(frames):
            ema = torch.empty((b, self.state_channels(c), self.k, h, w))
            return self._fused(frames, ema, np.ones(b, np.bool_), out)
        if self.trains_fused(frames):
            events = self._fused_train(frames)
            if out is None:
                return events.to(self.out_dtype)
            return buffers.output(out, shape, self.out_dtype, frames.device).copy_(events)
        state, outs = None, []
        for i in range(t):
            if state is not None and self.bptt_window and i % self.bptt_window == 0:
                state = EDRState(state.ema.detach())  # truncated backpropagation through time
            out_t, state = self.step(frames[:, i], state)
            outs.append(out_t)
        if out is None:
            return torch.stack(outs, dim=1)  # (B, T, C'*2*K', H, W)
        return torch.stack(
            outs, dim=1, out=buffers.output(out, shape, self.out_dtype, frames.device)
        )

    def step(
        self,
        frame: torch.Tensor,
        state: EDRState | None = None,
        reset: torch.Tensor | None = None,
        inplace: bool = False,
        out: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, EDRState]:
        """One frame (B, C, H, W) -> (events (B, C'*2*K', H, W), new state).

        ``state=None`` starts every row from this frame; ``reset`` (B,) bool restarts the rows
        where it is set. The state passed in is left as it was (keep it to branch or replay),
        unless ``inplace=True``: then the fused path writes the new EMA into its tensor and
        returns it, saving a copy of the state per step (for callers that own their buffers).
        ``out``: a (B, C'*2*K', H, W) tensor in ``out_dtype`` that receives the events (a
        streaming loop's one output buffer).
        """
        check_frame(frame, dtype=self._compute_dtype)
        b, c, h, w = frame.shape
        shape = (b, self.state_channels(c), self.k, h, w)
        if state is not None and not (
            isinstance(state, tuple) and isinstance(getattr(state, "ema", None), torch.Tensor)
        ):
            raise ValueError(
                f"state must be the EDRState a previous step returned, or None; got "
                f"{type(state).__name__}"
            )
        if state is not None and state.ema.device.type == "meta":
            raise ValueError(
                "state is on the meta device (a shape, no values): pass the EDRState a previous "
                "step returned, or None"
            )
        if state is not None and tuple(state.ema.shape) != shape:
            raise ValueError(f"state has shape {tuple(state.ema.shape)}, this frame needs {shape}")
        if reset is not None:
            reset = torch.as_tensor(reset, dtype=torch.bool, device=frame.device).reshape(-1)
            if reset.numel() != b:
                raise ValueError(
                    f"reset must have one flag per batch row ({b}), got {reset.numel()}"
                )
        if state is not None:  # rows that restart may hold anything: they are not read
            kept = state.ema if reset is None else state.ema[~reset.to(state.ema.device)]
            if not torch.isfinite(kept).all():
                raise ValueError("state holds NaN or inf: start again from state=None (or reset)")
        if self.can_fuse(frame):
            if state is None:
                ema = torch.empty(shape, dtype=torch.float32)
                restart = np.ones(b, np.bool_)
            else:
                source = state.ema.detach().to(torch.float32).contiguous()
                # Not inplace: the kernel copies the caller's state into a new one as it goes
                # (a torch copy between two launches would wake torch's threads against numba's).
                ema = source if inplace else torch.empty_like(source)
                restart = reset.cpu().numpy() if reset is not None else np.zeros(b, np.bool_)
            events = self._fused(
                frame.unsqueeze(1),
                ema,
                restart,
                None if out is None else out.unsqueeze(1),
                source=None if state is None else source,
            )
            return events[:, 0], EDRState(ema)
        events, state = self._step_torch(frame, state, reset)
        if out is None:
            return events, state
        return buffers.output(out, tuple(events.shape), events.dtype, events.device).copy_(
            events
        ), state

    # ---- the two paths -----------------------------------------------------------------------
    def _intensity(self, frame: torch.Tensor) -> torch.Tensor:
        """(B, C, H, W) -> (B, C', H, W) intensities + eps, in the compute dtype."""
        x = frame.to(self._compute_dtype)
        return (to_gray(x, channel_dim=1) if self.color == "gray" else x) + self.eps

    def _step_torch(
        self, frame: torch.Tensor, state: EDRState | None, reset: torch.Tensor | None
    ) -> tuple[torch.Tensor, EDRState]:
        intensity = self._intensity(frame).unsqueeze(2)  # (B, C', 1, H, W)
        b, c, _, h, w = intensity.shape
        if state is None:
            prev = intensity.expand(b, c, self.k, h, w)
        elif reset is not None:
            prev = torch.where(reset.view(b, 1, 1, 1, 1), intensity, state.ema.to(intensity))
        else:
            prev = state.ema.to(intensity)
        alpha = self.alpha.to(intensity).view(1, 1, self.k, 1, 1)
        ema = prev + alpha * (intensity - prev)  # (B, C', K, H, W)
        ratio = intensity / ema
        beta = self.betas.to(intensity).view(1, 1, self.k, 1, 1)
        if self.combine == "sum":
            summed = (beta * torch.log(ratio)).sum(dim=2, keepdim=True)  # (B, C', 1, H, W)
            response = summed if self.return_form == "log" else torch.exp(summed)
        elif self.return_form == "log":
            response = beta * torch.log(ratio)
        else:
            response = ratio**beta
        on_th, off_th = (v.to(intensity).view(1, 1, -1, 1, 1) for v in self.thresholds())
        on, off = torch.relu(response - on_th), torch.relu(off_th - response)
        if self.threshold == "hard":  # 0/1 events exactly, with the soft ones' gradient
            on = (response > on_th).to(on.dtype) + (on - on.detach())
            off = (response < off_th).to(off.dtype) + (off - off.detach())
        events = torch.stack((on, off), dim=3)  # (B, C', K', 2, H, W)
        return events.reshape(b, -1, h, w).to(self.out_dtype), EDRState(ema)

    def can_fuse(self, x: torch.Tensor) -> bool:
        needs_grad = torch.is_grad_enabled() and (x.requires_grad or self.learnable)
        return (
            self.fast
            and not needs_grad
            and self._compute_dtype == torch.float32
            and x.device.type == "cpu"
            and x.dtype in (torch.uint8, torch.float32)
        )

    def trains_fused(self, x: torch.Tensor) -> bool:
        """Whether ``forward`` takes the fused training path (:mod:`edr.representations.edr_grad`):
        gradients wanted, on the CPU; the torch path serves GPUs and ``fast=False``."""
        return (
            self.fast
            and torch.is_grad_enabled()
            and (x.requires_grad or self.learnable)
            and x.device.type == "cpu"
        )

    def _fused_train(self, frames: torch.Tensor) -> torch.Tensor:
        """(B, T, C, H, W) -> (B, T, C' * 2 * K', H, W) in the compute dtype, differentiable."""
        b, t, c = frames.shape[:3]
        on_th, off_th = self.thresholds()
        settings = {
            "log_form": self.return_form == "log",
            "hard": self.threshold == "hard",
            "sum_k": self.combine == "sum",
            "window": self.bptt_window or 0,
            "dtype": self._compute_dtype,
        }
        if frames.requires_grad or frames.dtype not in (torch.uint8, torch.float32):
            # EDR after a learned layer (torch differentiates the luma), or half-precision frames
            intensity = self._intensity(frames.flatten(0, 1)).unflatten(0, (b, t))
            return fused_events(intensity, self.alpha, self.betas, on_th, off_th, **settings)
        gray = self.color == "gray" and c == 3  # the kernels read the frames as they come
        return fused_events(frames, self.alpha, self.betas, on_th, off_th, gray=gray,
                            eps=self.eps, **settings)  # fmt: skip

    def kernel_args(self, in_channels: int) -> KernelArgs:
        """What the kernels (``edr_kernel``, ``frame_kernel``) take of this layer, in their
        order, for frames of ``in_channels`` channels."""
        return KernelArgs(
            self.color == "gray" and in_channels == 3,
            np.float32(self.eps),
            *self.kernel_params(),
            self.return_form == "log",
            self.threshold == "hard",
            self.combine == "sum",
        )

    def kernel_params(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(alpha, beta, on_th, off_th) as float32 arrays, recomputed only when a parameter changes."""
        params = self._raw()
        key = tuple((p.data_ptr(), p._version) for p in params)
        if self._param_cache is None or self._param_cache[0] != key:
            with torch.no_grad():
                values = (self.alpha, self.betas, *self.thresholds())
                arrays = tuple(v.detach().cpu().to(torch.float32).numpy().copy() for v in values)
            self._param_cache = (key, arrays)
        return self._param_cache[1]

    def _fused(
        self,
        frames: torch.Tensor,
        ema: torch.Tensor,
        restart: np.ndarray,
        out: torch.Tensor | None = None,
        source: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """frames (B, T, C, H, W) -> (B, T, C'*2*K', H, W) in ``out_dtype`` (into ``out`` when
        given) through ``kernels.edr_kernel``, carrying the EMA in ``ema`` (updated in place;
        first copied from ``source``, a state of the same shape, where that is another tensor)."""
        b, t, c_in, h, w = frames.shape
        c, k = ema.shape[1], ema.shape[2]
        k_out = 1 if self.combine == "sum" else k
        shape = (b, t, c * k_out * 2, h, w)
        target = buffers.output(out, shape, self.out_dtype, frames.device)
        events = target if buffers.writable(target) else buffers.RECYCLED.empty(shape)
        pixels_last = frames.permute(0, 1, 3, 4, 2)  # (B, T, H, W, C), a view
        interleaved = c_in > 1 and pixels_last.is_contiguous()  # as env pixels (H, W, C) come
        if interleaved:
            x = pixels_last.view(b, t, 1, h * w * c_in)
        else:
            x = frames.contiguous().view(b, t, c_in, h * w)
        kernels.launch(
            kernels.edr_kernel,
            b * t * h * w,
            x.numpy(),
            c_in if interleaved else 0,
            *self.kernel_args(c_in),
            (ema if source is None else source).view(b, c, k, h * w).numpy(),
            source is not None and source.data_ptr() != ema.data_ptr(),
            ema.view(b, c, k, h * w).numpy(),
            restart,
            events.view(b, t, c, k_out, 2, h * w).numpy(),
        )
        return target if events is target else target.copy_(events)

    def extra_repr(self) -> str:
        taus = [round(v, 3) for v in self.half_lives.tolist()]
        return (
            f"half_lives={taus}, threshold={self.threshold}, return_form={self.return_form}, "
            f"combine={self.combine}, eps={self.eps}, learnable={self.learnable}, color={self.color}"
        )
