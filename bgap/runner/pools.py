"""Process pools: the one definition of the worker processes bgap starts on this machine,
and of the threads each gets.

Spawned, not forked: a process that has run torch's OpenMP pool cannot fork safely. Each
worker gets one torch thread (bgap's networks are small: threads cost more than they
give) and a share of the cores for the simulator's numba kernels: with numba's default,
one thread per core in every process, two trainings on two cores ran four kernel threads
and each kernel waited at its barrier for a thread the other process held (2.8x slower,
``bench side``). A worker hears Ctrl-C only while it runs a job (:func:`in_worker`): an
idle one would die of it with a traceback, one per process.
"""

from __future__ import annotations

import signal
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
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
    return ProcessPoolExecutor(workers, get_context("spawn"), initializer=start)


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
    set_threads(1, numba_threads)
