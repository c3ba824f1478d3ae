"""Training a navigation policy: ``python -m bgap.train policy=behavior_rich env=sparse``.

One run folder holds everything (rl-baselines3-zoo style): ``model.zip``, ``config.yaml``
(resolved), ``command.txt``, ``tb/`` (TensorBoard: episode reward, collision rate, average
speed, lane changes, epsilon, loss, periodic evaluations), ``checkpoints/`` (the latest
model, replay buffer, counters and, on the vector backend, the environments' and random
streams' state, every ``profile.checkpoint_every`` steps and on Ctrl-C),
``evaluations.csv`` and ``learning_curves.png`` (the periodic validations) and
``best_model.zip`` with ``best.json`` (the validation-chosen checkpoint that evaluation uses
by default, ``checkpoint=best``). ``resume=true`` continues from the checkpoint: exactly as if never
interrupted on the vector backend; on highway-env (whose environments are not saved) the
environments restart on fresh seeds.

``policy=behavior_rich`` trains in the enriched traffic (mix per ``mix_sampling``);
``policy=default`` trains in highway-env's stock traffic, the paper's "default policy".
"""

from __future__ import annotations

import pickle
import warnings
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from contextlib import ExitStack
from dataclasses import replace
from functools import partial
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig
from stable_baselines3.common.vec_env import VecMonitor
from tqdm import TqdmExperimentalWarning, tqdm

from bgap.agents.monitor import (
    SB3Monitor,
    TrainingMonitor,
    plot_learning_curves,
)
from bgap.agents.observation import with_features
from bgap.common.cluster import (
    ClusterConfig,
    connected,
    kept_trainings,
    run_tasks,
    ship_in,
    task_folder,
    writable,
)
from bgap.common.config import app, load
from bgap.common.errors import ConfigError, Interrupted
from bgap.common.runs import CHECKPOINT_STATE, exclusive, held_by_parent, pack, unpack, write_atomic
from bgap.common.threads import cores_per_process, set_threads
from bgap.experiments.batched import train_batched
from bgap.experiments.config import SCHEMAS, ExperimentConfig
from bgap.experiments.training import (
    build_model,
    member_configs,
    member_dirs,
    model_class,
    open_run_dir,
    read_checkpoint,
    run_dir_for,
    run_name,
    training_config,
)
from bgap.sim.sb3 import SB3VecEnv
from bgap.sim.simulators import make_vector_env
from bgap.sim.vector import VectorHighway
from bgap.traffic.scenario import env_config


def make_training_env(cfg: ExperimentConfig, n_envs: int, seed: int) -> VecMonitor:
    """``n_envs`` training environments (:func:`bgap.sim.simulators.make_vector_env`: one batched
    VectorHighway, or highway-env copies in subprocesses) as an SB3 VecEnv; env k is seeded
    ``seed + k``. Both backends draw each episode's mix themselves (``mix_sampling``)."""
    config = env_config(cfg, cfg.mix_sampling)
    venv = make_vector_env(config, n_envs, cfg.backend, asynchronous=n_envs > 1)
    venv = SB3VecEnv(with_features(venv, cfg.agent.observation, config))
    venv.seed(seed)
    return VecMonitor(venv)


def _vector_highway(env: VecMonitor) -> VectorHighway | None:
    """The VectorHighway inside a training VecEnv (None on highway-env)."""
    inner = env.venv.venv.unwrapped
    return inner if isinstance(inner, VectorHighway) else None


def resume_state(model: Any, env: Any) -> dict[str, Any]:
    """What an exact resume needs beyond the model and replay buffer: the environments
    (vector backend), the global random streams (PER sampling, epsilon draws) and the action
    space's (exploratory actions), which SB3 reseeds when it loads a model."""
    venv = _vector_highway(env)
    return {
        "env": venv.state_dict() if venv is not None else None,
        "action_space": model.action_space.np_random.bit_generator.state,
        "numpy": np.random.get_state(),  # noqa: NPY002 (SB3 and PER draw from it)
        "torch": torch.get_rng_state(),
    }


def train(cfg: ExperimentConfig, progress: bool = True, callbacks: Sequence = ()) -> Path:
    """Train ``cfg.policy`` (resuming if ``cfg.resume``); returns the run folder.

    ``callbacks``: extra SB3 callbacks (the sweeps' pruning evaluations)."""
    if cfg.learner == "batched":
        return train_batched([cfg], progress)[0]
    cfg = training_config(cfg)
    with exclusive(Path(cfg.run_dir) if cfg.run_dir else run_dir_for(cfg)):
        return _train(cfg, progress, callbacks)


