"""Many trainings in one batched learner (``learner=batched``): the members' environments
stepped together, each member's run folder, checkpoints and resume as :func:`train` writes
them (:mod:`bgap.experiments.train`); the algorithm is :class:`bgap.agents.batched.BatchedDQN`."""

from __future__ import annotations

import json
import pickle
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.vec_env import DummyVecEnv
from torch.utils.tensorboard import SummaryWriter
from tqdm import tqdm

from bgap.agents.batched import BatchedDQN, Schedule
from bgap.agents.monitor import (
    INFO_KEYS,
    TrainingMonitor,
    plot_learning_curves,
)
from bgap.agents.observation import MODEL_ATTRIBUTE, with_features
from bgap.common.errors import ConfigError, Interrupted, check
from bgap.common.runs import CHECKPOINT_STATE, digest, write_atomic
from bgap.experiments.config import ExperimentConfig
from bgap.experiments.training import (
    build_model,
    member_dirs,
    open_run_dir,
    read_checkpoint,
    run_name,
    training_config,
    validation_seed,
)
from bgap.runner.cluster import ClusterConfig
from bgap.runner.interrupt import CtrlC
from bgap.runner.threads import set_threads
from bgap.sim.simulators import make_vector_env
from bgap.traffic.scenario import env_config


# ---------------------------------------------------------------------- batched learner
class _DummyEnv(gym.Env):
    """Spaces only: SB3 needs an environment to build the model a member is saved as."""

    def __init__(self, observation_space: gym.Space, action_space: gym.Space) -> None:
        self.observation_space, self.action_space = observation_space, action_space


class _MemberPolicy:
    """Member k of a batched learner seen as a model (``predict``, ``save``, ``_n_updates``)
    by :class:`~bgap.agents.monitor.TrainingMonitor`'s periodic evaluations."""

    def __init__(
        self,
        learner: BatchedDQN,
        k: int,
        save: Callable[[int, Path], None],
        options: list[str],
        observation_space: gym.Space,
    ) -> None:
        self.learner, self.k, self._save = learner, k, save
        setattr(self, MODEL_ATTRIBUTE, options)  # its observation's added columns
        self.observation_space = observation_space  # what a model played by rollout has

    def save(self, path: Path) -> None:
        self._save(self.k, path)

    @property
    def _n_updates(self) -> int:
        return int(self.learner.n_updates[self.k])

    def predict(self, obs: np.ndarray, deterministic: bool = True) -> tuple[np.ndarray, None]:
        return self.learner.greedy(np.asarray(obs)[None], [self.k])[0], None


@dataclass
class _Group:
    """One vector environment for the members that share a traffic config."""

    venv: Any
    members: list[int]
    n_envs: int

    def envs_of(self, position: int) -> list[int]:
        return list(range(position * self.n_envs, (position + 1) * self.n_envs))


def batched_members(cfgs: Sequence[ExperimentConfig]) -> list[ExperimentConfig]:
    """``cfgs`` as the members of one batched learner, or one line saying why they cannot
    be: the same agent, profile and backend (any policy family, seed and traffic), each
    in a run folder of its own."""
    check(len(cfgs) >= 1, "seeds", [], "the batched learner needs at least one training")
    cfgs = [replace(training_config(c), learner="batched") for c in cfgs]
    first = cfgs[0]
    for c in cfgs[1:]:
        for key in ("agent", "profile", "backend"):
            if getattr(c, key) != getattr(first, key):
                raise ConfigError(
                    f"members of one batched learner need the same {key}: seed {c.seed} "
                    f"({c.policy}) differs from seed {first.seed} ({first.policy})"
                )
    dirs = member_dirs(cfgs)
    if len(set(dirs)) < len(dirs):
        raise ConfigError(f"two members share a run folder: {[str(d) for d in dirs]}")
    return cfgs


def train_batched(
    cfgs: Sequence[ExperimentConfig], progress: bool = True, sb3_streams: bool = False
) -> list[Path]:
    """Train every config of ``cfgs`` (:func:`batched_members`) here, in one
    :class:`~bgap.agents.batched.BatchedDQN`; each member gets the run folder
    :func:`~bgap.experiments.train.train` writes (config, command, ``tb/``,
    ``evaluations.csv``, checkpoints, an SB3-loadable ``model.zip``). Finished members are
    reused, unfinished ones resumed (``resume=true``) from their own checkpoints; returns
    the run folders. ``sb3_streams``: one member drawing from SB3's random streams
    (:class:`~bgap.agents.batched.BatchedDQN`), to compare a whole training with SB3's.
    (:func:`bgap.experiments.train.trainings` locks the folders and sends the members to
    a cluster.)"""
    cfgs = batched_members(cfgs)
    dirs = member_dirs(cfgs)
    _open_and_train(cfgs, dirs, progress, sb3_streams)
    return dirs  # every member's, the finished ones' too


