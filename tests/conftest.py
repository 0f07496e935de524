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
