"""A sweep's cells and whether each builds: what the experiment files' test and the documented
commands' test check for every cell without training any."""

from __future__ import annotations

import itertools
from collections.abc import Iterable

from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

from edr.run import CONF_DIR


def listed(override: str) -> bool:
    """``key=a,b``: an axis swept over its values (not a list value such as ``[4,4]``)."""
    _, equals, value = override.partition("=")
    return bool(equals) and "," in value and not value.startswith(("[", "{"))


def grid(overrides: Iterable[str]) -> list[list[str]]:
    """The cells of ``key=a,b,...`` overrides: one list of single-valued overrides per cell."""
    axes = [[f"{o.split('=', 1)[0]}={v}" for v in o.split("=", 1)[1].split(",")]
            if listed(o) else [o] for o in overrides]  # fmt: skip
    return [list(cell) for cell in itertools.product(*axes)]


def assert_builds(cells: Iterable[list[str]]) -> None:
    """Each cell composes, its representation builds and, for a recognition task, its backbone
    builds for that representation's input."""
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        for overrides in cells:
            cfg = compose(config_name="config", overrides=overrides)
            representation = instantiate(cfg.representation)
            if "crop" in cfg.task:  # a recognition task
                net = instantiate(cfg.backbone)(
                    in_channels=representation.out_channels(1 if cfg.task.gray else 3),
                    num_classes=6, frames=8, height=cfg.task.crop, width=cfg.task.crop,
                )  # fmt: skip
                assert sum(p.numel() for p in net.parameters()) > 0, overrides