def place_members(base: Path, cfgs: list[ExperimentConfig]) -> list[Path]:
    """On a node: where a batched learner's Ray task keeps its members' run folders (in
    ``cluster.storage``, so that a retried task resumes from the lost one's checkpoints)."""
    return member_dirs(_on_node(base, cfgs))


def train_members_on_node(base: Path, cfgs: list[ExperimentConfig]) -> None:
    """On a node: the shipped members trained to the end in one batched learner (each
    resumed from its checkpoint, or from one a lost attempt left in ``cluster.storage``)."""
    train_batched(_on_node(base, cfgs), progress=False)


def _on_node(base: Path, cfgs: list[ExperimentConfig]) -> list[ExperimentConfig]:
    group = base / f"batched-{digest([run_name(c) for c in cfgs])}"
    return [
        replace(c, run_dir=str(group), root=str(base), cluster=ClusterConfig(), resume=True)
        for c in cfgs
    ]


def _open_and_train(
    cfgs: list[ExperimentConfig], dirs: list[Path], progress: bool, sb3_streams: bool
) -> None:
    opened = [open_run_dir(c, d) for c, d in zip(cfgs, dirs, strict=True)]
    todo = [i for i, (_, status) in enumerate(opened) if status != "finished"]
    if not todo:
        return
    resuming = [opened[i][1] == "resume" for i in todo]
    for i, res in zip(todo, resuming, strict=True):
        if res and not (dirs[i] / "checkpoints" / "learner.pt").exists():
            raise ConfigError(
                f"{dirs[i]} holds a checkpoint of the sb3 learner: resume it with learner=sb3"
            )
    _train_members(
        [cfgs[i] for i in todo], [dirs[i] for i in todo], resuming, progress, sb3_streams
    )


def _train_members(
    cfgs: list[ExperimentConfig],
    dirs: list[Path],
    resuming: list[bool],
    progress: bool,
    sb3_streams: bool = False,
) -> None:
    members = _Members(cfgs, dirs, resuming, sb3_streams)
    bar = tqdm(
        total=int(members.p.train_steps * len(cfgs)),
        initial=int(members.learner.num_timesteps.sum()),
        disable=not progress,
        unit="step",
        desc=f"{len(cfgs)} trainings",
    )
    try:
        with CtrlC() as interrupted:
            for k in np.flatnonzero(~members.active):  # resumed at its budget: only the end
                members.finish(k)
            while members.active.any():
                if interrupted.requested:
                    for k in np.flatnonzero(members.active):
                        members.checkpoint(k)
                    raise KeyboardInterrupt
                bar.update(members.step())
    except KeyboardInterrupt:
        steps = ", ".join(
            f"{d.name}: {int(n)}" for d, n in zip(dirs, members.last_ckpt, strict=True)
        )
        raise Interrupted(
            f"batched training stopped; checkpoints at steps {steps}; continue with the same "
            "command and resume=true"
        ) from None
    finally:
        bar.close()
        for g in members.groups:
            g.venv.close()


