"""Shared fixtures: small, seeded environments and recordings."""

from __future__ import annotations

import os

if "PYTEST_XDIST_WORKER" in os.environ:
    # pytest-xdist runs one worker per core. Each worker's numba and torch thread pools (one
    # thread per core each) would then oversubscribe the cores, and numba's parallel kernels
    # wait for their slowest thread: the pipeline's evaluation stage ran 2.6x slower so on 2
    # cores. One thread per worker, and per command a worker starts (they inherit it). Set
    # before numba or torch is imported; results do not depend on the number of threads.
    for _var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402
import pytest

from bgap.common.config import validate
from bgap.datasets.config import SimulateConfig
from tests.configs import compose


def pytest_sessionstart(session) -> None:
    """Compile the numba kernels once, in the main process, before the test workers start:
    they (and the copies of the package some tests make) then load them from numba's cache
    instead of each compiling them again (about 30 s of CPU each on a fresh checkout)."""
    if not hasattr(session.config, "workerinput"):
        warm_compiled_kernels()


@pytest.fixture(scope="session", autouse=True)
def _sb3_logs_in_pytests_tmp(tmp_path_factory) -> None:
    """SB3 models learning without a tensorboard folder (the agent tests) log nowhere, but
    SB3 still makes an empty ``$TMPDIR/SB3-<time>`` folder per ``learn`` unless
    ``SB3_LOGDIR`` names one: keep them in pytest's temporary folder, which it prunes."""
    os.environ["SB3_LOGDIR"] = str(tmp_path_factory.mktemp("sb3"))


LONG_FILES = (
    "test_pipeline.py",
    "test_pipeline_side.py",
    "test_train_evaluate.py",
    "test_bad_inputs.py",
    "test_sweep.py",
    "test_install.py",
)
"""Test files that take most of a minute or more, longest first: collected first, so that
pytest-xdist's ``--dist loadfile`` (with ``--no-loadscope-reorder``, pyproject.toml) starts
them at once instead of leaving one to run alone at the end."""


def pytest_collection_modifyitems(session, config, items) -> None:
    def rank(item) -> int:
        name = item.path.name
        return LONG_FILES.index(name) if name in LONG_FILES else len(LONG_FILES)

    items.sort(key=rank)  # stable: the order within and among the other files is kept


def make_cfg(*overrides: str) -> SimulateConfig:
    """A validated config composed from conf/ exactly as the command line would."""
    return validate(compose("simulate", list(overrides)))


@pytest.fixture(scope="session")
def sparse_mixed_recording():
    """8 seeded 60 s sparse episodes, paper behaviours, half aggressive, idle ego (the class
    differences asserted on it are many standard errors wide). On the vector backend, which
    tests/test_sim.py holds to highway-env step for step (14 s less on highway-env)."""
    from bgap.datasets.simulate import simulate

    cfg = make_cfg("env=sparse", "mix=0.5", "behavior=paper", "seed=100", "backend=vector")
    return simulate(cfg, episodes=8, progress=False)


def warm_compiled_kernels() -> None:
    """Compile (or load from numba's cache) the simulator's and CMetric's kernels in this
    checkout, so that a copy of the package made afterwards with its ``__pycache__`` (same
    sources, same modification times) loads them instead of compiling them again."""
    from bgap.agents.policies import rollout
    from bgap.cmetric import score_trajectories
    from bgap.traffic.scenario import env_config

    cfg = make_cfg("env=sparse", "env.duration=2")
    table = rollout(env_config(cfg), "random", [0], "vector", record=True).trajectories
    score_trajectories(table)


def lane_changes(table) -> np.ndarray:
    """Per-vehicle lane changes, counted from the recorded lane column."""
    ordered = table.sort_values(["episode", "vehicle_id", "frame"])
    same = (ordered.episode.diff() == 0) & (ordered.vehicle_id.diff() == 0)
    changed = same & (ordered.lane.diff() != 0)
    return changed.groupby([ordered.episode, ordered.vehicle_id]).sum()
