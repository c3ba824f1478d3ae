"""Thread pools of torch and numba in one process, set so that neither undoes the other.

Why a helper: numba's OpenMP threading layer, on its first parallel kernel, sets the OpenMP
thread count of the calling thread to its own (one per core), and torch's CPU pool reads
that same count. ``torch.set_num_threads(1)`` before the simulator's first kernel (the
first reset of a vector environment) is silently undone: an SB3 training meant to use one
torch thread used one per core, and two such trainings on two cores ran about 3x slower
than with one thread each (an Adam step of a 236,000-parameter policy: 390 ms against 3 ms
on a loaded machine). Results do not depend on the count (the same model after 3,000 steps
either way); the time does.
"""

from __future__ import annotations

import os

import numba
import numpy as np


@numba.njit(parallel=True, cache=True, nogil=True)
def _first_parallel_kernel(x: np.ndarray) -> None:
    for i in numba.prange(x.shape[0]):
        x[i] = i


def set_threads(torch_threads: int, numba_threads: int | None = None) -> None:
    """torch's intra-op threads for this process, and numba's when given (capped at
    ``NUMBA_NUM_THREADS``): numba's layer is started first, so the counts stay as set."""
    # Imported here: numba-only users of bgap.common (the simulator) need no torch.
    import torch

    _first_parallel_kernel(np.zeros(2 * numba.config.NUMBA_NUM_THREADS))
    if numba_threads is not None:
        numba.set_num_threads(max(1, min(numba_threads, numba.config.NUMBA_NUM_THREADS)))
    torch.set_num_threads(max(1, torch_threads))


def cores_per_process(processes: int) -> int:
    """This process's cores (its CPU affinity where the system has one, not the machine's
    count) shared out among ``processes`` side-by-side processes, at least one each: the
    numba threads each may run without their kernels' barriers waiting on one another."""
    affinity = getattr(os, "sched_getaffinity", None)
    cores = len(affinity(0)) if affinity else os.cpu_count() or 1
    return max(1, cores // max(1, processes))
