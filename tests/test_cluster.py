"""Work on a Ray cluster (issue 35): the same numbers as here, one-line errors. Skipped where
Ray is not installed (it is an optional extra: pip install -e ".[cluster]")."""

from __future__ import annotations

import os
import shlex
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
    from bgap.experiments.train import trainings
    from bgap.experiments.training import member_configs

    dirs = {}
    for extra in ([], ["cluster.address=local"]):
        where = "ray" if extra else "here"
        overrides = ["agent=ppo", "profile=tiny", "env=sparse", "seeds=[0,1]", "backend=vector",
                     f"run_dir={tmp_path}/{where}", *extra]  # fmt: skip
        dirs[where] = trainings(member_configs(validate(compose("train", overrides))), False)
    for here, there in zip(dirs["here"], dirs["ray"], strict=True):
        assert here.name == there.name and (there / "config.yaml").exists()
        a, b = (load_model(d).policy.state_dict() for d in (here, there))
        assert all(th.equal(a[k], b[k]) for k in a)


@pytest.fixture
def nodes():
    """A Ray cluster of separate node processes on this machine
    (``ray.cluster_utils.Cluster``): a head without CPUs (the driver's), nodes added by the
    test, one CPU each, so that a task runs on a node the test can kill."""
    from ray.cluster_utils import Cluster

    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 0})
    yield cluster
    cluster.shutdown()


def _in_thread(fn, *args):
    """``fn(*args)`` in a thread; returns a function that joins it and gives its result (or
    raises its error)."""
    import threading

    out: dict = {}

    def target():
        try:
            out["value"] = fn(*args)
        except BaseException as err:  # noqa: BLE001 - handed to the joining test
            out["error"] = err

    thread = threading.Thread(target=target, daemon=True)
    thread.start()

    def join(timeout=600):
        thread.join(timeout)
        assert not thread.is_alive(), "still running"
        if "error" in out:
            raise out["error"]
        return out["value"]

    return join


def _wait_for(condition, timeout=300, what="the condition"):
    import time

    deadline = time.time() + timeout
    while not condition():
        assert time.time() < deadline, f"timed out waiting for {what}"
        time.sleep(0.2)


def test_a_training_whose_node_dies_resumes_on_another_and_learns_the_same(tmp_path, nodes):
    """An SB3 DQN training as a Ray task on node A, checkpoints in cluster.storage; node A is
    killed after a checkpoint and before the end; Ray retries the task on node B, which
    resumes from the checkpoint: the final parameters equal an uninterrupted local
    training's."""
    import torch as th

    from bgap.agents.policies import load_model
    from bgap.experiments.train import train, trainings
    from bgap.experiments.training import member_configs

    base = ["profile=tiny", "profile.train_steps=3000", "profile.checkpoint_every=300",
            "env=sparse", "backend=vector"]  # fmt: skip
    whole = train(validate(compose("train", [*base, f"run_dir={tmp_path}/whole"])), False)
    first = nodes.add_node(num_cpus=1)
    storage = tmp_path / "storage"
    overrides = [*base, f"run_dir={tmp_path}/cut", f"cluster.address={nodes.address}",
                 f"cluster.storage={storage}"]  # fmt: skip
    cfgs = member_configs(validate(compose("train", overrides)))
    join = _in_thread(trainings, cfgs, False)
    _wait_for(lambda: any(storage.glob("*/checkpoints/state.pkl")), what="a checkpoint")
    assert not any(storage.glob("*/model.zip")), "finished before the kill: train longer"
    nodes.add_node(num_cpus=1)
    nodes.remove_node(first)  # the node dies with its worker, mid-training
    (cut,) = join()
    a, b = (load_model(d).policy.state_dict() for d in (whole, cut))
    assert all(th.equal(a[k], b[k]) for k in a)


