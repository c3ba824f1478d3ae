"""Ctrl-C as a flag: the one mechanism by which long work stops at a point where its state
is whole (a training between two updates, a driver between two waits).

The first Ctrl-C raises the flag and puts the previous handler back, so a second one
interrupts at once. Outside the main thread (where Python allows no signal handler) the
flag never rises and Ctrl-C is the caller's.
"""

from __future__ import annotations

import signal
import threading
from typing import Any


class CtrlC:
    """While active (``with CtrlC() as ctrl_c``, or :meth:`start` and :meth:`stop` across
    callbacks), Ctrl-C sets :attr:`requested` instead of raising ``KeyboardInterrupt``."""

    def __init__(self) -> None:
        self.requested = False
        self._previous: Any = None

    def start(self) -> CtrlC:
        self.requested = False
        if threading.current_thread() is threading.main_thread():
            # None: a handler set from C; Python's own is what a second Ctrl-C should meet
            self._previous = signal.getsignal(signal.SIGINT) or signal.default_int_handler
            signal.signal(signal.SIGINT, self._note)
        return self

    def stop(self) -> None:
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)
            self._previous = None

    def _note(self, signum: int, frame: Any) -> None:
        self.requested = True
        self.stop()

    def __enter__(self) -> CtrlC:
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.stop()
