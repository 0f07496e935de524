"""Fixtures shared by the tests: small clips, and the app's config composed as edr-run would."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, open_dict

from clips import translating_clip
from edr.run import CONF_DIR


def pytest_configure(config: pytest.Config) -> None:
    """Under pytest-xdist each worker takes its share of the cores, for torch here and for the
    commands it starts (``OMP_NUM_THREADS``): N workers each at all cores oversubscribe them, and
    torch's spinning threads then ran the learning tests 3-5x slower (the catching tests took
    137-313 s a test in a full run, 28-62 s alone on one thread)."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if workers > 1:
        share = max(1, (os.cpu_count() or 1) // workers)
        torch.set_num_threads(share)
        os.environ["OMP_NUM_THREADS"] = str(share)


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Under ``--dist loadgroup`` (make test), xdist has named each grouped test after its group by
    now; where it could not, the groups would run on every worker (the paper's tiny sweeps twice):
    say so instead of running. Then the longest work first (the groups, whose first test builds
    a shared fixture of minutes, then the slow and learning tests), so that no worker starts
    the paper's tiny sweeps while the others run out of tests."""
    if not getattr(config.option, "loadgroup", False):
        return
    lost = [i.nodeid for i in items if i.get_closest_marker("xdist_group") and "@" not in i.nodeid]
    if lost:
        raise pytest.UsageError(
            f"pytest-xdist's --dist loadgroup did not group {lost[0]} (and {len(lost) - 1} more) "
            f"under pytest {pytest.__version__}: install pyproject.toml's pytest (make setup)"
        )
    items.sort(key=lambda item: (  # a stable sort: the collection's order within each rank
        not item.get_closest_marker("xdist_group"),
        not (item.get_closest_marker("slow") or item.get_closest_marker("learning")),
    ))  # fmt: skip


@pytest.fixture
def moving_right() -> torch.Tensor:
    return translating_clip(dx=2)


@pytest.fixture
def moving_left() -> torch.Tensor:
    return translating_clip(dx=-2)


def _compose(*overrides: str) -> DictConfig:
    """As Hydra prepares a job: composed with its Hydra config, which the job then sees through
    ``HydraConfig`` (group choices, overrides) and no longer as a key."""
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose(config_name="config", overrides=list(overrides), return_hydra_config=True)
    HydraConfig.instance().set_config(cfg)
    with open_dict(cfg):
        del cfg["hydra"]
    return cfg


@pytest.fixture
def compose_config() -> Callable[..., DictConfig]:
    """``compose_config(*overrides)``: the app's config as ``edr-run`` composes it (no Hydra run)."""
    return _compose


def _cli(*args: str, cwd: Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    exe = Path(sys.executable).parent / args[0]
    environ = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
    return subprocess.run(
        [str(exe), *args[1:]], cwd=cwd, capture_output=True, text=True, env=environ, timeout=600
    )


@pytest.fixture
def cli() -> Callable[..., subprocess.CompletedProcess]:
    """``cli("edr-run", *args, cwd=...)``: one of the installed commands, run to its end."""
    return _cli
