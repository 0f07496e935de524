"""``hydra/launcher=parallel``: Hydra's joblib launcher, with a sweep that Ctrl-C or SIGTERM stops
the way one run stops.

Joblib answers an interrupt by killing its workers: a worker still writing its run's record was
cut off, which left the record ``running`` and the sweep's summary short of it. Here the sweep's
process holds the signal instead (:func:`edr.checks.interrupts.deferred`) and tells every worker
to stop (a file in a folder of its own, which each job watches); each job stops as a single run
does, writing its record and attempt line; a cell that had not started does not start; and once
all have returned, the sweep's process raises the interrupt, which ``edr-run`` ends with the
sweep's summary line and exit status 130 (Ctrl-C) or 143 (SIGTERM).
"""

from __future__ import annotations

import os
import signal
import tempfile
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hydra.core.utils import JobReturn
from hydra.types import TaskFunction
from hydra_plugins.hydra_joblib_launcher.joblib_launcher import JoblibLauncher

from edr.checks import interrupts

WATCH_EVERY_S = 0.2  # how often a job looks for the sweep's stop


class StoppableJob:
    """A sweep's task function as a worker runs it: stopped by a file named for the signal
    (``SIGINT``, ``SIGTERM``) appearing in ``stop_folder``, as that signal would stop it."""

    def __init__(self, task_function: TaskFunction, stop_folder: Path) -> None:
        self.task_function, self.stop_folder = task_function, stop_folder

    def _signal(self) -> int | None:
        names = os.listdir(self.stop_folder) if self.stop_folder.is_dir() else []
        return next((signal.Signals[name].value for name in names), None)

    def _watch(self, done: threading.Event) -> None:
        while not done.wait(WATCH_EVERY_S):
            if (signum := self._signal()) is not None:
                os.kill(os.getpid(), signum)  # the job's own handler stops it
                return

    def __call__(self, cfg: Any) -> Any:
        if self._signal() is not None:
            return None  # the sweep stopped before this cell began
        interrupts.install()
        done = threading.Event()
        threading.Thread(target=self._watch, args=(done,), daemon=True).start()
        try:
            return self.task_function(cfg)
        except KeyboardInterrupt:
            return None  # its record says so (edr.run); the sweep's process raises the stop
        finally:
            done.set()
            interrupts.ignore_stop_signals()  # idle between cells: the sweep's process decides


class ParallelLauncher(JoblibLauncher):
    """:class:`JoblibLauncher` whose jobs stop themselves on the sweep's signal (module doc)."""

    def launch(
        self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int
    ) -> Sequence[JobReturn]:
        task_function = self.task_function
        assert task_function is not None, "Hydra sets the task function up before launching"
        with tempfile.TemporaryDirectory(prefix="edr-sweep-stop-") as folder:
            stop = Path(folder)
            self.task_function = StoppableJob(task_function, stop)
            try:
                with interrupts.deferred(
                    lambda signum: (stop / signal.Signals(signum).name).touch()
                ):
                    return super().launch(job_overrides, initial_job_idx)
            finally:
                self.task_function = task_function
