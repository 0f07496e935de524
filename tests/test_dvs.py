"""The simulated event camera and event binning."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from clips import ramp_clip, translating_clip
from edr.representations import DVSCamera, DVSSimulator
from edr.representations.dvs import EVENT_DTYPE


def _pixel(values: list[float]) -> np.ndarray:
    return np.array(values, dtype=np.float64).reshape(-1, 1, 1)


def test_brightening_fires_on_events_at_interpolated_times() -> None:
    sim = DVSSimulator(threshold_on=0.2, threshold_off=0.2, eps=1.0, fps=25)
    # ln(I + 1) rises by ln(3) ~ 1.0986 in one frame: floor(1.0986 / 0.2) = 5 ON events.
    events = sim.simulate(_pixel([99, 299]))
    assert events.dtype == EVENT_DTYPE
    assert len(events) == 5 and (events["p"] == 1).all()
    span = math.log(300) - math.log(100)
    expected = [math.floor(40_000 * 0.2 * k / span) for k in range(1, 6)]
    np.testing.assert_array_equal(events["t"], expected)
    assert np.all(np.diff(events["t"]) >= 0) and events["t"].max() < 40_000


def test_darkening_fires_off_events_and_reference_carries_over() -> None:
    sim = DVSSimulator(threshold_on=0.3, threshold_off=0.3)
    events = sim.simulate(_pixel([255, 200, 150, 150]))
    assert len(events) > 0 and (events["p"] == 0).all()
    total = math.log(256) - math.log(151)
    assert len(events) == int(total / 0.3)  # a sub-threshold remainder carries to the next frame


def test_refractory_period_drops_events() -> None:
    frames = _pixel([9, 999])
    free = DVSSimulator(threshold_on=0.1).simulate(frames)
    dead = DVSSimulator(threshold_on=0.1, refractory_us=20_000).simulate(frames)
    assert len(dead) < len(free)
    assert np.all(np.diff(dead["t"]) >= 20_000)


def test_mismatch_is_seeded_and_noise_fires_on_a_still_scene() -> None:
    frames = np.repeat(np.linspace(20, 200, 6)[:, None, None], 64, axis=2).repeat(8, axis=1)
    a = DVSSimulator(mismatch=0.3, seed=1).simulate(frames)
    b = DVSSimulator(mismatch=0.3, seed=1).simulate(frames)
    c = DVSSimulator(mismatch=0.3, seed=2).simulate(frames)
    np.testing.assert_array_equal(a, b)
    assert len(a) != len(c) or not np.array_equal(a, c)
    still = np.full((11, 8, 8), 100.0)
    assert len(DVSSimulator().simulate(still)) == 0
    noisy = DVSSimulator(shot_noise_hz=50.0).simulate(still)
    # 64 pixels x 50 Hz x 0.4 s = 1,280 expected noise events.
    assert 1_000 < len(noisy) < 1_600 and set(np.unique(noisy["p"])) == {0, 1}


def test_dvs_camera_on_off_order_matches_edr() -> None:
    up = DVSCamera()(ramp_clip([50, 100], height=2, width=2))
    assert up.shape == (1, 1, 2, 2, 2)
    assert (up[0, 0, 0] > 0).all() and (up[0, 0, 1] == 0).all()
    moving = DVSCamera(threshold_on=0.1, threshold_off=0.1)(translating_clip(frames=4))
    assert moving[:, :, 0].sum() > 0 and moving[:, :, 1].sum() > 0
    assert torch.equal(moving, moving.round())


@pytest.mark.parametrize("fps", [25.0, 30.0])  # 40,000 us a frame, and 33,333.3 us
def test_dvs_camera_bins_tile_by_tile_what_the_event_list_holds(monkeypatch, fps: float) -> None:
    """DVSCamera bins each frame interval's events, a few pixels at a time, as they come: the
    counts of the whole clip's event list, each event in the frame interval its integer time
    falls in (as ``events_to_frames`` bins them; at 30 fps, whose frame is not a whole number
    of microseconds, DVSCamera used to fail on one frame fewer from it)."""
    from edr.representations import dvs

    settings = {"mismatch": 0.1, "refractory_us": 300.0, "shot_noise_hz": 40.0, "fps": fps,
                "threshold_on": 0.1, "threshold_off": 0.15}  # fmt: skip
    clip = translating_clip(frames=7, height=12, width=16)  # (1, 7, 3, 12, 16) uint8
    gray = dvs.to_gray(clip, channel_dim=2)[0, :, 0].numpy()
    simulator = DVSSimulator(**settings)
    events = simulator.simulate(gray)
    expected = np.zeros((6, 2, 12, 16), np.float32)  # [ON, OFF] per frame interval
    interval = np.minimum(events["t"] // simulator.frame_us, 5).astype(np.int64)
    np.add.at(expected, (interval, 1 - events["p"].astype(np.int64), events["y"], events["x"]), 1)
    monkeypatch.setattr(dvs, "TILE_PIXELS", 7)  # tiles that cut rows
    tiled = DVSCamera(**settings)(clip)[0].numpy()  # (6, 2, 12, 16)
    assert expected.sum() == len(events) > 100
    np.testing.assert_array_equal(tiled, expected)
    if fps == 25.0:
        binned = dvs.events_to_frames(
            events, 12, 16, time_window=simulator.frame_us, start_time=0.0,
            end_time=6 * simulator.frame_us, dtype=np.float32,
        )  # fmt: skip
        np.testing.assert_array_equal(tiled, binned[:, ::-1])


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -1.0])
def test_the_simulator_refuses_frames_that_are_not_intensities(bad) -> None:

    frames = np.full((3, 4, 4), 100.0)
    frames[1, 2, 2] = bad
    with pytest.raises(ValueError, match="finite intensities >= 0"):
        DVSSimulator().simulate(frames)


def test_edr_refuses_a_meta_frame_and_a_nan_state() -> None:
    import torch

    from edr.representations import EDR

    edr = EDR()
    with pytest.raises(ValueError, match="meta device"):
        edr(torch.empty(1, 2, 1, 4, 4, device="meta"))
    _, state = edr.step(torch.full((1, 1, 4, 4), 100.0))
    state.ema[0, 0, 0, 1, 1] = float("nan")
    with pytest.raises(ValueError, match="state holds NaN"):
        edr.step(torch.full((1, 1, 4, 4), 100.0), state)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"events": "list"}, "structured numpy array"),
        ({"x": "float"}, "events x must be integers"),
        ({"t": "nan"}, "events t must be finite"),
        ({"n_time_bins": 1.5}, "n_time_bins must be a whole number"),
        ({"height": -1}, "height must be a positive integer"),
        ({"dtype": np.uint8}, "counts must not wrap"),
    ],
)
def test_events_to_frames_refuses_malformed_events_and_sizes(change, message) -> None:
    from edr.representations.dvs import events_to_frames

    t_type = np.float64 if change.get("t") == "nan" else np.int64
    x_type = np.float32 if change.get("x") == "float" else np.int16
    dtype = np.dtype([("t", t_type), ("x", x_type), ("y", np.int16), ("p", np.int8)])
    events = np.zeros(3, dtype)
    events["t"] = [0, 1, 2]
    if change.get("t") == "nan":
        events["t"][1] = np.nan
    given = events.tolist() if change.get("events") == "list" else events
    kwargs = {"n_time_bins": change.get("n_time_bins", 2), "dtype": change.get("dtype", np.int16)}
    with pytest.raises(ValueError, match=message):
        events_to_frames(given, change.get("height", 4), 4, **kwargs)
