"""``events_to_frames`` bins events exactly as tonic's ``ToFrame`` does (tonic is a test
dependency), and refuses events it cannot bin with a message that names the field."""

from __future__ import annotations

import numpy as np
import pytest
import tonic

from edr.representations import DVSSimulator, events_to_frames
from edr.representations.dvs import EVENT_DTYPE

H, W = 6, 9
SETTINGS = [
    {"time_window": 1000},
    {"time_window": 1000, "include_incomplete": True},
    {"time_window": 1000, "overlap": 250},
    {"time_window": 1000, "overlap": 250, "include_incomplete": True},
    {"time_window": 1000, "start_time": 0, "end_time": 60_000},
    {"event_count": 37},
    {"event_count": 37, "include_incomplete": True},
    {"event_count": 37, "overlap": 5},
    {"n_time_bins": 7},
    {"n_time_bins": 7, "overlap": 0.2},
    {"n_event_bins": 5},
    {"n_event_bins": 5, "overlap": 0.1},
]


def _events(t: list[int] | np.ndarray, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    events = np.zeros(len(t), EVENT_DTYPE)
    events["t"] = t
    events["x"] = rng.integers(0, W, len(t))
    events["y"] = rng.integers(0, H, len(t))
    events["p"] = rng.integers(0, 2, len(t))
    return events


def _tonic(events: np.ndarray, **settings) -> np.ndarray:
    return tonic.transforms.ToFrame(sensor_size=(W, H, 2), **settings)(events.copy())


@pytest.mark.parametrize(
    "settings", SETTINGS, ids=lambda s: ",".join(f"{k}={v}" for k, v in s.items())
)
@pytest.mark.parametrize("seed", [0, 1])
def test_random_events_bin_as_tonic_bins_them(settings, seed) -> None:
    rng = np.random.default_rng(seed)
    events = _events(np.sort(rng.integers(0, 50_000, 1000)), seed)
    ours, theirs = events_to_frames(events, H, W, **settings), _tonic(events, **settings)
    assert ours.dtype == theirs.dtype == np.int16
    np.testing.assert_array_equal(ours, theirs)


def test_hand_built_edges_match_tonic() -> None:
    ends = _events([0, 33, 66, 99])  # n_time_bins=3: bins [0, 33), [33, 66), [66, 99)
    assert events_to_frames(ends, H, W, n_time_bins=3).sum(axis=(1, 2, 3)).tolist() == [1, 1, 1]
    steady = _events(np.arange(100))
    for settings in ({"time_window": 10}, {"time_window": 10, "include_incomplete": True},
                     {"event_count": 12}, {"event_count": 12, "include_incomplete": True}):  # fmt: skip
        ours = events_to_frames(steady, H, W, **settings)
        np.testing.assert_array_equal(ours, _tonic(steady, **settings))
    assert len(events_to_frames(steady, H, W, time_window=10)) == 9  # the last, partial one dropped
    assert len(events_to_frames(steady, H, W, time_window=10, include_incomplete=True)) == 10
    edge = _events([0, 10, 20])  # t = 10 opens the second window
    assert events_to_frames(edge, H, W, time_window=10).sum(axis=(1, 2, 3)).tolist() == [1, 1]


def test_the_simulators_events_go_to_tonic_as_they_are() -> None:
    rng = np.random.default_rng(3)
    video = rng.uniform(20, 220, (6, H, W)).round()
    sim = DVSSimulator(threshold_on=0.1, threshold_off=0.1)
    events = sim.simulate(video)
    assert events.dtype.names == ("t", "x", "y", "p") and len(events) > 10
    np.testing.assert_array_equal(
        events_to_frames(events, H, W, time_window=sim.frame_us),
        _tonic(events, time_window=sim.frame_us),
    )
    frames = events_to_frames(events, H, W, time_window=sim.frame_us, dtype=np.float32)
    assert frames.dtype == np.float32


def test_polarity_minus_one_is_off() -> None:
    events = _events([0, 1, 2, 3])
    events["p"] = [1, 0, 1, 0]
    signed = events.copy()
    signed["p"] = [1, -1, 1, -1]
    np.testing.assert_array_equal(
        events_to_frames(signed, H, W, event_count=4), events_to_frames(events, H, W, event_count=4)
    )


@pytest.mark.parametrize(
    ("field", "values", "message"),
    [
        ("p", [0, 2, 1, 0], "events p must be 0/1, -1/1 or bool"),
        ("x", [0, -1, 1, 2], r"events x must lie in \[0, 9\)"),
        ("y", [0, 1, 6, 2], r"events y must lie in \[0, 6\)"),
        ("t", [0, 20, 10, 30], "events t must be sorted"),
    ],
)
def test_bad_events_are_refused_by_name(field, values, message) -> None:
    events = _events([0, 10, 20, 30])
    events[field] = values
    with pytest.raises(ValueError, match=message):
        events_to_frames(events, H, W, time_window=10)


def test_bad_settings_are_refused() -> None:
    events = _events([0, 10, 20, 30])
    with pytest.raises(ValueError, match="exactly one"):
        events_to_frames(events, H, W)
    with pytest.raises(ValueError, match="overlap"):
        events_to_frames(events, H, W, time_window=10, overlap=10)
    with pytest.raises(ValueError, match="missing"):
        events_to_frames(np.zeros(3, [("t", np.int64), ("x", np.int16)]), H, W, time_window=10)
