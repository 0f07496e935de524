"""Atari envs through ale-py and torchrl, and EDR as a streaming torchrl transform."""

from __future__ import annotations

import multiprocessing
import signal
import sys
from pathlib import Path
from typing import Any

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import check_env_specs

from edr.checks import interrupts
from edr.representations import EDR
from edr.rl.envs import EnvPoolAtari, gym_atari, gym_image_env, make_atari_env
from edr.rl.transform import ObservationFrame


def _frame_transform(env) -> ObservationFrame:
    (found,) = [t for t in env.transform if isinstance(t, ObservationFrame)]
    return found


@pytest.mark.parametrize(
    ("backend", "num_envs"), [("single", 1), ("serial", 2), ("parallel", 2), ("envpool", 2)]
)
def test_env_specs_hold_with_edr(backend: str, num_envs: int) -> None:
    env = make_atari_env("Pong", num_envs=num_envs, backend=backend, edr=EDR(color="gray"))
    try:
        check_env_specs(env)
        batch = () if backend == "single" else (num_envs,)
        assert env.observation_spec["observation"].shape == (*batch, 3 + 2, 84, 84)
        assert env.observation_spec["edr"].shape == (*batch, 2, 84, 84)
    finally:
        env.close()


@pytest.mark.slow  # 14 s in a fresh clone (the gray frame kernel compiles)
def test_observation_combinations() -> None:
    for fdr, edr, channels in (
        ("gray", None, 1),
        ("none", EDR(half_lives=(1, 3.8), color="gray"), 4),
    ):
        env = make_atari_env("Pong", backend="single", fdr=fdr, edr=edr)
        assert env.reset()["observation"].shape == (channels, 84, 84)
        env.close()
    with pytest.raises(ValueError, match="FDR, EDR or both"):
        make_atari_env("Pong", backend="single", fdr="none", edr=None)


def test_presets() -> None:
    paac, v5 = gym_atari("Breakout", "paac"), gym_atari("Breakout", "v5")
    assert paac.observation_space.shape == v5.observation_space.shape == (84, 84, 3)
    assert (
        paac.unwrapped._frameskip == 1 and v5.unwrapped._frameskip == 4
    )  # paac skips in the wrapper
    with pytest.raises(ValueError, match="preset"):
        gym_atari("Pong", "v4")


def test_transform_equals_edr_step_on_the_same_frames() -> None:
    env = make_atari_env("Pong", backend="single", fdr="none", edr=EDR(color="gray"))
    env.set_seed(0)
    rollout = env.rollout(25, break_when_any_done=False)
    env.close()
    frames = torch.cat([rollout["pixels"][:1], rollout["next", "pixels"]]).permute(
        0, 3, 1, 2
    )  # (T+1, 3, H, W)
    expected = EDR(color="gray")(frames.unsqueeze(0))[0]  # (T+1, 2, H, W)
    got = torch.cat([rollout["edr"][:1], rollout["next", "edr"]])
    torch.testing.assert_close(got, expected)
    assert got[1:].abs().sum() > 0  # Pong's ball and paddles move


@pytest.mark.parametrize("mode", ["serial", "envpool"])
def test_partial_reset_restarts_only_that_env(mode: str) -> None:
    env = make_atari_env("Pong", num_envs=3, backend=mode, fdr="none", edr=EDR(color="gray"))
    env.set_seed(1)
    rollout = env.rollout(6, break_when_any_done=False)
    transform = _frame_transform(env)
    ema_before, last_before = transform._ema.clone(), transform._last.clone()
    mask = torch.tensor([[False], [True], [False]])
    # As a collector does: the current step's data, with the flag of the env that ended.
    out = env.reset(rollout[:, -1]["next"].clone().set("_reset", mask))
    ema_after = transform._ema.view(3, 1, 1, 84, 84)
    ema_before = ema_before.view(3, 1, 1, 84, 84)
    torch.testing.assert_close(ema_after[[0, 2]], ema_before[[0, 2]])  # untouched
    torch.testing.assert_close(transform._last[[0, 2]], last_before[[0, 2]])
    torch.testing.assert_close(out["edr"][[0, 2]], last_before[[0, 2]])
    pixels = out["pixels"][1].permute(2, 0, 1).float()  # (3, H, W)
    luma = 0.299 * pixels[0] + 0.587 * pixels[1] + 0.114 * pixels[2] + 1.0
    torch.testing.assert_close(ema_after[1, 0, 0], luma)  # restarted from its new first frame
    assert out["edr"][1].abs().max() == 0
    assert not torch.equal(ema_after[1], ema_before[1])
    env.close()


