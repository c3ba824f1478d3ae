"""Process pools: the one definition of the worker processes bgap starts on this machine,
and of the threads each gets.

Spawned, not forked: a process that has run torch's OpenMP pool cannot fork safely. Each
worker gets one torch thread (bgap's networks are small: threads cost more than they
give) and a share of the cores for the simulator's numba kernels: with numba's default,
one thread per core in every process, two trainings on two cores ran four kernel threads
and each kernel waited at its barrier for a thread the other process held (2.8x slower,
``bench side``). A worker hears Ctrl-C only while it runs a job (:func:`in_worker`): an
idle one would die of it with a traceback, one per process. A worker being spawned would
die of it before Python has started (a fatal error from ``site``): workers are spawned with
Ctrl-C blocked, as CPython's own resource tracker is, and unblock it once they ignore it.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from functools import partial
from multiprocessing import get_context
from typing import Any

from bgap.runner.threads import cores_per_process, set_threads


def process_pool(workers: int, numba_threads: int | None = None) -> ProcessPoolExecutor:
    """A pool of ``workers`` spawned processes, each with one torch thread and
    ``numba_threads`` kernel threads (default: an equal share of this process's cores).
    Submit ``in_worker, fn, *args`` for a job that Ctrl-C can stop."""
    share = numba_threads or cores_per_process(workers)
    start = partial(_start_worker, share)
    return _Pool(workers, get_context("spawn"), initializer=start)


class _Pool(ProcessPoolExecutor):
    """A process pool whose workers start with Ctrl-C blocked. With the spawn context they
    are started by ``submit``, on demand; a Ctrl-C meanwhile is held (its handler would
    otherwise run halfway through a spawn, leaving a worker without its start-up data) and
    delivered once ``submit`` returns."""

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future:
        if threading.current_thread() is not threading.main_thread():
            return super().submit(fn, *args, **kwargs)  # the signals are the main thread's
        held: list[int] = []
        previous = signal.signal(signal.SIGINT, lambda signum, frame: held.append(signum))
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})  # what workers inherit
        try:
            return super().submit(fn, *args, **kwargs)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)
            signal.signal(signal.SIGINT, previous)
            if held:
                signal.raise_signal(signal.SIGINT)


def in_worker(fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)`` in a pool's worker, with Ctrl-C heard (Python's own handler) while it
    runs."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        return fn(*args)
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def _start_worker(numba_threads: int) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # idle: the parent handles Ctrl-C
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # blocked while it started
    set_threads(1, numba_threads)
