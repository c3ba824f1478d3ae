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
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.vec_env import VecMonitor
from tqdm import TqdmExperimentalWarning, tqdm

from bgap.agents.monitor import (
    ReportSteps,
    SB3Monitor,
    TrainingMonitor,
    plot_learning_curves,
)
from bgap.agents.observation import with_features
from bgap.common.errors import Interrupted
from bgap.common.runs import CHECKPOINT_STATE, write_atomic
from bgap.experiments.batched import (
    batched_members,
    place_members,
    train_batched,
    train_members_on_node,
)
from bgap.experiments.config import ExperimentConfig
from bgap.experiments.training import (
    build_model,
    member_dirs,
    model_class,
    open_run_dir,
    read_checkpoint,
    run_dir_for,
    run_name,
    training_config,
    validation_seed,
)
from bgap.runner.cluster import ClusterConfig, connected, ship_folders
from bgap.runner.jobs import run_jobs
from bgap.runner.locks import all_exclusive
from bgap.runner.progress import Reporter
from bgap.sim.mixture import MixtureHighway
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


def _vector_highway(env: VecMonitor) -> VectorHighway | MixtureHighway | None:
    """The vector backend's environment inside a training VecEnv, whose state an exact
    resume saves (None on highway-env)."""
    inner = env.venv.venv.unwrapped
    return inner if isinstance(inner, (VectorHighway, MixtureHighway)) else None


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
    """Train ``cfg.policy`` with ``cfg.seed`` (resuming if ``cfg.resume``): :func:`trainings`
    of one, in its run folder (``run_dir``, or one named after its settings); returns it.
    ``callbacks``: extra SB3 callbacks (the sweeps' pruning evaluations)."""
    cfg = training_config(cfg)
    if cfg.learner == "batched":
        cfg = batched_members([cfg])[0]
    return _trainings([cfg], [run_dir_for(cfg)], progress, callbacks)[0]


def trainings(
    cfgs: list[ExperimentConfig], progress: bool = True, wait: bool = False
) -> list[Path]:
    """Every training of ``cfgs`` (:func:`member_configs`) to the end, finished ones reused
    and unfinished ones resumed with ``resume=true``; their run folders in ``cfgs``' order
    (:func:`member_dirs`). ``wait``: wait for another command that holds one of the
    folders (two jobs of a multirun that need the same training), instead of refusing."""
    if cfgs[0].learner == "batched":
        cfgs = batched_members(cfgs)
        dirs = member_dirs(cfgs)
    else:
        dirs = member_dirs(cfgs)
        cfgs = [replace(c, run_dir=str(d)) for c, d in zip(cfgs, dirs, strict=True)]
    return _trainings(cfgs, dirs, progress, wait=wait)


def _trainings(
    cfgs: list[ExperimentConfig],
    dirs: list[Path],
    progress: bool,
    callbacks: Sequence = (),
    wait: bool = False,
) -> list[Path]:
    """The one place that decides which learner trains ``cfgs`` and where: one batched
    learner for all (``learner=batched``) or one SB3 training each, here, side by side
    (``workers``) or as Ray tasks (``cluster``); their run folders locked here, while
    this process writes them."""
    first = cfgs[0]
    with all_exclusive(dirs, wait):
        if first.cluster.enabled:
            with connected(first.cluster):  # one line for a cluster out of reach, first
                _on_cluster(cfgs, dirs)
        elif first.learner == "batched":
            train_batched(cfgs, progress)
        else:
            _side_by_side(cfgs, dirs, progress, callbacks)
    return dirs


def _train(
    cfg: ExperimentConfig, progress: bool, callbacks: Sequence, report: Reporter | None = None
) -> Path:
    """One SB3 training, in ``cfg.run_dir`` or the folder named after its settings; its
    progress on ``report`` (a bar of :func:`~bgap.runner.jobs.run_jobs`) or SB3's bar."""
    run_dir, status = open_run_dir(cfg)
    if status == "finished":
        return run_dir
    ckpt = run_dir / "checkpoints"
    resuming = status == "resume"
    callbacks = (*callbacks, *([ReportSteps(report)] if report else []))
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
        eval_seed=validation_seed(cfg),  # validation episodes, never the test ones
        checkpoint_rule=p.checkpoint_rule,
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
                    progress_bar=progress and report is None,
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


def _side_by_side(
    cfgs: list[ExperimentConfig], dirs: list[Path], progress: bool, callbacks: Sequence
) -> None:
    """SB3 trainings, ``workers`` at a time, each in its own process with a progress bar
    here (steps, time left); one after the other here, with one torch thread, when there is
    one, ``workers=1``, or they are short. Each training seeds itself, so it learns the same
    as alone."""
    workers = cfgs[0].workers if cfgs[0].profile.train_steps >= SIDE_BY_SIDE_STEPS else 1
    kept = (
        f"each training keeps its last checkpoint in its run folder ({dirs[0]}, ...); "
        "continue with the same command and resume=true"
    )
    bars = [(f"{c.policy} s{c.seed}", c.profile.train_steps) for c in cfgs]
    run_jobs(
        _train,
        [(c, progress, callbacks) for c in cfgs],
        workers=workers,
        torch_threads=1,  # small MLP: threads cost more than they give
        kept=kept,
        job_bars=bars if progress else None,
    )


def _on_cluster(cfgs: list[ExperimentConfig], dirs: list[Path]) -> None:
    """The unfinished trainings as Ray tasks (:func:`bgap.runner.cluster.ship_folders`): one
    per SB3 training, one for all the members of a batched learner (one process)."""
    todo = [
        k
        for k, (c, d) in enumerate(zip(cfgs, dirs, strict=True))
        if open_run_dir(c, d)[1] != "finished"
    ]  # open_run_dir writes each config and command
    if not todo:
        return
    cluster = cfgs[0].cluster
    if cfgs[0].learner == "batched":
        members = [cfgs[k] for k in todo]
        jobs = [((members,), [dirs[k] for k in todo])]
        place, work, what = place_members, train_members_on_node, "batched learner"
    else:
        jobs = [((cfgs[k],), [dirs[k]]) for k in todo]
        place, work, what = _place_training, _train_on_node, "training"
    bar = tqdm(
        total=len(jobs),
        desc=f"{len(todo)} trainings as {len(jobs)} Ray tasks on {cluster.address}",
        unit="task",
    )

    def done(k: int) -> None:
        bar.write(f"finished: {what} in {', '.join(str(d) for d in jobs[k][1])}")
        bar.update()

    try:
        ship_folders(cluster, place, work, jobs, done)
    finally:
        bar.close()


def _place_training(base: Path, cfg: ExperimentConfig) -> list[Path]:
    """On a node: where a training's Ray task works (kept in ``cluster.storage``)."""
    return [base / task_folder_name(cfg)]


def _train_on_node(base: Path, cfg: ExperimentConfig) -> None:
    """On a node: the shipped run folder trained to the end (resumed from its checkpoint,
    or from one a lost attempt left in ``cluster.storage``)."""
    (placed,) = _place_training(base, cfg)
    train(replace(cfg, run_dir=str(placed), resume=True, cluster=ClusterConfig()), False)


def task_folder_name(cfg: ExperimentConfig) -> str:
    """The folder in ``cluster.storage`` where a training's Ray task keeps its checkpoints."""
    return f"{Path(cfg.run_dir).name}-{run_name(cfg)}"
