"""A minimal progress display on stderr for long work (only when stderr is a terminal or asked)."""
from __future__ import annotations

import sys
import time


class Progress:
    """Call with (done, total); prints a one-line bar at most every 0.2 s."""

    def __init__(self, label: str, enabled: bool | None = None, stream=None):
        self.label = label
        self.stream = stream or sys.stderr
        self.enabled = self.stream.isatty() if enabled is None else enabled
        self._last = 0.0

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled or total <= 0:
            return
        now = time.monotonic()
        if done < total and now - self._last < 0.2:
            return
        self._last = now
        frac = min(1.0, done / total)
        bar = "#" * int(30 * frac)
        self.stream.write(f"\r{self.label} [{bar:<30}] {100 * frac:5.1f}%")
        if done >= total:
            self.stream.write("\n")
        self.stream.flush()


class StageLog:
    """Names the stage a command is in while it works (one line, overwritten), so a command that
    takes tens of seconds is not silent; on stderr only when it is a terminal (or asked)."""

    def __init__(self, label: str, enabled: bool | None = None, stream=None):
        self.label = label
        self.stream = stream or sys.stderr
        self.enabled = self.stream.isatty() if enabled is None else enabled
        self._t0 = time.monotonic()
        self._width = 0

    def __call__(self, stage: str) -> None:
        if not self.enabled:
            return
        text = f"{self.label}: {stage} ... ({time.monotonic() - self._t0:.0f} s)"
        self.stream.write("\r" + text.ljust(self._width))
        self._width = len(text)
        self.stream.flush()

    def done(self) -> None:
        if self.enabled and self._width:
            self.stream.write("\r" + " " * self._width + "\r")
            self.stream.flush()
