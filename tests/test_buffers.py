"""``out=`` on the fused representations, and big outputs recycled once their caller drops them."""

from __future__ import annotations

import pytest
import torch

from edr.representations import EDR, GrayDiff
from edr.representations.buffers import Recycler


@pytest.fixture
def clip() -> torch.Tensor:
    torch.manual_seed(0)
    return torch.randint(0, 256, (2, 5, 3, 12, 16), dtype=torch.uint8)


@pytest.mark.parametrize("out_dtype", ["float32", "float16"])
def test_edr_forward_and_step_write_into_out(clip, out_dtype) -> None:
    edr = EDR(color="gray", out_dtype=out_dtype)
    expected = edr(clip)
    out = torch.full_like(expected, 7)
    with torch.no_grad():
        assert edr(clip, out=out) is out
    torch.testing.assert_close(out, expected)
    frame_out = torch.empty_like(expected[:, 0])
    events, state = edr.step(clip[:, 0], out=frame_out)
    assert events.data_ptr() == frame_out.data_ptr()
    torch.testing.assert_close(frame_out, expected[:, 0])
    events, _ = edr.step(clip[:, 1], state, out=frame_out)
    torch.testing.assert_close(frame_out, expected[:, 1])


def test_out_on_the_torch_path_and_wrong_out_refused(clip) -> None:
    edr = EDR(color="gray", fast=False)
    out = torch.empty(2, 5, 2, 12, 16)
    assert edr(clip, out=out) is out
    torch.testing.assert_close(out, EDR(color="gray")(clip))
    with pytest.raises(ValueError, match=r"\(2, 5, 2, 12, 16\)"):
        EDR(color="gray")(clip, out=torch.empty(2, 5, 6, 12, 16))
    with pytest.raises(ValueError, match=r"torch\.float16"):
        EDR(color="gray", out_dtype="float16")(clip, out=out)


def test_gray_diff_writes_into_out(clip) -> None:
    expected = GrayDiff()(clip)
    out = torch.empty_like(expected)
    assert GrayDiff()(clip, out=out) is out
    torch.testing.assert_close(out, expected)
    slow = torch.empty_like(expected)
    assert GrayDiff(fast=False)(clip, out=slow) is slow
    torch.testing.assert_close(slow, expected)


def test_recycler_reuses_memory_only_once_every_view_is_gone() -> None:
    pool = Recycler(limit_bytes=1 << 20, min_bytes=1 << 10)
    first = pool.empty((64, 64))  # 16 KiB
    address = first.data_ptr()
    view = first[1:]
    del first
    second = pool.empty((64, 64))
    assert second.data_ptr() != address  # a view of the first is alive: not handed out twice
    del view
    assert pool.free_bytes == 64 * 64 * 4
    third = pool.empty((64, 64))
    assert third.data_ptr() == address and pool.free_bytes == 0  # reused
    small = pool.empty((4, 4))
    del small
    assert pool.free_bytes == 0  # below min_bytes: plain allocations
    del second, third
    assert pool.free_bytes == 2 * 64 * 64 * 4
    big = pool.empty((512, 512))  # 1 MiB: holding it and the two others would pass the limit
    del big
    assert pool.free_bytes <= 1 << 20
    pool.clear()
    assert pool.free_bytes == 0


def test_a_plain_call_reuses_its_dropped_output() -> None:
    edr = EDR(color="gray")
    clip = torch.randint(0, 256, (1, 40, 3, 120, 160), dtype=torch.uint8)  # 6 MB of events
    first = edr(clip)
    address, expected = first.data_ptr(), first.clone()
    del first
    again = edr(clip)
    assert again.data_ptr() == address
    torch.testing.assert_close(again, expected)
