"""Progress on stderr: a live status line on a terminal, timestamped stage lines otherwise."""

from __future__ import annotations

import sys
import time
from typing import TextIO

from . import interrupt

QUIET_SECONDS = 2.0
"""Without a terminal, stages are logged only once the work has lasted this long."""


class Progress:
    """Reports named stages with elapsed time; silent when ``quiet``.

    On a terminal a live status line is redrawn; otherwise (logs, CI) stages are printed one
    per line, but only for work that has already taken more than a couple of seconds.
    """

    def __init__(self, *, quiet: bool = False, stream: TextIO | None = None) -> None:
        self.quiet = quiet
        self.stream = stream or sys.stderr
        self.start = time.monotonic()
        self.live = self.stream.isatty()
        self._open_line = False

    def __call__(self, stage: str) -> None:
        """Announce that ``stage`` has begun (and stop here if Ctrl-C was pressed)."""
        interrupt.check()
        if self.quiet:
            return
        elapsed = time.monotonic() - self.start
        if not self.live and elapsed < QUIET_SECONDS:
            return
        text = f"[{elapsed:6.1f}s] {stage}"
        if self.live:
            self.stream.write("\r\x1b[2K" + text)
            self._open_line = True
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def bar(self, stage: str, fraction: float) -> None:
        """Draw a bar for ``stage`` at ``fraction`` (0..1)."""
        filled = int(max(0.0, min(1.0, fraction)) * 30)
        self(f"{stage} [{'#' * filled}{'.' * (30 - filled)}] {fraction * 100:5.1f}%")

    def done(self) -> None:
        """End the live line, if one is open."""
        if self._open_line and not self.quiet:
            self.stream.write("\n")
            self.stream.flush()
            self._open_line = False
