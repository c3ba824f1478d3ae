"""Thread counts set for a training stay set once the simulator runs (bgap.common.threads)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

PROBE = """
import sys, tempfile, torch
from pathlib import Path
from bgap.common.config import validate
from bgap.common.threads import set_threads
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


def test_one_torch_thread_stays_one_after_the_simulators_first_kernel():
    """The hazard, as bgap.train meets it (a model built, then the first reset: numba's
    OpenMP layer starts and torch's count becomes numba's 2), and the helper that starts
    that layer first so that 1 stays 1."""
    assert _torch_threads_after_a_reset("plain") == 2
    assert _torch_threads_after_a_reset("helper") == 1
