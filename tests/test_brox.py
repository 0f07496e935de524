"""Brox flow (torch): shapes, the sign and size of a known translation, flips, determinism, a
constant image; and the ground-truth pairs that edr.studies.flows scores every flow on."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import torch

from edr.representations import BroxFlow, Farneback
from edr.studies.flows import endpoint_error, pair, sample_image, warp_field


@pytest.fixture(scope="module")
def translation() -> tuple[torch.Tensor, np.ndarray]:
    first, second, truth = pair(sample_image(), "translation")  # (2.3, -1.4) px
    clip = torch.from_numpy(np.stack([first, second]).round().astype(np.uint8))[None, :, None]
    return clip, truth  # (1, 2, 1, 240, 320) uint8, (2, 240, 320)


def test_a_known_translation_within_a_tenth_of_a_pixel_and_better_than_farneback(
    translation,
) -> None:
    clip, truth = translation
    flow = BroxFlow()(clip)
    assert flow.shape == (1, 1, 2, 240, 320) and flow.dtype == torch.float32
    estimate = flow[0, 0].numpy()
    inner = estimate[:, 20:-20, 20:-20]
    assert np.median(inner[0]) == pytest.approx(2.3, abs=0.02)  # dx: rightwards, unbiased
    assert np.median(inner[1]) == pytest.approx(-1.4, abs=0.02)  # dy: upwards
    brox = endpoint_error(estimate, truth)
    assert brox < 0.1
    assert brox < endpoint_error(Farneback()(clip)[0, 0].numpy(), truth)


def test_flip_negates_dx_and_runs_are_deterministic(translation) -> None:
    clip, _ = translation
    small = torch.from_numpy(
        np.stack(
            [cv2.resize(f, (96, 72), interpolation=cv2.INTER_AREA) for f in clip[0, :, 0].numpy()]
        )
    )[None, :, None]  # (1, 2, 1, 72, 96)
    brox = BroxFlow()
    flow, again = brox(small), brox(small)
    torch.testing.assert_close(flow, again, rtol=0, atol=0)
    flipped = brox(small.flip(-1))
    assert BroxFlow.hflip_negate == (0,)  # clips.py negates channel 0 when it flips a flow
    inner = (slice(None), slice(None), slice(8, -8), slice(8, -8))
    dx, dx_flipped = (float(f[:, :, 0][inner].median()) for f in (flow, flipped))
    assert dx > 0.5 and dx_flipped == pytest.approx(-dx, abs=0.1)


def test_batches_pairs_and_a_constant_image_has_no_motion() -> None:
    clip = torch.full((2, 3, 3, 40, 48), 128, dtype=torch.uint8)
    flow = BroxFlow()(clip)
    assert flow.shape == (2, 2, 2, 40, 48)
    assert torch.isfinite(flow).all() and flow.abs().max() < 1e-6


def test_settings_checked() -> None:
    with pytest.raises(ValueError, match="alpha"):
        BroxFlow(alpha=-1.0)
    with pytest.raises(ValueError, match="scale_factor"):
        BroxFlow(scale_factor=1.0)


@pytest.mark.parametrize("kind", ["rotation", "zoom", "smooth"])
def test_ground_truth_is_the_flow_from_the_first_frame(kind: str) -> None:
    """second(x + f(x)) reproduces first(x) better with the solved flow f than with the warp w
    that made second (they differ by up to 0.2 px here): f is the flow from the first frame."""
    first, second, truth = pair(sample_image(), kind)
    h, w = first.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    inner = (slice(20, -20), slice(20, -20))

    def residual(flow: np.ndarray) -> float:  # mean gray-level error, of 255
        back = cv2.remap(second, xx + flow[0], yy + flow[1], cv2.INTER_CUBIC)
        return float(np.abs(back - first)[inner].mean())

    field = warp_field(kind, h, w)
    assert 0.1 < np.abs(truth - field).max() < 0.3
    assert residual(truth) < residual(field) and residual(truth) < 2.0  # two bicubic resamplings


def test_flow_accuracy_writes_a_record_that_edr_tables_renders(tmp_path) -> None:
    """``python -m edr.studies.flows`` writes a record only; ``edr-tables`` renders it."""
    from edr import tables
    from edr.studies import flows

    flows.main(["--out-dir", str(tmp_path / "bench")])
    (record,) = (tmp_path / "bench").glob("flow_accuracy_*.json")
    assert [p.name for p in tmp_path.rglob("*.md")] == []
    tables.main(["--runs", str(tmp_path), "--bench", str(tmp_path / "bench"),
                 "--out", str(tmp_path / "paper")])  # fmt: skip
    text = (tmp_path / "paper" / "flow_accuracy.md").read_text()
    epe = json.loads(record.read_text())["epe"]
    assert f"| Brox | {epe['Brox']['translation']:.3f} |" in text and record.name in text
    assert epe["Brox"]["translation"] < 0.2  # a working Brox recovers a 2.7-pixel shift


def test_brox_refuses_intensities_far_outside_video_range() -> None:
    frames = torch.full((1, 2, 1, 16, 16), 1e38)
    with pytest.raises(ValueError, match="Brox expects video intensities"):
        BroxFlow()(frames)
