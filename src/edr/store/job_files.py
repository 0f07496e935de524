"""The files Hydra writes for a job in its run folder (``run.log``, ``.hydra/``), written only
once edr-run has checked the folder: a refused run (a tampered record, a live lock, a foreign
checkpoint) leaves a folder it found byte for byte as it was.

Hydra opens a job's log and saves its config files before the job's function starts, so the
configs hand both to this module (``conf/config.yaml``): ``hydra.job_logging``'s file handler is
:class:`RunLog`, and ``hydra.output_subdir`` is null, :func:`write_job_config` writing what
Hydra would have. :func:`open_run_log` and :func:`write_job_config` are edr-run's, once the
folder passed its checks (a skipped run's log line is written; its ``.hydra/`` left as its run
wrote it).
"""

from __future__ import annotations

import errno
import logging
import os
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from edr.store.atomic import write_text_atomic

JOB_CONFIG = ".hydra"  # where Hydra keeps a job's config, overrides and own config


class RunLog(logging.FileHandler):
    """Hydra's file handler for a run's ``run.log``. In a new folder (Hydra made it, empty) it
    writes at once, as :class:`logging.FileHandler` does. In a folder that holds files already
    (a run to skip, resume or refuse), its records wait in memory until :func:`open_run_log`;
    closed before that (the run refused, the process ended), they are dropped and the file is
    neither made nor opened."""

    def __init__(self, filename: str, mode: str = "a", encoding: str | None = None,
                 delay: bool = False, errors: str | None = None) -> None:  # fmt: skip
        folder = Path(filename).parent
        self.held = folder.is_dir() and any(folder.iterdir())
        if self.held and not os.access(folder, os.W_OK):  # said before the run, as Hydra does
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), filename)
        self.waiting: list[logging.LogRecord] = []
        super().__init__(filename, mode, encoding, delay=delay or self.held, errors=errors)

    def emit(self, record: logging.LogRecord) -> None:
        if self.held:
            self.waiting.append(record)
        else:
            super().emit(record)

    def start_writing(self) -> None:
        """Write the records held so far, then every record as it comes."""
        self.held = False
        waiting, self.waiting = self.waiting, []
        for record in waiting:
            super().emit(record)

    def close(self) -> None:
        self.waiting = []  # a folder never checked: nothing of this job goes into it
        super().close()


def open_run_log() -> None:
    """The run's log (:class:`RunLog`, where Hydra's job logging made one) writes what it held
    and what comes: the folder is checked."""
    for handler in logging.getLogger().handlers:
        if isinstance(handler, RunLog):
            handler.start_writing()


def write_job_config(cfg: DictConfig) -> None:
    """Hydra's record of the job (``.hydra/config.yaml``, ``hydra.yaml``, ``overrides.yaml``) in
    its output folder, as Hydra writes it, within a Hydra job whose config leaves it to edr-run
    (``hydra.output_subdir`` null); nothing outside one (a test's or a notebook's run)."""
    if not HydraConfig.initialized():
        return
    hydra_cfg = HydraConfig.instance().cfg  # {"hydra": ...}
    runtime = hydra_cfg.hydra.runtime
    if hydra_cfg.hydra.output_subdir is not None or OmegaConf.is_missing(runtime, "output_dir"):
        return
    folder = Path(runtime.output_dir) / JOB_CONFIG
    for name, node in (("config.yaml", cfg), ("hydra.yaml", hydra_cfg),
                       ("overrides.yaml", hydra_cfg.hydra.overrides.task)):  # fmt: skip
        write_text_atomic(folder / name, OmegaConf.to_yaml(node))