def _train(cfg: ExperimentConfig, progress: bool, callbacks: Sequence) -> Path:
    run_dir, status = open_run_dir(cfg)
    if status == "finished":
        return run_dir
    ckpt = run_dir / "checkpoints"
    resuming = status == "resume"
    set_threads(1)  # small MLP: threads cost more than they give
    env = make_training_env(cfg, cfg.profile.n_envs, cfg.seed)
    p = cfg.profile
    monitor = TrainingMonitor(
        run_dir,
        env.num_envs,
        env_config(cfg),
        cfg.backend,
        max_episodes=p.train_episodes,
        eval_every=p.eval_every_episodes,
        eval_episodes=p.eval_during_training,
        eval_seed=cfg.val_seed,  # validation episodes, never the test ones
    )
    if resuming:
        state = read_checkpoint(ckpt, lambda: pickle.loads((ckpt / CHECKPOINT_STATE).read_bytes()))
        venv = _vector_highway(env)
        exact = venv is not None and state["env"] is not None
        model = read_checkpoint(
            ckpt,
            lambda: model_class(cfg.agent.algo).load(
                ckpt / "model.zip",
                env=env,
                device="cpu",
                tensorboard_log=str(run_dir / "tb"),
                force_reset=not exact,
            ),
        )
        if cfg.agent.algo != "ppo":  # on-policy: a rollout starts afresh, no buffer kept
            read_checkpoint(ckpt, lambda: model.load_replay_buffer(ckpt / "replay.pkl"))
        monitor.restore(state)
        if exact:
            venv.load_state_dict(state["env"])
        else:  # highway-env: new episodes on seeds the run has not used
            env.seed(cfg.seed + 1_000_003 * (1 + monitor.state["episodes"]))
        np.random.set_state(state["numpy"])  # noqa: NPY002 (SB3 and PER draw from it)
        torch.set_rng_state(state["torch"])
        model.action_space.np_random.bit_generator.state = state["action_space"]
    else:
        model = build_model(cfg, env, run_dir / "tb")
    callback = SB3Monitor(monitor, p.checkpoint_every, lambda: resume_state(model, env))
    if resuming:
        callback.saved_at = int(model.num_timesteps)
    remaining = p.train_steps - model.num_timesteps
    try:
        # SB3's progress bar is tqdm's rich flavour, which warns that it is experimental
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", category=TqdmExperimentalWarning)
            if remaining > 0:
                model.learn(
                    total_timesteps=remaining,
                    callback=[callback, *callbacks],
                    progress_bar=progress,
                    reset_num_timesteps=not resuming,
                    tb_log_name=cfg.agent.algo,
                )
    except KeyboardInterrupt:
        saved = callback.saved_at
        where = f"the checkpoint of step {saved} is in {ckpt}" if saved else "no checkpoint yet"
        raise Interrupted(
            f"training stopped at step {model.num_timesteps}, {where}; continue with: python -m "
            f"bgap.train resume=true run_dir={run_dir} (and the same overrides)"
        ) from None
    finally:
        env.close()
    if remaining > 0:  # else the checkpoint resumed from is already the last one (a kill
        callback.checkpoint()  # came before model.zip), and the callback never met the model
    write_atomic(run_dir / "model.zip", model.save)  # written last, whole: "finished"
    plot_learning_curves(run_dir)
    return run_dir


SIDE_BY_SIDE_STEPS = 5_000
"""Trainings shorter than this run one after the other in this process: a spawned process
takes seconds to import torch and bgap, more than such a training lasts."""


def train_side_by_side(cfgs: list[ExperimentConfig], workers: int) -> list[Path]:
    """Several SB3 trainings (:func:`member_configs`), ``workers`` at a time, each in its own
    process and run folder (:func:`member_dirs`, locked here for all of them); returns the
    run folders in ``cfgs``' order. Each training seeds itself, so it learns the same as
    alone. One training, or ``workers=1``: in this process, with its progress bar. (The
    batched learner, DQN only, is faster where it applies.)"""
    dirs = member_dirs(cfgs)
    cfgs = [replace(c, run_dir=str(d)) for c, d in zip(cfgs, dirs, strict=True)]
    if cfgs[0].cluster.enabled:
        return _train_on_cluster(cfgs, dirs)
    if workers <= 1 or len(cfgs) == 1 or cfgs[0].profile.train_steps < SIDE_BY_SIDE_STEPS:
        return [train(c) for c in cfgs]
    with ExitStack() as locks, side_by_side_pool(min(workers, len(cfgs))) as pool:
        for d in sorted(set(dirs)):
            locks.enter_context(exclusive(d))
        futures = {pool.submit(_train_worker, c, dirs): c for c in cfgs}
        bar = tqdm(total=len(cfgs), desc=f"{len(cfgs)} trainings, {workers} at a time",
                   unit="training")  # fmt: skip
        try:
            for future in as_completed(futures):
                c = futures[future]
                bar.write(f"finished: {c.policy} seed {c.seed} in {future.result()}")
                bar.update()
        except (KeyboardInterrupt, BrokenProcessPool) as stop:
            pool.shutdown(wait=True, cancel_futures=True)
            why = "stopped" if isinstance(stop, KeyboardInterrupt) else "lost a process"
            raise Interrupted(
                f"trainings {why}; each keeps its last checkpoint in its run folder "
                f"({dirs[0]}, ...); continue with the same command and resume=true"
            ) from None
        finally:
            bar.close()
    return dirs


