"""The library's contract: every bad constructor argument and every non-finite input refused
with a message naming it, one output dtype policy on every path, and a streaming state that
``step`` never changes behind its caller's back."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from edr.representations import (
    EDR,
    FDR,
    TVL1,
    DVSCamera,
    DVSSimulator,
    Farneback,
    GrayDiff,
    RGBDiff,
)
from edr.representations.mpeg_flow import MPEGFlow

NAN, INF = float("nan"), float("inf")
BAD_ARGUMENTS = [
    (EDR, {"half_lives": NAN}, "half_lives=nan: expected a finite number"),
    (EDR, {"half_lives": [1.0, -2.0]}, "half_lives=.*each a number > 0"),
    (EDR, {"half_lives": "3.8"}, "half_lives='3.8'"),
    (EDR, {"beta": NAN}, "beta=nan: expected a finite number"),
    (EDR, {"beta": 0.0}, "beta=0.0: expected a number > 0"),
    (EDR, {"beta": -1}, "beta=-1: expected a number > 0"),
    (EDR, {"nu_on": -0.1}, "nu_on=-0.1: expected a number >= 0"),
    (EDR, {"nu_off": NAN}, "nu_off=nan: expected a finite number"),
    (EDR, {"nu_off": 1.0}, "nu_off=1.0: expected a number < 1"),
    (EDR, {"eps": 0.0}, "eps=0.0: expected a number > 0"),
    (EDR, {"eps": INF}, "eps=inf: expected a finite number"),
    (EDR, {"learnable": "yes"}, "learnable='yes': expected true or false"),
    (EDR, {"threshold": "medium"}, "threshold='medium': expected one of 'soft', 'hard'"),
    (EDR, {"out_dtype": "int8"}, "out_dtype='int8'"),
    (FDR, {"scale": -1.0}, "FDR: scale=-1.0: expected a number > 0"),
    (FDR, {"color": "sepia"}, "FDR: color='sepia'"),
    (GrayDiff, {"scale": NAN}, "GrayDiff: scale=nan"),
    (RGBDiff, {"scale": 0}, "RGBDiff: scale=0"),
    (Farneback, {"levels": 0}, "Farneback: levels=0: expected a number >= 1"),
    (Farneback, {"pyr_scale": 1.5}, "Farneback: pyr_scale=1.5: expected a number <= 1"),
    (TVL1, {"tau": -1.0}, "TVL1: tau=-1.0"),
    (DVSSimulator, {"fps": 0}, "DVSSimulator: fps=0: expected a number > 0"),
    (DVSSimulator, {"threshold_on": NAN}, "DVSSimulator: threshold_on=nan"),
    (DVSCamera, {"mismatch": -1.0}, "DVSSimulator: mismatch=-1.0"),
    (MPEGFlow, {"codec": 3}, "MPEGFlow: codec=3: expected a string"),
]


@pytest.mark.parametrize(("cls", "kwargs", "message"), BAD_ARGUMENTS, ids=lambda v: str(v)[:40])
def test_a_bad_argument_is_refused_by_name(cls, kwargs, message) -> None:
    with pytest.raises(ValueError, match=message):
        cls(**kwargs)


def test_a_scalar_half_life_is_one_timescale() -> None:
    clip = torch.randint(0, 256, (1, 4, 1, 5, 5), dtype=torch.uint8)
    assert EDR(half_lives=3.8).k == 1
    torch.testing.assert_close(EDR(half_lives=3.8)(clip), EDR(half_lives=[3.8])(clip))


@pytest.mark.parametrize("fast", [True, False])
@pytest.mark.parametrize(("value", "message"), [(NAN, "NaN"), (INF, "inf"), (-INF, "inf")])
def test_non_finite_frames_are_refused(fast, value, message) -> None:
    clip = torch.full((1, 3, 1, 4, 4), 50.0)
    clip[0, 1, 0, 2, 2] = value
    with torch.no_grad(), pytest.raises(ValueError, match=message):
        EDR(fast=fast)(clip)
    with pytest.raises(ValueError, match=message):
        EDR(fast=fast)(torch.full((1, 2, 1, 3, 3), value))  # all of it
    with pytest.raises(ValueError, match=message):
        FDR()(clip)


INPUT_DTYPES = [torch.uint8, torch.float16, torch.bfloat16, torch.float32, torch.float64]


@pytest.mark.parametrize("dtype", INPUT_DTYPES, ids=str)
@pytest.mark.parametrize("grad", [False, True], ids=["no_grad", "autograd"])
def test_every_path_returns_float32(dtype, grad) -> None:
    clip = torch.randint(0, 256, (1, 4, 3, 6, 6)).to(dtype)
    with torch.set_grad_enabled(grad):
        for rep in (EDR(), EDR(learnable=grad), EDR(fast=False), FDR(), GrayDiff(), RGBDiff()):
            assert rep(clip).dtype == torch.float32, (type(rep).__name__, dtype)
        out, state = EDR().step(clip[:, 0])
        assert out.dtype == torch.float32 and state.ema.dtype == torch.float32


def test_out_dtype_is_the_same_on_both_paths() -> None:
    clip = torch.randint(0, 256, (2, 5, 1, 6, 6), dtype=torch.uint8)
    with torch.no_grad():
        reference = EDR()(clip)
        for fast in (True, False):
            half = EDR(out_dtype="float16", fast=fast)(clip)
            assert half.dtype == torch.float16
            torch.testing.assert_close(half.float(), reference, rtol=2e-3, atol=2e-3)
    assert EDR(out_dtype="float64")(clip.double()).dtype == torch.float64


@pytest.mark.parametrize("fast", [True, False])
def test_step_leaves_the_callers_state_alone(fast) -> None:
    frames = torch.randint(0, 256, (3, 2, 1, 5, 5), dtype=torch.uint8)
    edr = EDR(half_lives=(1.0, 3.8), fast=fast)
    with torch.no_grad():
        _, state = edr.step(frames[0])
        kept = state.ema.clone()
        first, after = edr.step(frames[1], state)
        again, _ = edr.step(frames[1], state)  # branch from the same state: the same result
        assert torch.equal(state.ema, kept) and after.ema is not state.ema
        torch.testing.assert_close(first, again)
        _, owned = edr.step(frames[2], after, inplace=True)
        if fast:  # the fused path writes into the caller's own buffer when asked to
            assert owned.ema.data_ptr() == after.ema.data_ptr()


def test_streaming_equals_the_whole_clip_with_and_without_inplace() -> None:
    clip = torch.randint(0, 256, (2, 6, 3, 5, 7), dtype=torch.uint8)
    edr = EDR(half_lives=(1.0, 3.8), color="gray")
    with torch.no_grad():
        whole = edr(clip)
        for inplace in (False, True):
            state, outs = None, []
            for t in range(clip.shape[1]):
                out, state = edr.step(clip[:, t], state, inplace=inplace)
                outs.append(out)
            torch.testing.assert_close(torch.stack(outs, 1), whole)


def test_black_pixels_are_finite_on_both_paths_and_in_gradients() -> None:
    clip = torch.zeros((1, 3, 1, 2, 2))
    clip[0, 2] = 100.0
    with torch.no_grad():
        fast = EDR()(clip)
    slow = EDR(fast=False)(clip)
    torch.testing.assert_close(fast, slow)
    learnable = EDR(learnable=True)
    learnable(clip).sum().backward()
    assert all(math.isfinite(p.grad.abs().sum().item()) for p in learnable.parameters())
    assert np.isfinite(fast.numpy()).all()


def test_several_python_threads_may_call_the_fused_kernels_at_once() -> None:
    """numba's OpenMP layer is thread-safe; the results must not mix."""
    from concurrent.futures import ThreadPoolExecutor

    clip = torch.randint(0, 256, (2, 6, 3, 16, 20), dtype=torch.uint8)
    edr = EDR(half_lives=(1.0, 3.8))
    with torch.no_grad():
        expected = edr(clip)

        def work(_: int) -> torch.Tensor:
            with torch.no_grad():
                return edr(clip)

        with ThreadPoolExecutor(4) as pool:
            results = list(pool.map(work, range(16)))
    assert all(torch.equal(r, expected) for r in results)