def test_a_sweep_worker_killed_mid_trial_loses_no_trial(tmp_path, nodes, postgres, monkeypatch):
    """Two Optuna workers as Ray tasks on two nodes sharing a PostgreSQL study; one node is
    killed while its worker's trial runs (heartbeat recorded). The study still ends with the
    asked number of finished trials, the dead worker's trial is failed (its heartbeat
    stopped), and no trial's run folder is used twice."""
    import optuna
    import sqlalchemy
    from optuna.trial import TrialState

    import bgap.common.studies as studies
    from bgap.experiments.sweep import sweep

    monkeypatch.setattr(studies, "HEARTBEAT", (1, 3))  # handed to the workers
    first = nodes.add_node(num_cpus=1)
    nodes.add_node(num_cpus=1)
    cfg = validate(compose("sweep", [
        "profile=tiny", "sweep_eval_episodes=4", "trials=4", "mode=single", "workers=2",
        f"storage={postgres}", "study=ray-killed", f"root={tmp_path}",
        f"preset={tmp_path}/tuned.yaml", f"cluster.address={nodes.address}",
    ]))  # fmt: skip
    join = _in_thread(sweep, cfg, False)
    engine = sqlalchemy.create_engine(postgres)
    beating = sqlalchemy.text(
        "SELECT count(*) FROM trials t JOIN trial_heartbeats h ON h.trial_id = t.trial_id"
        " WHERE t.state = 'RUNNING'"
    )

    def two_beating() -> bool:
        try:
            with engine.connect() as db:
                return db.execute(beating).scalar() >= 2
        except sqlalchemy.exc.ProgrammingError:  # no tables yet
            return False

    _wait_for(two_beating, what="both workers' trials")
    engine.dispose()
    nodes.remove_node(first)  # one of the two running trials loses its worker
    nodes.add_node(num_cpus=1)  # where Ray retries the lost worker
    join()
    study = optuna.load_study(study_name="ray-killed", storage=postgres)
    states = [t.state for t in study.trials]
    assert sum(s in (TrialState.COMPLETE, TrialState.PRUNED) for s in states) >= 4
    assert TrialState.FAIL in states and TrialState.RUNNING not in states
    runs = [t.user_attrs["run_dir"] for t in study.trials if t.state != TrialState.FAIL]
    assert len(set(runs)) == len(runs)


def test_a_sweep_sent_to_the_cluster_by_the_environment_runs_its_workers_once(tmp_path):
    """``BGAP_CLUSTER_ADDRESS=local`` (how ``dvc repro`` sends a stage to a cluster): the two
    workers run the study's trials themselves. They used to read the address back and send
    the sweep to the cluster again, workers starting workers until memory ran out."""
    import optuna

    cmd = [sys.executable, "-m", "bgap.sweep", "profile=tiny", "sweep_eval_episodes=4",
           "trials=2", "mode=single", "workers=2", "study=by-env", f"root={tmp_path}",
           f"preset={tmp_path}/tuned.yaml"]  # fmt: skip
    env = {**os.environ, "BGAP_CLUSTER_ADDRESS": "local"}
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    url = f"sqlite:///{tmp_path}/sweeps/optuna.db"
    trials = optuna.load_study(study_name="by-env", storage=url).trials
    assert 2 <= len(trials) <= 3  # 2 finished; at most one more in flight when they ended
    assert len(list((tmp_path / "sweeps" / "by-env").glob("trial-*"))) == len(trials)


def test_a_sweep_on_several_nodes_refuses_a_sqlite_study(tmp_path):
    cmd = [sys.executable, "-m", "bgap.sweep", "profile=tiny", "cluster.address=10.0.0.1:6379",
           f"root={tmp_path}"]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 2 and "cannot share a SQLite file" in done.stderr
    assert "Traceback" not in done.stderr