@pytest.mark.parametrize("fdr", ["gray", "rgb"])
def test_frames_restart_per_env_and_are_channels_last(fdr: str) -> None:
    env = make_atari_env("Pong", num_envs=3, backend="serial", fdr=fdr, edr=EDR(color="gray"))
    env.set_seed(2)
    rollout = env.rollout(5, break_when_any_done=False)  # (3 envs, 5 steps)
    frames = rollout["next", "observation"]  # (3, 5, C + 2, H, W)
    torch.testing.assert_close(
        frames, torch.cat([rollout["next", "fdr"], rollout["next", "edr"]], 2)
    )
    mask = torch.tensor([[False], [True], [False]])
    out = env.reset(rollout[:, -1]["next"].clone().set("_reset", mask))
    # channels-last in memory, as the network's trunk convolves it: it takes the frame uncopied
    assert out["observation"].is_contiguous(memory_format=torch.channels_last)
    torch.testing.assert_close(out["observation"][[0, 2]], frames[[0, 2], -1])  # kept
    assert not out["edr"][1].any()  # env 1 restarted: its EMA starts from this frame, no events
    env.close()


def test_a_frame_ring_gives_the_same_frames_and_autograd_refuses_an_overwritten_one() -> None:
    frames, copies = {}, {}
    for ring in (None, 3):
        env = make_atari_env("Pong", num_envs=2, backend="serial", edr=EDR(color="gray"),
                             frame_ring=ring)  # fmt: skip
        env.set_seed(4)
        torch.manual_seed(4)  # the same random actions
        td, emitted, copies[ring] = env.reset(), [], []
        for _ in range(7):
            td = env.step_and_maybe_reset(td.set("action", env.action_spec.rand()))[1]
            emitted.append(td["observation"])
            copies[ring].append(td["observation"].clone())  # before the ring comes round to it
            assert emitted[-1].is_contiguous(memory_format=torch.channels_last)
        frames[ring] = emitted
        env.close()
    ringed = frames[3]
    assert ringed[0].data_ptr() == ringed[3].data_ptr() == ringed[6].data_ptr()  # reused
    torch.testing.assert_close(copies[3], copies[None])  # each step's frame, as it was emitted
    assert len({s.data_ptr() for s in frames[None]}) == 7  # without a ring: a new one each step

    env = make_atari_env("Pong", num_envs=2, backend="serial", edr=EDR(color="gray"), frame_ring=2)
    td = env.reset()
    td = env.step_and_maybe_reset(td.set("action", env.action_spec.rand()))[1]
    weight = torch.ones(1, 5, 1, 1, requires_grad=True)
    loss = torch.nn.functional.conv2d(td["observation"], weight).sum()  # saves the frame
    for _ in range(2):  # the ring comes round to it
        td = env.step_and_maybe_reset(td.set("action", env.action_spec.rand()))[1]
    env.close()
    with pytest.raises(RuntimeError, match="modified by an inplace operation"):
        loss.backward()
    with pytest.raises(ValueError, match="2 buffers or more"):
        ObservationFrame(ring=1)


def test_float16_observation_is_the_float32_one_rounded() -> None:
    observations = {}
    for dtype in ("float32", "float16"):
        env = make_atari_env(
            "Pong", num_envs=2, backend="serial", edr=EDR(color="gray"), obs_dtype=dtype
        )
        check_env_specs(env)
        env.set_seed(3)
        torch.manual_seed(3)  # the same random actions
        observations[dtype] = env.rollout(4)["next", "observation"]  # (2, 4, 5, H, W)
        assert env.observation_spec["observation"].dtype == getattr(torch, dtype)
        env.close()
    assert observations["float16"].dtype == torch.float16
    torch.testing.assert_close(observations["float16"], observations["float32"].half())
    with pytest.raises(ValueError, match="obs_dtype"):
        make_atari_env("Pong", backend="single", obs_dtype="int8")


def test_transform_is_not_for_stored_data() -> None:
    with pytest.raises(NotImplementedError, match="stateful"):
        ObservationFrame(edr=EDR(color="gray"))(
            TensorDict({"pixels": torch.zeros(2, 8, 8, 3, dtype=torch.uint8)}, batch_size=[2])
        )


def test_envpool_resets_only_the_flagged_env_and_plays_the_paac_preset() -> None:
    env = EnvPoolAtari("Pong", num_envs=2)
    env.set_seed(3)
    td = env.reset()
    assert td["pixels"].shape == (2, 84, 84, 3) and td["pixels"].dtype == torch.uint8
    action = torch.zeros(2, 6, dtype=torch.bool)
    action[:, 0] = True
    for _ in range(5):
        out = env.step(td.set("action", action))["next"]
    before = out["pixels"].clone()
    reset = env.reset(out.clone().set("_reset", torch.tensor([[True], [False]])))
    torch.testing.assert_close(reset["pixels"][1], before[1])  # env 1 untouched
    assert not reset["done"].any()
    env.close()