class _Members:
    """The trainings of one batched learner: their environments (members sharing a traffic
    config share one vector environment; per-env seeds and random streams keep each
    member's episodes those of its own training), monitors, TensorBoard writers and run
    folders. :meth:`step` advances every active member by one vector step."""

    def __init__(
        self, cfgs: list[ExperimentConfig], dirs: list[Path], resuming: list[bool], sb3: bool
    ) -> None:
        self.cfgs, self.dirs = cfgs, dirs
        self.p, self.first = cfgs[0].profile, cfgs[0]
        self.e = e = self.p.n_envs
        if self.first.threads:
            set_threads(self.first.threads)
        self.groups = self._make_groups()
        self.space = space = self.groups[0].venv.single_observation_space
        action_space = self.groups[0].venv.single_action_space
        schedule = Schedule(
            e,
            self.p.train_steps,
            self.p.exploration_decay_steps or self.first.agent.exploration_decay_steps,
        )
        self.learner = BatchedDQN(
            self.first.agent,
            schedule,
            [c.seed for c in cfgs],
            int(np.prod(space.shape)),
            int(action_space.n),
            sb3_streams=sb3,
        )
        if sb3:
            np.random.seed(self.first.seed)  # noqa: NPY002 (SB3's set_random_seed)
        self.writers = [SummaryWriter(str(d / "tb" / "batched_1")) for d in dirs]
        self.monitors = [self._monitor(k) for k in range(len(cfgs))]
        self.obs = self._reset(space, resuming)
        self.template = build_model(
            self.first, DummyVecEnv([lambda: _DummyEnv(space, action_space)] * e), dirs[0] / "tb"
        )
        self.where = {k: (g, pos) for g in self.groups for pos, k in enumerate(g.members)}
        self.active = self.learner.num_timesteps < self.p.train_steps
        self.last_ckpt = self.learner.num_timesteps.copy()

    def _make_groups(self) -> list[_Group]:
        configs = [env_config(c, c.mix_sampling) for c in self.cfgs]
        keys = [json.dumps(c, sort_keys=True, default=str) for c in configs]
        groups: list[_Group] = []
        for key in dict.fromkeys(keys):
            members = [k for k, other in enumerate(keys) if other == key]
            venv = make_vector_env(
                configs[members[0]],
                len(members) * self.e,
                self.first.backend,
                asynchronous=self.first.backend == "highway",
            )
            venv = with_features(venv, self.cfgs[members[0]].agent.observation, configs[members[0]])
            groups.append(_Group(venv, members, self.e))
        shape = groups[0].venv.single_observation_space.shape
        for g in groups:
            if g.venv.single_observation_space.shape != shape:
                raise ConfigError(
                    "members of one batched learner need the same observation shape: "
                    f"{g.venv.single_observation_space.shape} vs {shape} (env settings)"
                )
        return groups

    def _monitor(self, k: int) -> TrainingMonitor:
        c, p = self.cfgs[k], self.p

        def log(key: str, value: float) -> None:
            self.writers[k].add_scalar(key, value, int(self.learner.num_timesteps[k]))

        return TrainingMonitor(
            self.dirs[k],
            self.e,
            env_config(c),
            c.backend,
            max_episodes=p.train_episodes,
            eval_every=p.eval_every_episodes,
            eval_episodes=p.eval_during_training,
            eval_seed=validation_seed(c),
            checkpoint_rule=p.checkpoint_rule,
            log=log,
        )

    def _reset(self, space: gym.Space, resuming: list[bool]) -> np.ndarray:
        """The first observations, each resumed member's learner, monitor and (on the vector
        backend) environments restored from its checkpoint."""
        cfgs, dirs, e = self.cfgs, self.dirs, self.e
        states = [
            read_checkpoint(
                d / "checkpoints",
                lambda d=d: pickle.loads((d / "checkpoints" / CHECKPOINT_STATE).read_bytes()),
            )
            if res
            else None
            for d, res in zip(dirs, resuming, strict=True)
        ]
        obs = np.zeros((len(cfgs), e, *space.shape), dtype=np.float32)
        for g in self.groups:
            seeds = []
            for k in g.members:
                start = cfgs[k].seed
                if states[k] is not None and states[k]["env"] is None:  # highway-env: fresh
                    start = cfgs[k].seed + 1_000_003 * (1 + states[k]["monitor"]["episodes"])
                seeds += [start + j for j in range(e)]
            first_obs, _ = g.venv.reset(seed=seeds)
            for pos, k in enumerate(g.members):
                obs[k] = first_obs[g.envs_of(pos)]
                if states[k] is None:
                    continue
                ckpt = dirs[k] / "checkpoints"
                member = read_checkpoint(
                    ckpt, lambda ckpt=ckpt: torch.load(ckpt / "learner.pt", weights_only=False)
                )
                self.learner.load_member_state(k, member)
                self.monitors[k].restore(states[k])
                if states[k]["env"] is not None:
                    g.venv.load_state_dict(states[k]["env"], envs=g.envs_of(pos))
                    obs[k] = g.venv.observations()[g.envs_of(pos)]
        return obs

    def save_model(self, k: int, path: Path) -> None:
        """Member ``k`` as an SB3 DQN ``model.zip`` (loadable with ``DQN.load``)."""
        learner, template = self.learner, self.template
        template.policy.q_net.load_state_dict(learner.member_network(k))
        template.policy.q_net_target.load_state_dict(learner.member_network(k, target=True))
        template.num_timesteps = int(learner.num_timesteps[k])
        template._n_updates = int(learner.n_updates[k])
        template._n_calls = int(learner.n_calls[k])
        template.exploration_rate = float(learner.exploration_rate[k])
        template.seed = self.cfgs[k].seed
        template.save(path)

    def checkpoint(self, k: int) -> None:
        g, pos = self.where[k]
        self.monitors[k].state["steps"] = int(self.learner.num_timesteps[k])
        vector = self.first.backend == "vector"
        env_state = g.venv.state_dict(envs=g.envs_of(pos)) if vector else None
        self.monitors[k].checkpoint(
            {
                "model.zip": lambda path: self.save_model(k, path),
                "learner.pt": lambda path: torch.save(self.learner.member_state(k), path),
            },
            {"env": env_state, "learner": "batched"},
        )
        self.last_ckpt[k] = self.learner.num_timesteps[k]
        self.writers[k].flush()

    def finish(self, k: int) -> None:
        self.checkpoint(k)
        write_atomic(self.dirs[k] / "model.zip", lambda tmp: self.save_model(k, tmp))
        self.writers[k].close()
        plot_learning_curves(self.dirs[k])
        self.active[k] = False

    def step(self) -> int:
        """One vector step of every active member: act, simulate, store, update; returns the
        environment steps taken."""
        learner, e, n = self.learner, self.e, len(self.cfgs)
        members = np.flatnonzero(self.active)
        due = learner.num_timesteps[members] - self.last_ckpt[members] >= self.p.checkpoint_every
        for k in members[due]:
            self.checkpoint(k)
        actions = learner.act(self.obs, members)
        new_obs, next_obs = np.empty_like(self.obs), np.empty_like(self.obs)
        rewards = np.zeros((n, e), dtype=np.float32)
        terminated, truncated = np.zeros((n, e), dtype=bool), np.zeros((n, e), dtype=bool)
        infos: list[dict[str, Any]] = [{} for _ in range(n)]
        for g in self.groups:
            o, r, term, trunc, info = g.venv.step(actions[g.members].reshape(-1))
            final = final_observations(o, term | trunc, info)
            for pos, k in enumerate(g.members):
                envs = g.envs_of(pos)
                new_obs[k], next_obs[k], rewards[k] = o[envs], final[envs], r[envs]
                terminated[k], truncated[k] = term[envs], trunc[envs]
                infos[k] = _member_info(info, envs)
        learner.num_timesteps[members] += e
        keep = []
        for k in members:
            self.monitors[k].state["steps"] = int(learner.num_timesteps[k])
            go_on = self.monitors[k].on_step(
                rewards[k],
                infos[k],
                terminated[k] | truncated[k],
                _MemberPolicy(
                    learner, k, self.save_model, self.first.agent.observation, self.space
                ),
            )
            if go_on:
                keep.append(k)
            else:  # the episode budget: SB3 stops before storing this transition
                self.finish(k)
        keep_ = np.asarray(keep, dtype=np.int64)
        if len(keep_):
            step = (self.obs, next_obs, actions, rewards, terminated, truncated)
            learner.observe(keep_, *(a[keep_] for a in step))
        self.obs = new_obs
        learner.train(keep_)
        self._log_and_finish(keep_)
        return e * len(members)

    def _log_and_finish(self, members: np.ndarray) -> None:
        learner = self.learner
        for k in members:
            steps = int(learner.num_timesteps[k])
            if learner.num_timesteps[k] % 1000 < self.e:
                self.writers[k].add_scalar("train/loss", learner.last_loss[k], steps)
                self.writers[k].add_scalar(
                    "rollout/exploration_rate", learner.exploration_rate[k], steps
                )
            if learner.num_timesteps[k] >= self.p.train_steps:
                self.finish(k)


def final_observations(obs: np.ndarray, done: np.ndarray, info: dict[str, Any]) -> np.ndarray:
    """The observations a vector step ended in: ``obs``, except that an env reset in that
    step ends in its finished episode's last observation (``info["final_obs"]``, the
    simulators' same-step auto-reset), which is what a replay buffer stores as next state."""
    final = obs.copy()
    for b in np.flatnonzero(done):
        final[b] = info["final_obs"][b]
    return final


def _member_info(info: dict[str, Any], envs: list[int]) -> dict[str, Any]:
    """The arrays of a vector env's info for some of its envs."""
    out: dict[str, Any] = {k: np.asarray(info[k])[envs] for k in INFO_KEYS if k in info}
    if "rewards" in info:
        out["rewards"] = {t: np.asarray(v)[envs] for t, v in info["rewards"].items()}
    return out
