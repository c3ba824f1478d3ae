"""Thread counts set for a training stay set once the simulator runs (bgap.runner.threads)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

PROBE = """
import sys, tempfile, torch
from pathlib import Path

import pytest
from bgap.common.config import validate
from bgap.runner.threads import set_threads
from bgap.experiments.config import compose
from bgap.experiments.train import make_training_env
from bgap.experiments.training import build_model

if sys.argv[1] == "helper":
    set_threads(1)
else:
    torch.set_num_threads(1)
cfg = validate(compose("train", ["agent=ppo", "env=sparse", "profile=tiny"]))
env = make_training_env(cfg, 2, seed=0)
build_model(cfg, env, Path(tempfile.mkdtemp()))  # as bgap.train, before its first reset
env.reset()  # the simulator's first parallel kernel
print(torch.get_num_threads())
"""


def _torch_threads_after_a_reset(how: str) -> int:
    env = {**os.environ, "NUMBA_NUM_THREADS": "2", "PYTHONPATH": str(ROOT)}
    done = subprocess.run([sys.executable, "-c", PROBE, how], env=env, cwd=ROOT,
                          capture_output=True, text=True, check=True)  # fmt: skip
    return int(done.stdout.strip().splitlines()[-1])


@pytest.mark.slow  # the default suite's time budget
def test_one_torch_thread_stays_one_after_the_simulators_first_kernel():
    """The hazard, as bgap.train meets it (a model built, then the first reset: numba's
    OpenMP layer starts and torch's count becomes numba's 2), and the helper that starts
    that layer first so that 1 stays 1. The hazard shows where the two share one OpenMP
    runtime (2 on the Intel machines the study ran on); on others (an AMD EPYC) 1 stays 1
    without the helper too, so only the helper's guarantee holds everywhere."""
    assert _torch_threads_after_a_reset("plain") in (1, 2)
    assert _torch_threads_after_a_reset("helper") == 1


def test_side_by_side_processes_share_the_cores_they_may_run_on(monkeypatch):
    """The share is the process's affinity over the processes, never below one thread."""
    from bgap.runner.threads import cores_per_process

    for cores, processes, share in ((16, 3, 5), (16, 2, 8), (2, 2, 1), (2, 4, 1), (1, 1, 1)):
        monkeypatch.setattr(os, "sched_getaffinity", lambda _, n=cores: set(range(n)))
        assert cores_per_process(processes) == share


def _threads_after_a_kernel() -> tuple[int, int]:
    """In a pool's worker: torch's and numba's threads once a parallel kernel has run, as
    the simulator's first reset runs one."""
    import numba
    import numpy as np
    import torch

    from bgap.runner.threads import _first_parallel_kernel

    _first_parallel_kernel(np.zeros(8))
    return torch.get_num_threads(), numba.get_num_threads()


def test_trainings_side_by_side_run_no_more_kernel_threads_than_cores():
    """bgap.train's pool of two processes (workers=2): one torch thread each, and numba's
    kernels together on at most the cores there are. With numba's default in each (one
    thread per core, as before 2026-12-04) two processes on two cores ran four threads and
    every kernel waited at its barrier: 2.8x slower (python tools/bench.py side)."""
    from bgap.runner.pools import process_pool

    cores = len(os.sched_getaffinity(0))
    with process_pool(2) as pool:
        counts = [f.result() for f in [pool.submit(_threads_after_a_kernel) for _ in range(2)]]
    for torch_threads, numba_threads in counts:
        assert torch_threads == 1
        assert 1 <= numba_threads and 2 * numba_threads <= max(2, cores)
