"""EDR against the equations, streaming, resets, gradients, the fused path, and bad input."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest
import torch

from clips import ramp_clip
from edr.representations import EDR
from edr_reference import edr_reference

CASES = [
    # half_lives, beta, nu_on, nu_off, threshold, return_form, combine, eps, color
    ([3.8], [1.0], [0.05], [0.05], "soft", "ratio", "separate", 1.0, "keep"),
    ([3.8], [1.0], [0.05], [0.05], "hard", "ratio", "separate", 1.0, "gray"),
    ([1.0], [2.0], [0.1], [0.2], "soft", "log", "separate", 0.5, "keep"),
    ([1.0], [0.5], [0.02], [0.3], "hard", "log", "separate", 3.0, "gray"),
    (
        [1.0, 3.8, 8.0],
        [1.0, 0.5, 2.0],
        [0.05, 0.1, 0.02],
        [0.05, 0.2, 0.1],
        "soft",
        "ratio",
        "separate",
        1.0,
        "keep",
    ),
    (
        [1.0, 3.8, 8.0],
        [1.5, 1.0, 0.7],
        [0.05, 0.1, 0.02],
        [0.05, 0.2, 0.1],
        "hard",
        "log",
        "separate",
        2.0,
        "gray",
    ),
    ([1.0, 3.8, 8.0], [1.0, 1.0, 1.0], [0.05], [0.05], "soft", "ratio", "sum", 1.0, "gray"),
    ([1.0, 3.8, 8.0], [0.7, 1.3, 0.4], [0.1], [0.1], "soft", "log", "sum", 0.5, "keep"),
    ([1.0, 3.8], [1.0, 0.3], [0.05], [0.05], "hard", "ratio", "sum", 1.0, "keep"),
    ([1.0, 3.8], [2.0, 0.5], [0.02], [0.3], "hard", "log", "sum", 1.0, "gray"),
]


def _build(case: tuple, **kw: object) -> EDR:
    half_lives, beta, nu_on, nu_off, threshold, return_form, combine, eps, color = case
    return EDR(
        half_lives=half_lives,
        beta=beta,
        nu_on=nu_on[0] if combine == "sum" else nu_on,
        nu_off=nu_off[0] if combine == "sum" else nu_off,
        threshold=threshold,
        return_form=return_form,
        combine=combine,
        eps=eps,
        color=color,
        **kw,
    )


def _random_clip(dtype: torch.dtype, seed: int = 0, shape=(2, 7, 3, 5, 6)) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    if dtype == torch.uint8:
        return torch.randint(0, 256, shape, generator=g, dtype=torch.uint8)
    return (torch.rand(shape, generator=g) * 255).to(dtype)


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("dtype", [torch.uint8, torch.float32])
@pytest.mark.parametrize("fused", [True, False])
def test_matches_the_equations(case: tuple, dtype: torch.dtype, fused: bool) -> None:
    clip = _random_clip(dtype)
    edr = _build(case, fast=fused)
    with torch.no_grad():
        ours = edr(clip).double().numpy()
    ref, response, (on_th, off_th) = edr_reference(clip.numpy(), *case)
    assert ours.shape == ref.shape
    if case[4] == "hard":
        # Indicators may flip only where the response is within float32 rounding of a threshold.
        b, t = response.shape[:2]
        h, w = response.shape[-2:]
        near = np.minimum(
            np.abs(response - on_th[None, None, None, :, None, None]),
            np.abs(response - off_th[None, None, None, :, None, None]),
        )
        near = np.repeat(near[:, :, :, :, None], 2, axis=4).reshape(b, t, -1, h, w) < 1e-5
        np.testing.assert_array_equal(ours[~near], ref[~near])
    else:
        np.testing.assert_allclose(ours, ref, rtol=2e-5, atol=2e-5)


@pytest.mark.parametrize("case", CASES[::3])
def test_fused_path_equals_autograd_path(case: tuple) -> None:
    for dtype in (torch.uint8, torch.float32):
        clip = _random_clip(dtype, seed=1, shape=(3, 9, 3, 17, 13))
        with torch.no_grad():
            fused = _build(case, fast=True)(clip)
        torch_path = _build(case, fast=False)(clip)
        torch.testing.assert_close(fused, torch_path, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("fused", [True, False])
def test_step_equals_forward(fused: bool) -> None:
    clip = _random_clip(torch.float32, shape=(2, 6, 3, 4, 5))
    edr = EDR(half_lives=(1.0, 3.8), color="keep", fast=fused)
    with torch.no_grad():
        whole = edr(clip)
        state, outs = None, []
        for t in range(clip.shape[1]):
            out_t, state = edr.step(clip[:, t], state)
            outs.append(out_t)
    torch.testing.assert_close(torch.stack(outs, 1), whole)


@pytest.mark.parametrize("color", ["gray", "keep"])
@pytest.mark.parametrize("dtype", [torch.uint8, torch.float32])
def test_channels_last_frames_give_the_same_events(color: str, dtype: torch.dtype) -> None:
    clip = _random_clip(dtype, seed=4, shape=(2, 5, 3, 6, 7))
    channels_last = clip.permute(0, 1, 3, 4, 2).contiguous().permute(0, 1, 4, 2, 3)
    assert not channels_last.is_contiguous()  # the kernel reads it in place, interleaved
    edr = EDR(half_lives=(1.0, 3.8), color=color)
    with torch.no_grad():
        torch.testing.assert_close(edr(channels_last), edr(clip))
        state, outs = None, []
        for t in range(clip.shape[1]):  # as an env's (H, W, C) pixels come, one frame a step
            out_t, state = edr.step(channels_last[:, t], state)
            outs.append(out_t)
    torch.testing.assert_close(
        torch.stack(outs, 1), EDR(half_lives=(1.0, 3.8), color=color, fast=False)(clip)
    )


def test_kernels_run_on_torchs_thread_count_and_leave_it() -> None:
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        with torch.no_grad():
            EDR(color="gray")(_random_clip(torch.uint8, shape=(2, 3, 3, 8, 8)))
        assert torch.get_num_threads() == 1  # numba's OpenMP pool would otherwise reset it
        assert numba.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)


@pytest.mark.parametrize("fused", [True, False])
def test_reset_restarts_only_masked_rows(fused: bool) -> None:
    clip = _random_clip(torch.float32, seed=3, shape=(3, 8, 1, 4, 4))
    edr = EDR(half_lives=(3.8,), fast=fused)
    reset_at, reset_row = 5, 1
    with torch.no_grad():
        state, outs = None, []
        for t in range(clip.shape[1]):
            reset = torch.tensor([False, t == reset_at, False])
            out_t, state = edr.step(clip[:, t], state, reset=reset)
            outs.append(out_t)
        got = torch.stack(outs, 1)
        untouched = edr(clip)
        restarted = edr(clip[reset_row : reset_row + 1, reset_at:])
    torch.testing.assert_close(got[[0, 2]], untouched[[0, 2]])
    torch.testing.assert_close(got[reset_row, :reset_at], untouched[reset_row, :reset_at])
    torch.testing.assert_close(got[reset_row, reset_at:], restarted[0])
    # A restart sets the EMA to the frame itself: the ratio is 1, no events at that frame.
    assert got[reset_row, reset_at].abs().max() == 0
    assert not torch.equal(got[reset_row, reset_at:], untouched[reset_row, reset_at:])


def test_gradcheck_through_learnable_parameters() -> None:
    edr = EDR(
        half_lives=(1.5, 3.8),
        beta=(1.0, 0.8),
        nu_on=(0.01, 0.02),
        nu_off=(0.01, 0.03),
        learnable=True,
        out_dtype="float64",  # computes in float64 too, as gradcheck needs
    )
    edr = edr.double()
    names = ["log_tau", "beta", "nu_on", "nu_off"]
    params = tuple(getattr(edr, n).detach().clone().requires_grad_(True) for n in names)
    g = torch.Generator().manual_seed(0)
    clip = (
        20 + 200 * torch.rand((1, 4, 1, 3, 3), generator=g, dtype=torch.float64)
    ).requires_grad_(True)

    def fn(x, *p):
        return torch.func.functional_call(edr, dict(zip(names, p, strict=True)), (x,))

    assert torch.autograd.gradcheck(fn, (clip, *params), eps=1e-6, atol=1e-5)


def test_learnable_parameters_receive_gradients() -> None:
    edr = EDR(half_lives=(1.0, 3.8), learnable=True, nu_on=0.01, nu_off=0.01)
    clip = _random_clip(torch.float32, seed=4, shape=(1, 6, 1, 8, 8))
    edr(clip).sum().backward()
    for name in ("log_tau", "beta", "nu_on", "nu_off"):
        grad = getattr(edr, name).grad
        assert grad is not None and torch.isfinite(grad).all() and grad.abs().sum() > 0, name
    assert EDR(learnable=True).half_lives.min() > 0


def test_alpha_matches_the_paper() -> None:
    alpha = EDR(half_lives=(1.0, 3.8)).alpha
    assert alpha[0].item() == pytest.approx(0.5)
    assert alpha[1].item() == pytest.approx(1 - 2 ** (-1 / 3.8))
    assert alpha[1].item() == pytest.approx(0.166, abs=1e-3)


@pytest.mark.parametrize("fused", [True, False])
def test_brightening_gives_on_darkening_gives_off(fused: bool) -> None:
    edr = EDR(fast=fused)
    with torch.no_grad():
        up = edr(ramp_clip([50, 50, 100, 150]))
        down = edr(ramp_clip([150, 150, 100, 50]))
    on, off = 0, 1
    assert (up[0, 2:, on] > 0).all() and (up[0, :, off] == 0).all()
    assert (down[0, 2:, off] > 0).all() and (down[0, :, on] == 0).all()
    assert up[0, :2].abs().max() == 0  # a still pixel gives nothing
    # Known value: I=101, ema = 51 + alpha*(101-51) after one step from 51.
    alpha = 1 - 2 ** (-1 / 3.8)
    expected = 101 / (51 + alpha * 50) - 1.05
    assert up[0, 2, on, 0, 0].item() == pytest.approx(expected, rel=1e-5)


def test_channel_order_is_channel_then_timescale_then_on_off() -> None:
    clip = _random_clip(torch.float32, seed=5, shape=(1, 5, 3, 3, 3))
    taus = (1.0, 3.8)
    both = EDR(half_lives=taus)(clip)
    for c in range(3):
        for k, tau in enumerate(taus):
            single = EDR(half_lives=(tau,))(clip[:, :, c : c + 1])
            for p in range(2):
                torch.testing.assert_close(both[:, :, (c * len(taus) + k) * 2 + p], single[:, :, p])


def test_gray_option_equals_luma_input() -> None:
    clip = _random_clip(torch.float32, seed=6, shape=(1, 4, 3, 5, 5))
    luma = 0.299 * clip[:, :, 0:1] + 0.587 * clip[:, :, 1:2] + 0.114 * clip[:, :, 2:3]
    torch.testing.assert_close(EDR(color="gray")(clip), EDR()(luma))
    assert EDR(color="gray").out_channels(3) == 2
    assert EDR(half_lives=(1, 2, 3)).out_channels(3) == 18
    assert EDR(half_lives=(1, 2, 3), combine="sum").out_channels(1) == 2


@pytest.mark.parametrize(
    ("clip", "message"),
    [
        (torch.full((1, 3, 1, 4, 4), float("nan")), "NaN"),
        (-torch.ones((1, 3, 1, 4, 4)), "negative"),
        (torch.ones((3, 1, 4, 4)), "rank"),
        (torch.ones((1, 0, 1, 4, 4)), "empty"),
        (torch.ones((1, 3, 2, 4, 4)), "channels"),
        (torch.ones((1, 3, 1, 4, 4), dtype=torch.int32), "uint8 or floating"),
    ],
)
def test_bad_input_raises_value_error(clip: torch.Tensor, message: str) -> None:
    for fused in (True, False):
        with pytest.raises(ValueError, match=message), torch.no_grad():
            EDR(fast=fused)(clip)


def test_bad_configuration_raises_value_error() -> None:
    for kwargs in (
        {"half_lives": ()},
        {"half_lives": (0.0,)},
        {"threshold": "medium"},
        {"return_form": "diff"},
        {"combine": "mean"},
        {"nu_off": 1.0},
        {"half_lives": (1.0, 2.0), "beta": (1.0, 2.0, 3.0)},
        {"half_lives": (1.0, 2.0), "combine": "sum", "nu_on": (0.1, 0.2)},
        {"eps": -1.0},
    ):
        with pytest.raises(ValueError):
            EDR(**kwargs)


def test_step_rejects_mismatched_state_and_reset() -> None:
    edr = EDR()
    frame = torch.ones((2, 1, 4, 4))
    _, state = edr.step(frame)
    with pytest.raises(ValueError, match="state has shape"):
        edr.step(torch.ones((2, 1, 5, 4)), state)
    with pytest.raises(ValueError, match="one flag per batch row"):
        edr.step(frame, state, reset=torch.tensor([True, False, True]))


def test_zero_intensity_is_legal_with_eps() -> None:
    out = EDR(eps=1.0)(torch.zeros((1, 3, 1, 2, 2)))
    assert torch.isfinite(out).all()
    assert math.isclose(out.abs().max().item(), 0.0)


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_runs_on_gpu_like_on_cpu() -> None:
    clip = _random_clip(torch.float32, seed=7, shape=(2, 5, 3, 8, 8))
    edr = EDR(half_lives=(1.0, 3.8))
    with torch.no_grad():
        cpu = edr(clip)
        gpu = edr.cuda()(clip.cuda()).cpu()
    torch.testing.assert_close(gpu, cpu, rtol=1e-5, atol=1e-5)


def test_small_kernel_calls_run_on_one_thread_big_ones_on_torchs_count() -> None:
    """One numba thread below PARALLEL_MIN_PIXELS: a parallel launch's spinning worker would
    take more from the other core than it saves (a streaming env step of 16 Pong envs)."""
    from edr.representations import kernels

    before = torch.get_num_threads()
    seen = []

    def kernel(*args) -> None:
        seen.append(numba.get_num_threads())

    try:
        torch.set_num_threads(2)
        kernels.launch(kernel, kernels.PARALLEL_MIN_PIXELS - 1)
        kernels.launch(kernel, kernels.PARALLEL_MIN_PIXELS)
        assert seen == [1, min(2, numba.config.NUMBA_NUM_THREADS)]
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