def test_ctrl_c_on_the_driver_cancels_the_tasks_and_says_what_was_kept(tmp_path):
    """Ctrl-C while a training runs as a Ray task (cluster.address=local): one line naming
    what was kept (its checkpoints in cluster.storage) and the exit status of an
    interruption; the same command with resume=true then finishes from there."""
    import signal
    import time

    from bgap.common.cli import INTERRUPTED

    storage = tmp_path / "storage"
    # long enough that the Ctrl-C, sent at the first checkpoint, always finds it running
    # (at 3,000 steps an idle machine finished first)
    cmd = [sys.executable, "-m", "bgap.train", "profile=tiny", "profile.train_steps=20000",
           "profile.checkpoint_every=300", "env=sparse", "backend=vector",
           f"run_dir={tmp_path}/run", "cluster.address=local",
           f"cluster.storage={storage}"]  # fmt: skip
    driver = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 300
    while not any(storage.glob("*/checkpoints/state.pkl")):
        assert time.time() < deadline and driver.poll() is None, driver.communicate()[1][-2000:]
        time.sleep(0.2)
    driver.send_signal(signal.SIGINT)
    _, err = driver.communicate(timeout=120)
    assert driver.returncode == INTERRUPTED, err[-2000:]
    lines = [line for line in err.splitlines() if "interrupted" in line]
    assert len(lines) == 1 and "cancelled" in lines[0] and str(storage) in lines[0]
    assert "Traceback" not in err
    resumed = subprocess.run([*cmd, "resume=true"], capture_output=True, text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert (tmp_path / "run" / "model.zip").exists()
    # the driver's command, not the command line of Ray's worker process that trained it
    typed = shlex.join(["python", *cmd[1:], "resume=true"])
    assert (tmp_path / "run" / "command.txt").read_text() == typed + "\n"


def test_a_cluster_that_wants_a_token_refuses_a_driver_without_one_in_one_line(tmp_path):
    """A head started with Ray's token authentication (RAY_AUTH_MODE=token): a driver with
    no token is one line naming the token and exit status 2, and writes nothing; with the
    cluster's token the same command runs."""
    import os
    import secrets
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    token = secrets.token_hex(16)
    home = {**os.environ, "HOME": str(tmp_path), "RAY_AUTH_MODE": "token"}  # no token file
    home.pop("RAY_AUTH_TOKEN", None)
    ray = [sys.executable, "-m", "ray.scripts.scripts"]
    start = [*ray, "start", "--head", f"--port={port}", "--num-cpus=1",
             "--include-dashboard=false"]  # fmt: skip
    subprocess.run(start, env={**home, "RAY_AUTH_TOKEN": token}, check=True, capture_output=True,
                   timeout=120)  # fmt: skip
    try:
        cmd = [sys.executable, "-m", "bgap.evaluate", "baselines=[idle]", "backend=vector",
               "profile.eval_episodes=2", f"cluster.address=127.0.0.1:{port}"]  # fmt: skip
        done = subprocess.run([*cmd, f"out={tmp_path}/no"], env=home, capture_output=True,
                              text=True, timeout=300)  # fmt: skip
        assert done.returncode == 2, done.stderr[-2000:]
        assert done.stderr.count("\n") == 1 and "none is set" in done.stderr
        assert not (tmp_path / "no").exists()
        done = subprocess.run([*cmd, f"out={tmp_path}/yes"], env={**home, "RAY_AUTH_TOKEN": token},
                              capture_output=True, text=True, timeout=300)  # fmt: skip
        assert done.returncode == 0, done.stderr[-2000:]
    finally:
        subprocess.run([*ray, "stop", "--force"], env=home, capture_output=True, timeout=120)


def test_a_batched_stage_through_a_two_node_cluster_learns_what_it_learns_here(tmp_path, nodes):
    """A tiny study stage (2 seeds x 2 policies, the batched learner) here and as one Ray
    task on a 2-node cluster: every member's parameters equal, in the same folders."""
    import torch as th

    from bgap.agents.policies import load_model
    from bgap.experiments.train import trainings
    from bgap.experiments.training import member_configs

    nodes.add_node(num_cpus=1)
    nodes.add_node(num_cpus=1)
    dirs = {}
    for extra in ([], [f"cluster.address={nodes.address}"]):
        where = "ray" if extra else "here"
        overrides = ["learner=batched", "profile=tiny", "env=sparse", "seeds=[0,1]",
                     "policies=[behavior_rich,default]", f"run_dir={tmp_path}/{where}",
                     *extra]  # fmt: skip
        dirs[where] = trainings(member_configs(validate(compose("train", overrides))), False)
    assert [d.name for d in dirs["here"]] == [d.name for d in dirs["ray"]]
    for here, there in zip(dirs["here"], dirs["ray"], strict=True):
        assert (there / "config.yaml").exists() and (there / "model.zip").exists()
        a, b = (load_model(d).policy.state_dict() for d in (here, there))
        assert all(th.equal(a[k], b[k]) for k in a)
