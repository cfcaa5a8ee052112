"""Progress of a long operation on stderr (reading or writing a bag, a replay): a bar on a
terminal, else a line every few seconds."""

from __future__ import annotations

import sys
import time
from typing import Optional, TextIO


class Progress:
    """Progress of a long operation on stderr: a bar on a terminal, else a line every few
    seconds. ``total`` 0 means unknown."""

    def __init__(self, label: str, total: int = 0, stream: Optional[TextIO] = None,
                 enabled: bool = True, every_s: float = 2.0) -> None:
        self.label, self.total, self.count = label, int(total), 0
        self._stream = stream or sys.stderr
        self._enabled = enabled
        self._tty = enabled and hasattr(self._stream, "isatty") and self._stream.isatty()
        self._every = 0.2 if self._tty else every_s
        self._last = time.monotonic()

    def update(self, n: int = 1) -> None:
        """Count ``n`` more items; redraw when due."""
        self.count += n
        now = time.monotonic()
        if self._enabled and now - self._last >= self._every:
            self._last = now
            self._show(end="\r" if self._tty else "\n")

    def _show(self, end: str) -> None:
        if self.total:
            frac = min(1.0, self.count / self.total)
            bar = f" [{'#' * int(30 * frac):<30}]" if self._tty else ""
            text = f"{self.label}{bar} {self.count}/{self.total} ({100 * frac:.0f}%)"
        else:
            text = f"{self.label} {self.count}"
        self._stream.write(text + end)
        self._stream.flush()

    def done(self) -> None:
        """Print the final count."""
        if self._enabled:
            self._show(end="\n")
