"""The vectorisable ln and exp of the training kernels against numpy's, in float32 and float64."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from edr.representations.vector_math import exp_into, log_into


@njit
def _log(x, out):
    log_into(x, out)


@njit
def _exp(x, out, scratch):
    exp_into(x, out, scratch)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_log_into_matches_numpy_over_forty_decades(dtype) -> None:
    x = np.logspace(-20, 20, 200_001).astype(dtype)
    out = np.empty_like(x)
    _log(x, out)
    want = np.log(x.astype(np.float64))
    tolerance = 2.5e-7 if dtype == np.float32 else 1e-15
    assert np.max(np.abs(out - want) / np.maximum(np.abs(want), 1.0)) < tolerance
    near_one = (1 + np.linspace(-0.01, 0.01, 20_001)).astype(dtype)  # where ln x is tiny
    _log(near_one, out[: near_one.size])
    assert np.max(np.abs(out[: near_one.size] - np.log(near_one.astype(np.float64)))) < 1e-8


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_exp_into_matches_numpy_and_may_write_over_its_input(dtype) -> None:
    x = np.linspace(-80, 80, 200_001).astype(dtype)
    out, scratch = np.empty_like(x), np.empty_like(x)
    _exp(x, out, scratch)
    want = np.exp(x.astype(np.float64))
    tolerance = 2e-7 if dtype == np.float32 else 1e-15
    assert np.max(np.abs(out - want) / want) < tolerance
    _exp(x, x, scratch)
    np.testing.assert_array_equal(x, out)


def test_exp_into_clamps_float32_to_normal_numbers() -> None:
    x = np.array([-200.0, 200.0], np.float32)
    out = np.empty_like(x)
    _exp(x, out, np.empty_like(x))
    assert 0 < out[0] < 1e-37 and np.isfinite(out[1]) and out[1] > 1e38
