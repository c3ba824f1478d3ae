"""Work on a Ray cluster (issue 35): the same numbers as here, one-line errors. Skipped where
Ray is not installed (it is an optional extra: pip install -e ".[cluster]")."""

from __future__ import annotations

import subprocess
import sys

import pytest

from bgap.common.config import validate
from tests.configs import compose

pytest.importorskip("ray")
pytestmark = pytest.mark.cluster


def test_an_evaluation_through_a_local_ray_cluster_writes_the_same_bytes(tmp_path):
    """A tiny trained model and two baselines on the tiny grid, here and as Ray tasks
    (cluster.address=local, each model shipped as its file's bytes): byte-identical
    episode tables; the cluster settings leave the results folder's name alone."""
    from bgap.experiments.run import results_dir
    from bgap.experiments.train import train

    train_cfg = validate(compose("train", ["agent=ppo", "profile=tiny", "env=sparse",
                                           "backend=vector", f"root={tmp_path}"]))  # fmt: skip
    run = train(train_cfg, progress=False)
    tables = []
    for extra in ([], ["cluster.address=local"]):
        out = tmp_path / ("ray" if extra else "here")
        cmd = [sys.executable, "-m", "bgap.evaluate", f"models=[{run}]", "baselines=[idle,rule]",
               "grid=tiny", "env=sparse", "backend=vector", "profile.eval_episodes=6",
               f"out={out}", *extra]  # fmt: skip
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr[-2000:]
        tables.append((out / "episodes.parquet").read_bytes())
    assert tables[0] == tables[1]
    here = validate(compose("run", ["profile=tiny"]))
    there = validate(compose("run", ["profile=tiny", "cluster.address=auto"]))
    assert results_dir(here) == results_dir(there)


def test_an_unreachable_cluster_is_one_line_and_exit_status_2(tmp_path):
    cmd = [sys.executable, "-m", "bgap.evaluate", "baselines=[idle]", "profile.eval_episodes=2",
           "backend=vector", f"out={tmp_path}/ev", "cluster.address=127.0.0.1:9"]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 2
    assert "cannot connect to a Ray cluster" in done.stderr
    assert "Traceback" not in done.stderr


def test_trainings_as_ray_tasks_learn_what_they_learn_here(tmp_path):
    """Two tiny SB3 trainings (seeds=[0,1]) here and as Ray tasks (their run folders shipped
    to the node and back): the same parameters, in the same folders' layout."""
    import torch as th

    from bgap.agents.policies import load_model
    from bgap.experiments.train import train_side_by_side
    from bgap.experiments.training import member_configs

    dirs = {}
    for extra in ([], ["cluster.address=local"]):
        where = "ray" if extra else "here"
        overrides = ["agent=ppo", "profile=tiny", "env=sparse", "seeds=[0,1]", "backend=vector",
                     f"run_dir={tmp_path}/{where}", *extra]  # fmt: skip
        dirs[where] = train_side_by_side(member_configs(validate(compose("train", overrides))), 1)
    for here, there in zip(dirs["here"], dirs["ray"], strict=True):
        assert here.name == there.name and (there / "config.yaml").exists()
        a, b = (load_model(d).policy.state_dict() for d in (here, there))
        assert all(th.equal(a[k], b[k]) for k in a)
