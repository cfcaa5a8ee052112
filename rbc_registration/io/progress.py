"""Progress of a long offline operation (reading a long CSV or a bag, writing a bag, a replay)
on stderr: on a terminal a bar redrawn in place and a line every :data:`EVERY_S` seconds at most;
nothing when stderr is not a terminal (piped or redirected: a log stays clean)."""

from __future__ import annotations

import sys
import time
from typing import Optional, TextIO

#: Seconds between two redraws.
EVERY_S = 0.5


class Progress:
    """Progress of a long operation on stderr (module docstring). ``total`` 0 means unknown.

    :param enabled: False: silent (e.g. ``--quiet``).
    :param delay_s: nothing is shown before this many seconds (a short operation says
        nothing).
    """

    def __init__(self, label: str, total: int = 0, stream: Optional[TextIO] = None,
                 enabled: bool = True, every_s: float = EVERY_S, delay_s: float = 0.0) -> None:
        self.label, self.total, self.count = label, int(total), 0
        self._stream = stream or sys.stderr
        isatty = getattr(self._stream, "isatty", None)
        self._on = enabled and callable(isatty) and bool(isatty())
        self._every = every_s
        self._start = time.monotonic()
        self._last = self._start + delay_s - every_s
        self._shown = False

    def update(self, n: int = 1) -> None:
        """Count ``n`` more items; redraw when due."""
        self.count += n
        if self._on:
            now = time.monotonic()
            if now - self._last >= self._every:
                self._last = now
                self._show("\r")

    def _show(self, end: str) -> None:
        if self.total:
            frac = min(1.0, self.count / self.total)
            text = (f"{self.label} [{'#' * int(30 * frac):<30}] {self.count}/{self.total} "
                    f"({100 * frac:.0f}%)")
        else:
            text = f"{self.label} {self.count}"
        self._stream.write(text + end)
        self._stream.flush()
        self._shown = True

    def done(self) -> None:
        """End the line with the final count (when anything was shown)."""
        if self._on and self._shown:
            self._show("\n")
