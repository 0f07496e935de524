"""``edr-run``: the Hydra entry point. One run = one task with its representation; it ends by
writing a run record (``run.json``) beside the run's artifacts.

    edr-run                                   # the demo on a generated video
    edr-run task.video=clip.avi task.frames=120
    edr-run -m representation=edr,edr_k3 seed=0,1
"""

from __future__ import annotations

import random
import time
from pathlib import Path
from typing import Any

import hydra
import numpy as np
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from edr.records import write_run_record

CONF_DIR = str(Path(__file__).resolve().parents[2] / "conf")


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def run(cfg: DictConfig) -> dict[str, Any]:
    """Run the task ``cfg`` describes and return its metrics; writes ``<out_dir>/run.json``."""
    # ---- set-up ------------------------------------------------------------------------------
    started = time.perf_counter()
    seed_everything(cfg.seed)
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    out_dir = Path(cfg.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    resolved = OmegaConf.to_container(cfg, resolve=True)
    task = instantiate(cfg.task)  # a partial function of the task's own arguments

    # ---- the task ----------------------------------------------------------------------------
    metrics = task(out_dir=out_dir, seed=cfg.seed)

    # ---- the record --------------------------------------------------------------------------
    hydra_cfg = HydraConfig.get() if HydraConfig.initialized() else None
    choices = (
        {k: str(v) for k, v in hydra_cfg.runtime.choices.items() if "hydra" not in k}
        if hydra_cfg
        else {}
    )
    write_run_record(
        out_dir,
        task=choices.get("task", cfg.task._target_),
        choices=choices,
        config=resolved,
        overrides=list(hydra_cfg.overrides.task) if hydra_cfg else [],
        metrics=metrics,
        wall_time_s=time.perf_counter() - started,
    )
    return metrics


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="config")
def main(cfg: DictConfig) -> None:
    run(cfg)


if __name__ == "__main__":
    main()
