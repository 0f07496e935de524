"""Every shell command of the README, sweeps/README.md, paper/README.md, docs/runs.md's
Slurm section and docs/events.md (their fenced ``bash`` blocks) runs as written, at ``debug=tiny``, in a temporary
folder: a command that stops working fails CI.

How a command is made small: ``edr-run`` gets ``debug=tiny`` and, in a sweep, one cell: the first
value of each axis the command lists (every cell of its lists is composed and built, not run) and
of each axis its experiment file sweeps and the command does not set; an ALE game trains and
plays at the paper's tiny sweep's size (``ATARI_TINY``), where the command sets none of it;
``/data/...`` paths become small data the test generates in that data set's layout, and so do
the real clips of ``../shared/real-video`` (``EDR_REAL_VIDEO``), long enough to split in time;
``../shared/events/`` the real recordings beside the repository (skipped when absent);
``edr-bench`` times tiny clips; ``edr-tables`` writes into the temporary folder. A command an
earlier document already holds, word for word, runs in that document's test only. ``make``
targets are not run here: ``make test`` is this suite, and ``make demo`` is ``edr-run -m
experiment=kth_demo`` (a row of sweeps/README.md) followed by ``edr-tables``. Nor is
``sweeps/slurm-local.sh``: CI starts its cluster around the tests; a ``hydra/launcher=slurm``
command runs through that cluster (any whose ``sinfo`` answers), and is left out where none is up.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from omegaconf import DictConfig

from cells import assert_builds, grid, listed
from cluster import LOCAL_CLUSTER, slurm_environment
from edr.data.synthetic import write_synthetic_kth, write_synthetic_ucf101
from edr.data.video import write_video
from edr.run import CONF_DIR
from edr.studies.tiny_sweeps import ATARI_TINY

ROOT = Path(__file__).resolve().parents[1]
DOCUMENTS = ("README.md", "sweeps/README.md", "paper/README.md", "docs/runs.md", "docs/events.md")
SECTIONS = {"docs/runs.md": "## On Slurm"}  # the rest of the page repeats the README's commands
SHARED_EVENTS = ROOT.parent / "shared" / "events"  # real recordings docs/events.md reads
BENCH_TINY = ("--quick", "--warmup", "1", "--frames", "4", "--flow-frames", "2", "--height", "32",
              "--width", "48", "--atari-batch", "2", "--long-frames", "9")  # fmt: skip


def documented_commands(document: Path, section: str | None = None) -> list[list[str]]:
    """The commands of ``document``'s ```bash blocks (those of its ``section`` if given, up to
    the next heading of its level), split as the shell would, comments off."""
    text = document.read_text()
    if section is not None:
        level = section.split()[0]
        text = re.split(rf"\n{level} ", text.split(f"\n{section}\n", 1)[1], maxsplit=1)[0]
    blocks = re.findall(r"```bash\n(.*?)```", text, flags=re.S)
    text = "\n".join(blocks).replace("\\\n", " ")
    return [words for line in text.splitlines() if (words := shlex.split(line, comments=True))]


def run_by_an_earlier_document(document: str) -> set[str]:
    """The commands, word for word, of the documents before ``document`` in ``DOCUMENTS``: their
    tests run them (paper/README.md repeats two of sweeps/README.md's)."""
    earlier = DOCUMENTS[: DOCUMENTS.index(document)]
    return {shlex.join(w) for d in earlier for w in documented_commands(ROOT / d, SECTIONS.get(d))}


def _data(tmp: Path) -> dict[str, str]:
    """The documented /data paths, as small data in each set's layout."""
    kth = write_synthetic_kth(tmp / "data" / "KTH", persons=4, scenarios=1, frames=16)
    ucf = write_synthetic_ucf101(tmp / "data" / "UCF-101", groups=8, clips=1, frames=16,
                                 height=60, width=80)  # fmt: skip
    frames = np.random.default_rng(0).integers(0, 255, (12, 3, 60, 80), dtype=np.uint8)
    clip = write_video(tmp / "data" / "clip.avi", frames)
    return {"/data/KTH": str(kth), "/data/UCF-101": str(ucf), "/data/clip.avi": str(clip)}


def _real_video(tmp: Path) -> Path:
    """A stand-in for ``../shared/real-video``: generated videos in its ``kth/`` and ``ucf101/``,
    40 frames each (a split in time of debug=tiny's 8-frame clips needs 40)."""
    size = {"frames": 40, "height": 60, "width": 80}
    kth = write_synthetic_kth(tmp / "real-video" / "kth", persons=2, scenarios=1, **size)
    write_synthetic_ucf101(tmp / "real-video" / "ucf101", groups=1, clips=1, **size)
    sequences = tmp / "real-video" / "splits" / "kth" / "00sequences.txt"  # KTH's sub-sequences
    sequences.parent.mkdir(parents=True)
    sequences.write_text("".join(f"{v.name.removesuffix('_uncomp.avi')}\t\tframes\t1-20, 21-40\n"
                                 for v in sorted(kth.glob("*/*.avi"))))  # fmt: skip
    return tmp / "real-video"


def _composed(overrides: list[str]) -> DictConfig:
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        return compose(config_name="config", overrides=overrides, return_hydra_config=True)


def _sweep_axes(cfg: DictConfig) -> dict[str, str]:
    """The axes an experiment file sweeps, with the first value of each."""
    params = cfg.hydra.sweeper.params or {}
    return {str(k): str(v).split(",")[0] for k, v in params.items()}


def _atari_size(cfg: DictConfig, given: set[str]) -> list[str]:
    """An ALE game's run at the paper's tiny sweep's size, the values the command does not set:
    debug=tiny's (2,000 env steps on 4 envs, two 100-step evaluation games) took 13.7-14.1 s of
    CPU for Table 1's command, this 8.6-9.5 s (200 env steps on 2 envs, one 50-step game)."""
    if "env_steps" not in cfg.task or cfg.task.env.preset == "none":
        return []
    return [o for o in ATARI_TINY if o.split("=", 1)[0] not in given]


def _substituted(word: str, data: dict[str, str]) -> str:
    key, equals, value = word.partition("=")
    return f"{key}={data[value]}" if equals and value in data else word


def _first_value(word: str) -> str:
    return word.split(",", 1)[0] if listed(word) else word


def listed_cells(words: list[str], data: dict[str, str]) -> list[list[str]]:
    """Every cell of an ``edr-run -m`` command's own lists, as overrides (none if it lists none)."""
    args = [_substituted(w, data) for w in words[1:] if w != "-m"]
    if words[0] != "edr-run" or "-m" not in words or not any(map(listed, args)):
        return []
    return grid(args)


def tiny(words: list[str], data: dict[str, str], tmp: Path) -> list[str]:
    """The command made small (see the module's docstring)."""
    words = [w.replace("../shared/events/", f"{SHARED_EVENTS}/") for w in words]
    program, args = words[0], [_substituted(w, data) for w in words[1:]]
    if program == "edr-run" and not {"--help", "--cfg"} & set(args):
        args = [*args, "debug=tiny"] if "debug=tiny" not in args else args
        if "-m" in args:
            args = [_first_value(a) for a in args]  # one cell of the command's own lists
        given = {a.split("=", 1)[0] for a in args if "=" in a}
        cfg = _composed([a for a in args if a != "-m"])
        if "-m" in args:
            args += [f"{k}={v}" for k, v in _sweep_axes(cfg).items() if k not in given]
        args += _atari_size(cfg, given)
    elif program == "edr-bench":
        args = [*args, *BENCH_TINY, "--out-dir", str(tmp / "results" / "bench")]
    elif program == "edr-tables" and "--out" not in args:
        args = [*args, "--out", str(tmp / "paper")]
    if program == "edr-tables":
        args = [str(tmp / a[1:]) if a.startswith("/tmp/") else a for a in args]
    return [program, *args]


@pytest.mark.slow
@pytest.mark.parametrize("document", DOCUMENTS)
def test_every_documented_command_runs(document: str, cli, tmp_path) -> None:
    commands = documented_commands(ROOT / document, SECTIONS.get(document))
    assert commands, f"{document} has no bash block"
    if "../shared/events/" in (ROOT / document).read_text() and not SHARED_EVENTS.is_dir():
        pytest.skip(
            f"{document} reads real recordings; {SHARED_EVENTS} (../shared/events) is absent"
        )
    data = _data(tmp_path)
    env = {"EDR_CACHE": str(tmp_path / "cache"), "EDR_RESULTS": str(tmp_path / "results"),
           "EDR_REAL_VIDEO": str(_real_video(tmp_path))}  # fmt: skip
    slurm = slurm_environment() if any("hydra/launcher=slurm" in w for w in commands) else None
    run_before = run_by_an_earlier_document(document)
    for words in commands:
        if words[0] == "make" or any(LOCAL_CLUSTER.name in w for w in words):
            continue  # see the module's docstring
        if shlex.join(words) in run_before:
            continue  # that document's test ran it, and what it needs, as written
        if "hydra/launcher=slurm" in words:
            if slurm is None:
                continue  # no cluster here (see the module's docstring)
            env.update(slurm)  # SLURM_CONF, where the local cluster's is not set
        assert_builds(listed_cells(words, data))
        command = tiny(words, data, tmp_path)
        result = cli(*command, cwd=tmp_path, env=env)
        shown = shlex.join(words)
        assert result.returncode == 0, f"{document}: `{shown}` failed:\n{result.stderr[-3000:]}"
        output = result.stdout + result.stderr
        assert "Traceback" not in output, f"{document}: `{shown}`:\n{output[-3000:]}"
        if command[0] == "edr-run" and "debug=tiny" in command:
            assert " finished: " in output or "skipped" in output, f"`{shown}`: {output[-2000:]}"
