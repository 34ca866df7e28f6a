"""A small progress reporter for long runs (sweeps, diagrams, continuation).

No dependency: on a terminal it redraws one line; elsewhere (CI logs, pipes) it prints a line
at every tenth of the work, so logs stay short. ``enabled=False`` (or the environment variable
``PERTURB_PROGRESS=0``) silences it.
"""

from __future__ import annotations

import os
import sys
import time
from typing import TextIO

__all__ = ["Progress"]


class Progress:
    """Report ``done / total`` with elapsed time and an estimate of the time left.

    Use as a context manager::

        with Progress(len(grid), "sweep") as bar:
            for item in grid:
                ...
                bar.update()

    ``eta=False`` leaves out the estimate of the time left, for work whose items differ
    widely in cost.
    """

    def __init__(
        self,
        total: int,
        label: str = "",
        *,
        stream: TextIO | None = None,
        enabled: bool | None = None,
        eta: bool = True,
    ) -> None:
        self.total = max(int(total), 0)
        # an estimate of the time left assumes items of similar cost; where they are not (a
        # seed on a known branch costs nothing, a new branch seconds), it would jump about
        self.eta = bool(eta)
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        if enabled is None:
            enabled = os.environ.get("PERTURB_PROGRESS", "1") != "0"
        self.enabled = bool(enabled) and self.total > 0
        try:
            self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        except (OSError, ValueError):  # a closed stream
            self.tty, self.enabled = False, False
        self.done = 0
        self.start = time.perf_counter()
        self._last_decile = -1

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def update(self, n: int = 1) -> None:
        """Record ``n`` more items done."""
        self.done = min(self.total, self.done + n)
        if not self.enabled:
            return
        decile = (10 * self.done) // self.total
        if self.tty:
            self._write("\r" + self._line(), end="")
        elif decile != self._last_decile:
            self._last_decile = decile
            self._write(self._line())

    def _line(self) -> str:
        elapsed = time.perf_counter() - self.start
        rate = self.done / elapsed if elapsed > 0 else 0.0
        left = (self.total - self.done) / rate if rate > 0 else float("inf")
        eta = f", ~{left:.0f} s left" if self.eta and self.done < self.total and rate > 0 else ""
        return f"[perturb] {self.label} {self.done}/{self.total} ({elapsed:.1f} s{eta})"

    def _write(self, text: str, end: str = "\n") -> None:
        try:
            self.stream.write(text + end)
            self.stream.flush()
        except (OSError, ValueError):  # a closed stream must not stop the computation
            self.enabled = False

    def close(self) -> None:
        if self.enabled and self.tty:
            self._write("")
