"""Progress on stderr: a live status line on a terminal, timestamped stage lines otherwise."""

from __future__ import annotations

import sys
import threading
import time
from typing import TextIO

from . import interrupt

QUIET_SECONDS = 2.0
"""Without a terminal, stages are logged only once the work has lasted this long."""
LOG_BAR_SECONDS = 5.0
"""Without a terminal, a bar is logged at most this often (and when full), never per step."""


class Progress:
    """Reports named stages with elapsed time (silent when ``quiet``): a redrawn status line on
    a terminal, else (logs, CI) one line per stage of work lasting over QUIET_SECONDS."""

    def __init__(self, *, quiet: bool = False, stream: TextIO | None = None) -> None:
        self.quiet = quiet
        self.stream = stream or sys.stderr
        self.start = time.monotonic()
        self.live = self.stream.isatty()
        self._open_line = False
        self._lock = threading.Lock()
        self._pending: str | None = None
        """A stage begun before QUIET_SECONDS, printed then if it is still running."""
        self._timer: threading.Timer | None = None
        self._bar_logged = -LOG_BAR_SECONDS
        """When the last bar line was logged (seconds since the start; without a terminal)."""

    def __call__(self, stage: str) -> None:
        """Announce that ``stage`` has begun (and stop here if Ctrl-C was pressed)."""
        interrupt.check()
        if self.quiet:
            return
        elapsed = time.monotonic() - self.start
        if not self.live and elapsed < QUIET_SECONDS:
            self._hold(stage, elapsed)
            return
        with self._lock:
            self._pending = None
            self._write(f"[{elapsed:6.1f}s] {stage}")

    def _write(self, text: str) -> None:
        if self.live:
            self.stream.write("\r\x1b[2K" + text)
            self._open_line = True
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def _hold(self, stage: str, elapsed: float) -> None:
        """Keep an early stage; print it at QUIET_SECONDS if no other output came first (a
        long read, the first thing a command does, is then seen from the first seconds)."""
        with self._lock:
            self._pending = stage
            if self._timer is None:
                self._timer = threading.Timer(QUIET_SECONDS - elapsed, self._flush_held)
                self._timer.daemon = True
                self._timer.start()

    def _flush_held(self) -> None:
        with self._lock:
            if self._pending is not None:
                elapsed = time.monotonic() - self.start
                self._write(f"[{elapsed:6.1f}s] {self._pending}")
                self._pending = None

    def close(self) -> None:
        """The command ended: nothing held is printed later."""
        with self._lock:
            self._pending = None
            if self._timer is not None:
                self._timer.cancel()
        self.done()

    def bar(self, stage: str, fraction: float) -> None:
        """Draw a bar for ``stage`` at ``fraction`` (0..1); without a terminal, a line at most
        every LOG_BAR_SECONDS, and the full bar."""
        filled = int(max(0.0, min(1.0, fraction)) * 30)
        text = f"{stage} [{'#' * filled}{'.' * (30 - filled)}] {fraction * 100:5.1f}%"
        self.tick(text, last=fraction >= 1.0)

    def tick(self, stage: str, *, last: bool = False) -> None:
        """One step of many quick ones (a chunk, a frame): redrawn on a terminal; without
        one, a line at most every LOG_BAR_SECONDS (and the ``last``), never one per step."""
        if not self.live and not last:
            now = time.monotonic() - self.start
            if now - self._bar_logged < LOG_BAR_SECONDS:
                interrupt.check()
                return
            self._bar_logged = now
        self(stage)

    def done(self) -> None:
        """End the live line, if one is open (and drop a held stage: that work is over)."""
        self._pending = None
        if self._open_line and not self.quiet:
            self.stream.write("\n")
            self.stream.flush()
            self._open_line = False
