"""Ctrl-C that cannot be lost.

Python may raise the KeyboardInterrupt of a SIGINT inside a callback whose exceptions it only
prints ("Exception ignored in ..."), e.g. during an import in the middle of a long run; the
command would then carry on and finish as if nothing happened. The CLI's handler also latches
the request, progress reports (called per frame and per chunk) raise it again, and the
"Exception ignored" report of such a swallowed interrupt is kept off the terminal.
"""

from __future__ import annotations

import signal
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any

_requested: set[int] = set()
"""Holds the signal number once Ctrl-C was pressed (a set: mutable without ``global``)."""


def _on_sigint(signum: int, frame: FrameType | None) -> None:
    """Latch the request, then interrupt as Python's default handler does."""
    _requested.add(signum)
    raise KeyboardInterrupt


def check() -> None:
    """Raise KeyboardInterrupt if Ctrl-C was pressed (even if its first raise was swallowed)."""
    if _requested:
        raise KeyboardInterrupt


@contextmanager
def latched() -> Iterator[None]:
    """Install the latching SIGINT handler for the duration of a command; a KeyboardInterrupt
    Python could only report as "Exception ignored" is kept quiet (it is latched, not lost)."""
    _requested.clear()
    previous = signal.signal(signal.SIGINT, _on_sigint)
    hook = sys.unraisablehook

    def quiet_interrupts(unraisable: Any) -> None:
        if not isinstance(unraisable.exc_value, KeyboardInterrupt):
            hook(unraisable)

    sys.unraisablehook = quiet_interrupts
    try:
        yield
        check()  # swallowed after the last progress report: still an interrupted command
    finally:
        signal.signal(signal.SIGINT, previous)
        sys.unraisablehook = hook


TRACKER_QUIET = "ignore:resource_tracker:UserWarning"
"""A warning filter for multiprocessing's resource tracker: after Ctrl-C it reports a pool's
semaphores as leaked or gone after "tsog: interrupted", though it cleans them up all the same."""


def quiet_resource_tracker() -> None:
    """Have the resource tracker this process starts keep its clean-up warnings to itself (it
    takes its ``-W`` options from ``sys.warnoptions`` when it starts)."""
    if TRACKER_QUIET not in sys.warnoptions:
        sys.warnoptions.append(TRACKER_QUIET)
