"""Issue 71, items 2 and 5 for values: every value a user gives (an override, an environment
variable, an edr-bench flag) is refused in one line naming it, before any work, by class: game
and env ids, numbers out of range or of the wrong kind, interpolations that do not resolve,
videos that are no video, sizes past the memory available. The issue's own cases first, then
held-out ones of the same classes. In process (a subprocess costs seconds), but for a few."""

from __future__ import annotations

import errno
from pathlib import Path

import numpy as np
import pytest
import torch

from edr.checks.command_line import check_command_line
from edr.checks.config import Allocation, ConfigError, check_allocations, check_config
from edr.data.datasets import kth
from edr.data.synthetic import write_synthetic_kth
from edr.data.video import write_video
from edr.representations import EDR, EDRState
from edr.run import CONF_DIR, ENTRY_KEYS
from edr.studies import bench


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    """Broken inputs: videos of 0 bytes, text, one frame, cut; a folder; a symbolic-link loop."""
    root = tmp_path_factory.mktemp("files")
    (root / "empty.avi").write_bytes(b"")
    (root / "text.avi").write_text("this is not a video\n" * 20)
    write_video(root / "one.avi", np.zeros((1, 3, 32, 32), np.uint8))
    whole = write_video(root / "whole.avi", np.zeros((6, 3, 32, 32), np.uint8)).read_bytes()
    (root / "cut.avi").write_bytes(whole[: len(whole) // 2])
    (root / "folder.avi").mkdir()
    (root / "loop_a").symlink_to(root / "loop_b")
    (root / "loop_b").symlink_to(root / "loop_a")
    return {p.stem: p for p in root.iterdir()}


def _refused(*argv: str) -> str:
    """What ``edr-run argv`` says before Hydra starts (its one line), asserting it is one."""
    with pytest.raises(ConfigError) as refused:
        check_command_line(list(argv), CONF_DIR, lambda cfg: check_config(cfg, entry=ENTRY_KEYS))
    message = str(refused.value)
    assert "\n" not in message and "Traceback" not in message
    return message


# ---- edr-run overrides: (argv, what the line says) -----------------------------------------
ATARI = ("task=atari", "debug=tiny")
KTH = ("task=kth", "debug=tiny")
ISSUE_OVERRIDES = {
    "lower-case game": ((*ATARI, "task.env.game=pong"), "case-sensitive): Pong"),
    "a ROM with no single-player env": ((*ATARI, "task.env.game=Joust"), "no single-player env"),
    "Warlords on envpool": (
        (*ATARI, "task.env.game=Warlords", "task.env.backend=envpool"),
        "task.env.game='Warlords'",
    ),
    "Combat on serial": (
        (*ATARI, "task.env.game=Combat", "task.env.backend=serial"),
        "task.env.game='Combat'",
    ),
    "an unregistered env id": (
        (*ATARI, "task.env.env_id=NoSuch-v0", "task.env.preset=none"),
        "task.env.env_id='NoSuch-v0': expected a gymnasium env id registered here",
    ),
    "a gymnasium env without frames": (
        (*ATARI, "task.env.env_id=CartPole-v1", "task.env.preset=none"),
        "task.env.env_id='CartPole-v1': expected an env of RGB image observations (H, W, 3) "
        "uint8, as task.env.preset=none plays; it observes Box(4,) float32",
    ),
    "an unset environment variable": ((*KTH, "threads=${oc.env:UNSET}"), "variable UNSET"),
    "the task deleted": ((*KTH, "~task"), "~task: a run needs its task"),
    "eps that erases every event": (
        (*KTH, "representation.eps=1e308"),
        "eps=1e+308: expected at most 4845",
    ),
    "a half-life of 1e-300": (
        (*KTH, "representation.half_lives=[1e-300]"),
        "expected each at least 0.0817 frames",
    ),
    "a half-life of 1e300": (
        (*KTH, "representation.half_lives=[1e300]"),
        "expected each at most 1.16e+07 frames",
    ),
}
NEW_OVERRIDES = {
    "a frame stack no memory holds": (
        (*ATARI, "task.env.frame_stack=100000"),
        "task.env.frame_stack=100000: the 100005 observations each of the 4 envs holds would take",
    ),
    "more envs than memory holds": (
        (*ATARI, "task.env.num_envs=10000000"),
        "task.env.num_envs=10000000, task.loss.rollout_steps=5",
    ),
    "more evaluation games than memory holds": (
        (*ATARI, "task.evaluation.plays=100000000"),
        "task.evaluation.plays=100000000, task.env.frame_stack=4: one step's input",
    ),
    "upper-case game": ((*ATARI, "task.env.game=PONG"), "case-sensitive): Pong"),
    "snake-case game": ((*ATARI, "task.env.game=ms_pacman"), "case-sensitive): MsPacman"),
    "lower-case two-word game": ((*ATARI, "task.env.game=spaceinvaders"), "SpaceInvaders"),
    "a gymnasium id for a game": ((*ATARI, "task.env.game=Pong-v5"), "expected an ALE game"),
    "an empty game": ((*ATARI, "task.env.game=''"), "expected an ALE game (one of"),
    "a number for a game": ((*ATARI, "task.env.game=42"), "task.env.game=42: expected a string"),
    "another ROM without an env": ((*ATARI, "task.env.game=MazeCraze"), "no single-player env"),
    "an env id in the wrong case": (
        (*ATARI, "task.env.env_id=cartpole-v1", "task.env.preset=none"),
        "did you mean CartPole-v1",
    ),
    "an ALE id that does not exist": (
        (*ATARI, "task.env.env_id=ALE/NoSuch-v5", "task.env.preset=none"),
        "env_id='ALE/NoSuch-v5'",
    ),
    "an env of continuous actions without frames": (
        (*ATARI, "task.env.env_id=Pendulum-v1", "task.env.preset=none"),
        "it observes Box(3,) float32",
    ),
    "a board game's cell for frames": (
        (*ATARI, "task.env.env_id=FrozenLake-v1", "task.env.preset=none"),
        "it observes Discrete() int64",
    ),
    "an own env its module does not register": (
        (
            *ATARI,
            "task.env.env_id=NoSuch-v0",
            "task.env.env_module=edr.rl.games",
            "task.env.preset=none",
        ),
        "env_id='NoSuch-v0': expected an env gymnasium can make",
    ),
    "an own env id without preset=none": (
        (*ATARI, "task.env.env_id=EdrFruit-v0", "task.env.env_module=edr.rl.games"),
        "task.env.preset='paac': expected preset=none with env_id=<id>",
    ),
    "preset=none without an env id": (
        (*ATARI, "task.env.preset=none"),
        "task.env.preset='none': expected preset=none with env_id=<id>",
    ),
    "EnvPool for an own env": (
        (
            *ATARI,
            "task.env.env_id=EdrFruit-v0",
            "task.env.env_module=edr.rl.games",
            "task.env.preset=none",
            "task.env.backend=envpool",
        ),
        "task.env.backend='envpool': expected auto, batch, serial or parallel with preset=none",
    ),
    "an unset variable in a seed": ((*KTH, "seed=${oc.env:EDR_NO_SUCH_SEED}"), "EDR_NO_SUCH_SEED"),
    "an interpolation of no key": ((*KTH, "task.epochs=${no.such.key}"), "task.epochs=${no.such"),
    "the representation deleted": ((*KTH, "~representation"), "a run needs its representation"),
    "the backbone deleted": ((*KTH, "~backbone"), "a run needs its backbone"),
    "the paths deleted": ((*KTH, "~paths"), "a run needs its paths"),
    "eps of a million": ((*KTH, "representation.eps=1e6"), "eps=1e+06: expected at most"),
    "eps infinite": ((*KTH, "representation.eps=inf"), "a finite number"),
    "eps not a number": ((*KTH, "representation.eps=nan"), "a finite number"),
    "eps negative": ((*KTH, "representation.eps=-1"), "a number > 0"),
    "eps zero": ((*KTH, "representation.eps=0"), "a number > 0"),
    "eps a word": ((*KTH, "representation.eps=abc"), "expected a number"),
    "no half-lives": ((*KTH, "representation.half_lives=[]"), "expected at least one half-life"),
    "a half-life of 0": ((*KTH, "representation.half_lives=[0]"), "a number > 0"),
    "a negative half-life": ((*KTH, "representation.half_lives=[-1]"), "a number > 0"),
    "an infinite half-life": ((*KTH, "representation.half_lives=[inf]"), "a finite number"),
    "a half-life of 1e-5": ((*KTH, "representation.half_lives=[1e-5]"), "expected each at least"),
    "a half-life of 1e9 frames": ((*KTH, "representation.half_lives=1e9"), "each at most"),
    "a beta that never crosses": ((*KTH, "representation.beta=1e-12"), "every event would be 0"),
    "betas of the wrong count": (
        (*KTH, "representation.beta=[1,2]"),
        "beta=[1, 2]: expected one value, or one per",
    ),
    "thresholds no return crosses": (
        (*KTH, "representation.nu_on=1e12", "representation.nu_off=0.999999999999"),
        "every event would be 0",
    ),
    "Atari's EDR of 1e-300": (
        (*ATARI, "representation.half_lives=[1e-300]", "representation.color=gray"),
        "task.env.edr.half_lives=[1e-300]",
    ),
}


@pytest.mark.parametrize("case", [*ISSUE_OVERRIDES, *NEW_OVERRIDES])
def test_a_bad_override_is_one_line_before_any_folder(case, tmp_path, monkeypatch) -> None:
    argv, said = {**ISSUE_OVERRIDES, **NEW_OVERRIDES}[case]
    monkeypatch.chdir(tmp_path)
    assert said in _refused(*argv, f"paths.results={tmp_path / 'results'}")
    assert not any(tmp_path.iterdir())  # no run folder, no log


@pytest.mark.parametrize("variable", ["EDR_REAL_VIDEO", "EDR_RESULTS", "EDR_CACHE"])
def test_an_environment_variable_in_a_loop_is_named(variable, files, tmp_path, monkeypatch):
    """EDR_REAL_VIDEO (the issue's case) and the other two the paths read (held out)."""
    monkeypatch.setenv(variable, str(files["loop_a"]))
    monkeypatch.chdir(tmp_path)
    said = _refused("experiment=kth_real", "debug=tiny")
    assert f"environment variable {variable}" in said and "Symlink loop" in said
    assert not any(tmp_path.iterdir())


# ---- videos, for the demo's task.video and edr-bench --video ---------------------------------
VIDEOS = {"empty": "0 bytes", "text": "cannot open", "one": "at least 2 frames (its container "
          "holds 1)", "cut": "cannot open", "folder": "is not a file", "loop_a": "symbolic links",
          "missing": "video not found"}  # fmt: skip


@pytest.mark.parametrize("name", VIDEOS)
def test_the_demo_refuses_a_video_that_is_no_video(name, files, tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    video = files.get(name, tmp_path / "missing.avi")
    said = _refused("task=representation_demo", f"task.video={video}")
    assert f"task.video='{video}': expected" in said and VIDEOS[name] in said


# ---- edr-bench flags -------------------------------------------------------------------------
ISSUE_FLAGS = {
    "negative threads": (["--threads", "-1"], "--threads=-1: expected a number >= 1"),
    "negative Atari envs": (["--atari", "-3"], "--atari=-3: expected a number >= 0"),
    "a game that does not exist": (["--atari", "1", "--game", "NoSuchGame"], "--game=NoSuchGame"),
    "a frame of 100000 x 100000": (["--height", "100000", "--width", "100000"], "--height=100000"),
    "a million frames": (["--frames", "1000000"], "--frames=1000000"),
}
NEW_FLAGS = {
    "threads past the cores": (["--threads", "100000"], "--threads=100000: expected at most"),
    "zero threads": (["--threads", "0"], "--threads=0"),
    "threads a word": (["--threads", "many"], "argument --threads: invalid int value"),
    "frames a float": (["--frames", "1e3"], "argument --frames: invalid int value"),
    "a lower-case game": (["--atari", "1", "--game", "pong"], "case-sensitive): Pong"),
    "a ROM without an env": (["--atari", "1", "--game", "Joust"], "no single-player env"),
    "a backend that does not exist": (["--atari", "1", "--backends", "single"], "'single' is none"),
    "no backend": (["--atari", "1", "--backends", ""], "--backends="),
    "a network that does not exist": (["--network", "bogus"], "argument --network"),
    "a long clip past memory": (["--long-frames", "1000000000"], "--long-frames=1000000000"),
    "an Atari batch past memory": (["--atari-batch", "100000000"], "--atari-batch=100000000"),
    "Atari envs past memory": (["--atari", "100000"], "--atari=100000"),
    "no repeats": (["--repeats", "0"], "--repeats=0"),
    "a negative warm-up": (["--warmup", "-1"], "--warmup=-1"),
    "one flow frame": (["--flow-frames", "1"], "--flow-frames=1"),
    "frames too small": (["--height", "8"], "--height=8"),
    "no Atari steps": (["--atari", "1", "--steps", "0"], "--steps=0"),
}


def _bench_refusal(argv: list[str], out_dir: Path, capsys) -> str:
    with pytest.raises(SystemExit) as stopped:
        bench.main([*argv, "--quick", "--out-dir", str(out_dir)])
    assert stopped.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert not out_dir.exists() or not any(out_dir.iterdir())
    return err


@pytest.mark.parametrize("case", [*ISSUE_FLAGS, *NEW_FLAGS])
def test_a_bad_bench_flag_is_one_line_before_timing(case, tmp_path, capsys) -> None:
    argv, said = {**ISSUE_FLAGS, **NEW_FLAGS}[case]
    assert said in _bench_refusal(argv, tmp_path / "out", capsys)


@pytest.mark.parametrize("name", VIDEOS)
def test_a_bench_video_that_is_no_video_is_named(name, files, tmp_path, capsys) -> None:
    video = files.get(name, tmp_path / "missing.avi")
    said = _bench_refusal(["--video", str(video)], tmp_path / "out", capsys)
    assert f"--video={video}: expected" in said and VIDEOS[name] in said


@pytest.mark.parametrize("where", ["a file", "a folder under a file"])
def test_a_bench_out_dir_that_cannot_be_written_is_named(where, tmp_path, capsys) -> None:
    afile = tmp_path / "afile"
    afile.write_text("x")
    out = afile if where == "a file" else afile / "below"
    with pytest.raises(SystemExit) as stopped:
        bench.main(["--quick", "--out-dir", str(out)])
    assert (
        stopped.value.code == 2 and f"--out-dir={out}: expected a folder" in capsys.readouterr().err
    )


def test_a_full_disk_under_the_bench_is_one_line(tmp_path, capsys, monkeypatch) -> None:
    def full(args, repeats) -> None:
        raise OSError(errno.ENOSPC, "No space left on device", str(args.out_dir / "speed.json"))

    monkeypatch.setattr(bench, "run_speed_bench", full)
    with pytest.raises(SystemExit) as stopped:
        bench.main(["--quick", "--out-dir", str(tmp_path)])
    err = capsys.readouterr().err
    assert stopped.value.code == 1 and err.count("\n") == 1
    assert "cannot write under --out-dir" in err and "No space left on device" in err


# ---- the memory check counts every size, together -------------------------------------------
def test_arrays_that_fit_alone_but_not_together_are_refused(monkeypatch) -> None:
    monkeypatch.setattr("edr.checks.config.available_memory_bytes", lambda: 100)
    parts = [Allocation("--a=1", "the first", 60), Allocation("--b=2", "the second", 50)]
    check_allocations(parts[:1])
    with pytest.raises(ConfigError, match=r"^--a=1: the first would take .* with everything"):
        check_allocations(parts)


# ---- values only a run's data or env shows, refused before its record -----------------------
@pytest.fixture(scope="module")
def three_persons(tmp_path_factory) -> Path:
    """KTH's layout, 3 persons of 1 scenario, 4 tiny frames a video."""
    root = tmp_path_factory.mktemp("data") / "KTH"
    return write_synthetic_kth(root, persons=3, scenarios=1, frames=4, height=24, width=32)


def _person_folds(root: Path | None) -> tuple[str, ...]:
    """``experiment=kth_person task.videos.folds=100`` on ``root`` (None: generated data)."""
    if root is None:
        return (*KTH, "task.videos.protocol=person_folds", "task.videos.folds=100")
    return ("experiment=kth_person", "task.videos.folds=100", f"task.data_root={root}",
            "task.videos.sequences=null")  # fmt: skip


FOLDS_SAID = {
    "data": "task.videos.folds=100: expected at most 3, the persons whose videos are under ",
    "generated": "task.videos.folds=100: expected at most 4, the persons task.synthetic.persons=4 "
    "generates: each fold tests persons of its own (or folds=persons)",
}


@pytest.mark.parametrize("data", FOLDS_SAID)
def test_more_folds_than_persons_is_one_line_before_any_folder(
    data, three_persons, tmp_path, monkeypatch
) -> None:
    monkeypatch.chdir(tmp_path)
    root = three_persons if data == "data" else None
    said = _refused(*_person_folds(root), f"paths.results={tmp_path / 'results'}")
    assert said.startswith(FOLDS_SAID[data]), said
    assert not any(tmp_path.iterdir())  # no run folder, no log


@pytest.mark.parametrize(
    "argv",
    [_person_folds(None), "data", (*ATARI, "task.env.env_id=CartPole-v1", "task.env.preset=none")],
    ids=["folds, generated data", "folds, a data root", "a gymnasium env without frames"],
)
def test_a_run_refuses_them_before_its_record(argv, three_persons, tmp_path) -> None:
    """The same check in the run itself (the path a sweep's jobs take, and a run called from
    Python): refused before its folder is made, so no record says ``failed`` for it."""
    from conftest import _compose
    from edr.run import run

    argv = _person_folds(three_persons) if argv == "data" else argv
    out = tmp_path / "run"
    cfg = _compose(*argv, f"out_dir={out}", f"paths.results={tmp_path / 'results'}")
    with pytest.raises(ConfigError) as refused:
        run(cfg)
    assert "\n" not in str(refused.value)
    assert not out.exists() and not any(tmp_path.iterdir())


def test_more_folds_than_persons_is_refused_by_the_data_set_too(tmp_path) -> None:
    root = write_synthetic_kth(
        tmp_path / "KTH", persons=3, scenarios=1, frames=4, height=24, width=32
    )
    with pytest.raises(ConfigError, match=r"task\.videos\.folds=100: expected at most 3"):
        kth(root, protocol="person_folds", folds=100)


def test_a_non_image_env_is_named_when_it_is_made() -> None:
    from edr.rl.envs import gym_image_env

    with pytest.raises(
        ConfigError,
        match=r"env_id=CartPole-v1: expected an env of RGB image observations.*Box\(4,\)",
    ):
        gym_image_env("CartPole-v1")


def test_a_game_envpool_lacks_is_named() -> None:
    from edr.rl.envs import EnvPoolAtari

    pytest.importorskip("envpool")
    with pytest.raises(ConfigError, match=r"task\.env\.game=TicTacToe3D: expected a game EnvPool"):
        EnvPoolAtari("TicTacToe3D", 1)


def test_a_step_state_on_the_meta_device_is_a_value_error() -> None:
    state = EDRState(torch.empty(1, 1, 1, 4, 4, device="meta"))
    with pytest.raises(ValueError, match="state is on the meta device"):
        EDR().step(torch.zeros(1, 1, 4, 4), state)


# ---- the real commands, end to end (a few: each is a process) ------------------------------
@pytest.mark.slow
@pytest.mark.parametrize(
    "command",
    [("edr-run", "task=atari", "task.env.game=pong"), ("edr-run", "threads=${oc.env:UNSET}"),
     ("edr-bench", "--atari", "-3")],
    ids=["edr-run game", "edr-run variable", "edr-bench atari"],
)  # fmt: skip
def test_the_commands_refuse_in_one_line(cli, command, tmp_path) -> None:
    result = cli(*command, cwd=tmp_path)
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert not any(tmp_path.iterdir())
