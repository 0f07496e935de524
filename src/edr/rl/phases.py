"""Where the Atari training loop's time goes, phase by phase (torchrl's a2c example times its
phases the same way): written to every history row and log line as ``time/<phase>_ms``."""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager


class PhaseClock:
    """Where the training loop's time goes: seconds per phase (``env``, ``observation``,
    ``forward``, ``backward``, ``optimizer``) since the last :meth:`lap`, and the rest (``other``).
    ``observation`` runs inside ``env`` (the transform steps with the env) and is taken out of it.
    """

    def __init__(self) -> None:
        self.seconds: defaultdict[str, float] = defaultdict(float)
        self._start = time.perf_counter()

    @contextmanager
    def phase(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] += time.perf_counter() - start

    def lap(self) -> dict[str, float]:
        """Milliseconds per phase since the last lap, as ``time/<phase>_ms``; starts a new lap."""
        now = time.perf_counter()
        spent = dict(self.seconds)
        if "observation" in spent and "env" in spent:
            spent["env"] -= spent["observation"]
        spent["other"] = (now - self._start) - sum(spent.values())
        self.seconds.clear()
        self._start = now
        return {f"time/{name}_ms": 1e3 * value for name, value in spent.items()}
