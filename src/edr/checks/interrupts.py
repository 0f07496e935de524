"""Ctrl-C and SIGTERM: a run stops on the first one, within seconds, wherever it lands.

The first signal raises :class:`KeyboardInterrupt` (SIGTERM: :class:`Terminated`) in the main
thread. Python prints and drops an exception raised in a garbage collector's callback or a
``__del__`` ("Exception ignored in ..."), so a signal landing there would leave training
running: the training loops call :func:`raise_if_stopping` once a step, which raises it again.
Signals after the first are dropped: the run is already stopping and writing its record, and a
second Ctrl-C must not cut that short with a traceback.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator
from types import FrameType

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, a scheduler's preemption or time limit), ended as Ctrl-C is: the run's
    record says ``interrupted`` and the next attempt resumes from its checkpoint."""


class _State:
    first: int | None = None  # the signal the run is stopping on, once one came


def _interrupt(signum: int) -> KeyboardInterrupt:
    return (
        Terminated(signal.Signals(signum).name) if signum == signal.SIGTERM else KeyboardInterrupt()
    )


def _on_signal(signum: int, frame: FrameType | None) -> None:
    if _State.first is None:  # later ones: already stopping
        _State.first = signum
        raise _interrupt(signum)


def install() -> None:
    """Stop on the first SIGINT or SIGTERM as described above (from the main thread)."""
    _State.first = None
    for signum in STOP_SIGNALS:
        signal.signal(signum, _on_signal)


def clear() -> None:
    """Forget the signal an earlier run in this process stopped on, so that the next run (in a
    notebook, a test, a sweep's next job) starts unstopped instead of raising at its first step."""
    _State.first = None


def raise_if_stopping() -> None:
    """Raise the interrupt of a signal that came before, if one did: a loop still running then
    had it dropped somewhere (a callback, a ``__del__``)."""
    if _State.first is not None:
        raise _interrupt(_State.first)


def ignore_stop_signals() -> None:
    """Ignore SIGINT and SIGTERM in this process: for a worker process, which its parent stops
    itself. A Ctrl-C reaches the whole process group (and a scheduler's SIGTERM every process of
    the job); a worker that died of it would turn the parent's orderly stop into a failure."""
    for signum in STOP_SIGNALS:
        signal.signal(signum, signal.SIG_IGN)


@contextlib.contextmanager
def deferred(on_signal: Callable[[int], None] | None = None) -> Iterator[None]:
    """Hold SIGINT and SIGTERM until the block ends, then raise the first one's interrupt (none
    when the process was already stopping): for writes a signal must not cut in half (a run's
    finished record and its attempt line), or a parent that lets its workers stop themselves
    (``on_signal`` tells them, once). Off the main thread, where no handler can be set, the
    block runs as it is."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    came: list[int] = []

    def hold(signum: int, frame: FrameType | None) -> None:
        if not came:
            came.append(signum)
            if on_signal is not None:
                on_signal(signum)

    previous = {signum: signal.signal(signum, hold) for signum in STOP_SIGNALS}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    if came and _State.first is None:
        _State.first = came[0]
        raise _interrupt(came[0])