@pytest.mark.parametrize("backend", ["serial", "batch"])
def test_own_gymnasium_env_with_image_frames(monkeypatch, backend: str) -> None:
    monkeypatch.syspath_prepend(str(Path(__file__).parent))
    env = make_atari_env(
        "EdrCatch-v0", preset="none", module="catch_game", num_envs=2, backend=backend,
        edr=EDR(color="gray"), keep_inputs=False,
    )  # fmt: skip
    check_env_specs(env)
    rollout = env.rollout(12, break_when_any_done=False)
    assert rollout["next", "observation"].shape == (2, 12, 3 + 2, 84, 84)
    assert "pixels" not in rollout and "edr" not in rollout["next"]
    assert set(rollout["next", "reward"].unique().tolist()) <= {-1.0, 0.0, 1.0}
    env.close()
    with pytest.raises(ValueError, match="envpool plays ALE games only"):
        make_atari_env("EdrCatch-v0", preset="none", module="catch_game", backend="envpool")
    with pytest.raises(ValueError, match="RGB image observations"):
        gym_image_env("CartPole-v1")


def _sigterm_after_a_serial_env(tests: str, answer: Any) -> None:
    """In a child process (as a parallel sweep's job is): SIGTERM's handler after a serial env
    of two games is made, stepped and closed."""
    sys.path.insert(0, tests)
    interrupts.install()
    env = make_atari_env("EdrCatch-v0", preset="none", module="catch_game", num_envs=2,
                         backend="serial", edr=None, fdr="gray")  # fmt: skip
    env.rollout(2)
    env.close()
    answer.put(signal.getsignal(signal.SIGTERM) is interrupts._on_signal)


def test_a_serial_env_in_a_child_process_leaves_its_stop_signals_alone() -> None:
    """A job of ``hydra/launcher=parallel`` runs in a worker process; its serial env's games once
    set SIGTERM and Ctrl-C to be ignored there (only a ParallelEnv's own workers should), so
    the sweep's stop never reached a running Atari job and it trained on."""
    context = multiprocessing.get_context("spawn")
    answer = context.Queue()
    child = context.Process(
        target=_sigterm_after_a_serial_env, args=(str(Path(__file__).parent), answer)
    )
    child.start()
    child.join(120)
    assert child.exitcode == 0 and answer.get(timeout=5) is True


@pytest.mark.parametrize("mode", ["serial", "envpool"])  # pixels interleaved, pixels planar
@pytest.mark.parametrize(
    ("fdr", "edr"),
    [
        ("rgb", {"color": "gray"}),
        ("gray", {}),
        ("none", {"half_lives": (1, 3.8), "combine": "sum", "return_form": "log",
                  "threshold": "hard"}),
        ("rgb", None),
    ],
)  # fmt: skip
def test_one_pass_frame_equals_fdr_and_edr_step_by_torch(mode: str, fdr: str, edr) -> None:
    """The fused kernel's frames equal torch's path (EDR(fast=False)): FDR / 255 then EDR's
    events, per env, across a partial reset; FDR's channels are the pixels / 255 themselves."""
    frames = []
    for fast in (True, False):
        env = make_atari_env(
            "Pong",
            num_envs=2,
            backend=mode,
            fdr=fdr,
            edr=None if edr is None else EDR(**edr, fast=fast),
        )
        env.set_seed(5)
        torch.manual_seed(5)
        rollout = env.rollout(6, break_when_any_done=False)
        out = env.reset(
            rollout[:, -1]["next"].clone().set("_reset", torch.tensor([[True], [False]]))
        )
        frames.append(torch.cat([rollout["next", "observation"], out["observation"][:, None]], 1))
        env.close()
    torch.testing.assert_close(frames[0], frames[1])
    if fdr == "rgb":
        pixels = rollout["next", "pixels"].permute(0, 1, 4, 2, 3).float() / 255
        torch.testing.assert_close(frames[0][:, :6, :3], pixels, rtol=0, atol=0)
    assert frames[0][:, 1:, -2:].abs().sum() > 0 or edr is None  # the events of moving things


def test_a_closed_env_leaves_torchs_thread_count_as_it_found_it(monkeypatch) -> None:
    """torchrl's batched envs add their workers to torch's threads on close, up to the count
    torch had when torchrl was imported: a run's ``threads=1`` became 2 for its evaluation."""
    import torchrl

    threads = torch.get_num_threads()
    monkeypatch.setattr(torchrl, "_THREAD_POOL_INIT", threads + 4)  # torch started with more
    env = make_atari_env(game="Pong", num_envs=2, backend="serial", fdr="gray")
    env.reset()
    env.close()
    assert torch.get_num_threads() == threads