def side_by_side_pool(workers: int) -> ProcessPoolExecutor:
    """A pool of ``workers`` spawned processes (not forked: a process that has run torch's
    OpenMP cannot fork safely), each with one torch thread and an equal share of the cores
    for the simulator's numba kernels: with numba's default (one thread per core) in every
    process, two trainings on two cores ran four kernel threads and each kernel waited at
    its barrier for a thread the other process held (``python -m bgap.bench side``)."""
    init = partial(set_threads, 1, cores_per_process(workers))
    return ProcessPoolExecutor(workers, get_context("spawn"), initializer=init)


def _train_on_cluster(cfgs: list[ExperimentConfig], dirs: list[Path]) -> list[Path]:
    """Each unfinished training one Ray task (:mod:`bgap.common.cluster`): its run folder
    (config, command, any checkpoint) travels to the node, which trains it there, in
    ``cluster.storage`` when set (a retried task resumes from the lost one's checkpoints),
    and sends the finished folder back here."""
    cluster = cfgs[0].cluster
    if cluster.storage:
        writable(cluster.storage)
    with ExitStack() as locks, connected(cluster):  # one line for a cluster out of reach
        for d in sorted(set(dirs)):
            locks.enter_context(exclusive(d))
        todo = []
        for c, d in zip(cfgs, dirs, strict=True):
            if open_run_dir(c, d)[1] != "finished":  # writes config and command here
                todo.append((c, d))
        calls = [(c, pack(d), cluster.storage) for c, d in todo]
        bar = tqdm(total=len(todo), desc=f"{len(todo)} trainings on {cluster.address}",
                   unit="training")  # fmt: skip

        def done(k: int, packed: bytes) -> None:
            unpack(packed, todo[k][1])
            bar.write(f"finished: {todo[k][0].policy} seed {todo[k][0].seed} in {todo[k][1]}")
            bar.update()

        run_tasks(cluster, _train_task, calls, done, kept_trainings(cluster.storage))
        bar.close()
    return dirs


def _train_task(cfg: ExperimentConfig, packed: bytes, storage: str | None) -> bytes:
    """On a node: the shipped run folder trained to the end (resumed from its checkpoint, or
    from one a lost attempt left in ``storage``), sent back whole."""
    with task_folder(storage) as base:
        work = base / _task_folder_name(cfg)
        ship_in(packed, work)
        train(replace(cfg, run_dir=str(work), resume=True, cluster=ClusterConfig()), False)
        return pack(work)


def _task_folder_name(cfg: ExperimentConfig) -> str:
    """The folder in ``cluster.storage`` where a training's Ray task keeps its checkpoints."""
    return f"{Path(cfg.run_dir).name}-{run_name(cfg)}"


def _train_worker(cfg: ExperimentConfig, held: list[Path]) -> Path:
    held_by_parent(held)  # train_side_by_side locked the run folders for this process
    return train(cfg, progress=False)  # which sets one thread


@app("train", "bgap.train", SCHEMAS)
def main(dcfg: DictConfig) -> None:
    cfg: ExperimentConfig = load(dcfg)
    cfgs = member_configs(cfg)
    if cfg.resume:  # a user's resume=true with nothing to resume is a typo, not a new run
        where = [Path(cfg.run_dir)] if cfg.run_dir else [run_dir_for(c) for c in cfgs]
        if cfg.cluster.address and cfg.cluster.storage:  # where Ray tasks keep checkpoints
            where += [Path(cfg.cluster.storage) / _task_folder_name(c) for c in cfgs]
        if not any(d.exists() for d in where):
            raise ConfigError(
                f"resume=true: nothing to resume at {where[0]} (no such folder); check "
                "run_dir, or drop resume=true to start a new training"
            )
        saved = (CHECKPOINT_STATE, "model.zip")  # a checkpoint, or a finished training
        if not any(any(d.rglob(name)) for d in where if d.exists() for name in saved):
            raise ConfigError(
                f"resume=true: nothing to resume at {where[0]} (no checkpoint was written "
                "there yet); drop resume=true to start the training anew"
            )
    if cfg.learner == "batched":
        dirs = train_batched(cfgs)
    else:
        dirs = train_side_by_side(cfgs, cfg.workers)
    for run_dir in dirs:
        print(f"model: {run_dir / 'model.zip'}")


if __name__ == "__main__":
    main()
