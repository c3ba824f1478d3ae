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
# A user's cluster stays out, and the command a bgap run set for the processes it starts
for _var in ("BGAP_CLUSTER_ADDRESS", "BGAP_CLUSTER_STORAGE", "BGAP_COMMAND"):
    os.environ.pop(_var, None)

from bgap.runner.numerics import pin  # noqa: E402

pin(["pytest"])  # the kernels bgap's commands use, before torch loads: the same numbers

import glob  # noqa: E402
import shutil  # noqa: E402
import socket  # noqa: E402
import subprocess  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import pytest  # noqa: E402

from bgap.common.config import validate  # noqa: E402
from bgap.datasets.config import SimulateConfig  # noqa: E402
from tests.configs import compose  # noqa: E402


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

    cfg = make_cfg("env=sparse", "env.duration=4")  # longer than CMetric's 3-second window
    table = rollout(env_config(cfg), "random", [0], "vector", record=True).trajectories
    score_trajectories(table)


def lane_changes(table) -> np.ndarray:
    """Per-vehicle lane changes, counted from the recorded lane column."""
    ordered = table.sort_values(["episode", "vehicle_id", "frame"])
    same = (ordered.episode.diff() == 0) & (ordered.vehicle_id.diff() == 0)
    changed = same & (ordered.lane.diff() != 0)
    return changed.groupby([ordered.episode, ordered.vehicle_id]).sum()


# ------------------------------------------------ PostgreSQL (sweeps' shared storage)
def _pg_bin() -> Path | None:
    found = shutil.which("initdb")
    if found:
        return Path(found).resolve().parent
    candidates = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"))
    return Path(candidates[-1]).parent if candidates else None


@pytest.fixture(scope="module")
def postgres():
    """A throwaway PostgreSQL server on localhost (installed by .ci/run from Debian)."""
    bindir = _pg_bin()
    if bindir is None:
        pytest.skip("PostgreSQL is not installed (.ci/run installs Debian's postgresql)")
    pytest.importorskip("psycopg", reason="psycopg[binary] is in the dev extra")
    data = Path(tempfile.mkdtemp(prefix="bgap-pg-"))  # outside pytest's private tmp dirs
    as_user: list[str] = []
    if os.geteuid() == 0:  # PostgreSQL refuses to run as root
        if shutil.which("runuser") is None:
            pytest.skip("running as root without runuser: cannot start PostgreSQL")
        shutil.chown(data, "postgres")
        as_user = ["runuser", "-u", "postgres", "--"]
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    run = lambda *a: subprocess.run([*as_user, *a], check=True, capture_output=True)  # noqa: E731
    run(str(bindir / "initdb"), "-D", str(data / "db"), "-A", "trust", "-U", "bgap")
    run(
        str(bindir / "pg_ctl"),
        "-D",
        str(data / "db"),
        "-w",
        "-l",
        str(data / "log"),
        "-o",
        f"-p {port} -k {data} -c listen_addresses=127.0.0.1",
        "start",
    )
    yield f"postgresql://bgap@127.0.0.1:{port}/postgres"
    run(str(bindir / "pg_ctl"), "-D", str(data / "db"), "-m", "fast", "stop")
    shutil.rmtree(data, ignore_errors=True)


def scenes_table(folder) -> str:
    """A replay table of six scenes of 30 s at 15 Hz on two lanes, three vehicles each at a
    steady 21-23 m/s, written as the pipeline names its tables
    (``<folder>/sumo-idm-dense/trajectories.parquet``, whose folder names its split)."""
    t = np.arange(451) / 15.0
    rows = [
        pd.DataFrame(
            {
                "episode": scene,
                "frame": np.arange(451),
                "time": t,
                "vehicle_id": vid,
                "x": 30.0 * vid + (20.0 + vid) * t,
                "y": 4.0 * (vid % 2),
                "vx": 20.0 + vid,
                "vy": 0.0,
                "lane": vid % 2,
                "label": "conservative",
            }
        )  # fmt: skip
        for scene in range(6)
        for vid in (1, 2, 3)
    ]
    path = folder / "sumo-idm-dense" / "trajectories.parquet"
    path.parent.mkdir(parents=True)
    pd.concat(rows, ignore_index=True).to_parquet(path)
    return str(path)
