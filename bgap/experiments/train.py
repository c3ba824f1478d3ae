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

import json
import pickle
import signal
import threading
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor
from torch.utils.tensorboard import SummaryWriter
from tqdm import TqdmExperimentalWarning, tqdm

from bgap.agents.batched import BatchedDQN, Schedule
from bgap.agents.dqn import DQN
from bgap.agents.monitor import (
    INFO_KEYS,
    SB3Monitor,
    TrainingMonitor,
    plot_learning_curves,
    recover_checkpoint,
)
from bgap.agents.per import PrioritizedReplayBuffer
from bgap.common.config import app, load
from bgap.common.errors import ConfigError, Interrupted, check
from bgap.common.runs import VOLATILE, digest, save_run_metadata
from bgap.experiments.config import SCHEMAS, ExperimentConfig
from bgap.sim.sb3 import SB3VecEnv
from bgap.sim.simulators import make_vector_env
from bgap.sim.vector import VectorHighway
from bgap.traffic.behaviors import BehaviorConfig
from bgap.traffic.scenario import env_config

NOT_LEARNT = (
    *VOLATILE, "models", "baselines", "grid", "eval_seed", "val_seed", "out", "seeds",
    "policies", "threads", "checkpoint",
)  # fmt: skip
"""Settings of a training's config that do not change what it learns (run folder checks).
(``val_seed`` only moves the periodic evaluations' episodes; ``eval_seed`` the tests'.)"""


def training_config(cfg: ExperimentConfig, policy: str | None = None) -> ExperimentConfig:
    """The config a policy trains under: ``default`` swaps in stock traffic."""
    policy = policy or cfg.policy
    cfg = replace(cfg, policy=policy)
    if policy == "default":
        cfg = replace(cfg, behavior=BehaviorConfig(name="stock"), mix_sampling="fixed")
    return cfg


def training_identity(cfg: ExperimentConfig) -> dict[str, Any]:
    """Everything that changes what a training learns."""
    keys = {
        k: asdict(cfg)[k]
        for k in (
            "env",
            "behavior",
            "reward",
            "agent",
            "radius",
            "seed",
            "policy",
            "mix_sampling",
            "backend",
        )
    }
    keys["mix"] = cfg.mix if cfg.policy == "behavior_rich" else None
    if cfg.learner != "sb3":  # (the SB3 runs' names predate this setting)
        keys["learner"] = cfg.learner
    keys["profile"] = {
        k: v for k, v in asdict(cfg.profile).items() if k not in ("eval_episodes", "name")
    }
    return keys


def run_name(cfg: ExperimentConfig) -> str:
    """Readable prefix plus a hash of everything that changes what is learnt."""
    mix = f"mix{cfg.mix:g}" if cfg.mix_sampling == "fixed" else f"mix-{cfg.mix_sampling}"
    mix = mix if cfg.policy == "behavior_rich" else "stock"
    name = f"{cfg.env.name}-{cfg.policy}-{mix}-{cfg.profile.name}-s{cfg.seed}"
    name += f"-{cfg.learner}" if cfg.learner != "sb3" else ""
    return f"{name}-{digest(training_identity(cfg))}"


def run_dir_for(cfg: ExperimentConfig) -> Path:
    return Path(cfg.run_dir) if cfg.run_dir else Path(cfg.root) / "runs" / run_name(cfg)


def make_training_env(cfg: ExperimentConfig, n_envs: int, seed: int) -> VecMonitor:
    """``n_envs`` training environments (:func:`bgap.sim.simulators.make_vector_env`: one batched
    VectorHighway, or highway-env copies in subprocesses) as an SB3 VecEnv; env k is seeded
    ``seed + k``. Both backends draw each episode's mix themselves (``mix_sampling``)."""
    config = env_config(cfg, cfg.mix_sampling)
    venv = SB3VecEnv(make_vector_env(config, n_envs, cfg.backend, asynchronous=n_envs > 1))
    venv.seed(seed)
    return VecMonitor(venv)


def _vector_highway(env: VecMonitor) -> VectorHighway | None:
    """The VectorHighway inside a training VecEnv (None on highway-env)."""
    inner = env.venv.venv
    return inner if isinstance(inner, VectorHighway) else None


def resume_state(model: DQN, env: Any) -> dict[str, Any]:
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


def build_model(cfg: ExperimentConfig, env, tb_dir: Path) -> DQN:
    a = cfg.agent
    per = a.replay == "per"
    return DQN(
        "MlpPolicy",
        env,
        learning_rate=a.learning_rate,
        buffer_size=a.buffer_size,
        learning_starts=a.learning_starts,
        batch_size=a.batch_size,
        gamma=a.gamma,
        train_freq=a.train_freq,
        gradient_steps=a.gradient_steps,
        target_update_interval=a.target_update_interval,
        exploration_initial_eps=a.exploration_initial,
        exploration_final_eps=a.exploration_final,
        exploration_decay_steps=cfg.profile.exploration_decay_steps or a.exploration_decay_steps,
        max_grad_norm=a.max_grad_norm,
        replay_buffer_class=PrioritizedReplayBuffer if per else None,
        replay_buffer_kwargs={"alpha": a.per_alpha, "beta0": a.per_beta0} if per else None,
        per_beta_steps=cfg.profile.train_steps,
        loss=a.loss,
        policy_kwargs={"net_arch": list(a.net_arch)},
        tensorboard_log=str(tb_dir),
        seed=cfg.seed,
        device="cpu",
        verbose=0,
    )


def open_run_dir(cfg: ExperimentConfig, run_dir: Path | None = None) -> tuple[Path, str]:
    """The run folder of training ``cfg`` (its config and command saved) and what to do in
    it: ``new``, ``resume`` (a checkpoint and resume=true) or ``finished`` (model.zip is
    written last). A folder of another training is refused, naming what differs; an
    unfinished one without resume=true too."""
    run_dir = run_dir or run_dir_for(cfg)
    ckpt = run_dir / "checkpoints"
    recover_checkpoint(run_dir)  # a kill in the middle of writing one
    # The config it trains under (for policy=default the stock traffic, not the composed
    # behaviour preset).
    save_run_metadata(run_dir, OmegaConf.structured(cfg), ignore=NOT_LEARNT)
    if (run_dir / "model.zip").exists():
        return run_dir, "finished"  # also with resume=true, which bgap.run always passes
    if (ckpt / "state.pkl").exists():
        if not cfg.resume:
            raise ConfigError(
                f"{run_dir} holds an unfinished training: resume=true continues it (or "
                "choose another run_dir)"
            )
        return run_dir, "resume"
    return run_dir, "new"


def train(cfg: ExperimentConfig, progress: bool = True, callbacks: Sequence = ()) -> Path:
    """Train ``cfg.policy`` (resuming if ``cfg.resume``); returns the run folder.

    ``callbacks``: extra SB3 callbacks (the sweeps' pruning evaluations)."""
    if cfg.learner == "batched":
        return train_batched([cfg], progress)[0]
    cfg = training_config(cfg)
    run_dir, status = open_run_dir(cfg)
    if status == "finished":
        return run_dir
    ckpt = run_dir / "checkpoints"
    resuming = status == "resume"
    torch.set_num_threads(1)  # small MLP: threads cost more than they give; keeps runs exact
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
        state = pickle.loads((ckpt / "state.pkl").read_bytes())
        venv = _vector_highway(env)
        exact = venv is not None and state["env"] is not None
        model = DQN.load(
            ckpt / "model.zip",
            env=env,
            device="cpu",
            tensorboard_log=str(run_dir / "tb"),
            force_reset=not exact,
        )
        model.load_replay_buffer(ckpt / "replay.pkl")
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
                    tb_log_name="dqn",
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
    callback.checkpoint()
    model.save(run_dir / "model.zip")
    plot_learning_curves(run_dir)
    return run_dir


# ---------------------------------------------------------------------- batched learner
class _DummyEnv(gym.Env):
    """Spaces only: SB3 needs an environment to build the model a member is saved as."""

    def __init__(self, observation_space: gym.Space, action_space: gym.Space) -> None:
        self.observation_space, self.action_space = observation_space, action_space


class _MemberPolicy:
    """Member k of a batched learner seen as a model (``predict``, ``save``, ``_n_updates``)
    by :class:`~bgap.agents.monitor.TrainingMonitor`'s periodic evaluations."""

    def __init__(self, learner: BatchedDQN, k: int, save: Callable[[int, Path], None]) -> None:
        self.learner, self.k, self._save = learner, k, save

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


def member_configs(cfg: ExperimentConfig) -> list[ExperimentConfig]:
    """The trainings ``bgap.train`` makes: every seed of ``seeds`` (or ``seed``) for every
    policy of ``policies`` (or ``policy``)."""
    return [
        training_config(replace(cfg, seed=seed, policy=policy))
        for policy in (cfg.policies or [cfg.policy])
        for seed in (cfg.seeds or [cfg.seed])
    ]


def train_batched(
    cfgs: Sequence[ExperimentConfig], progress: bool = True, sb3_streams: bool = False
) -> list[Path]:
    """Train every config of ``cfgs`` (members: same agent, profile and backend; any policy
    family, seed and traffic) in one :class:`~bgap.agents.batched.BatchedDQN`; each member
    gets the run folder :func:`train` writes (config, command, ``tb/``, ``evaluations.csv``,
    checkpoints, an SB3-loadable ``model.zip``). Finished members are reused, unfinished
    ones resumed (``resume=true``) from their own checkpoints; returns the run folders.
    ``sb3_streams``: one member drawing from SB3's random streams
    (:class:`~bgap.agents.batched.BatchedDQN`), to compare a whole training with SB3's."""
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
    dirs = [run_dir_for(c) for c in cfgs]
    if first.run_dir and (len(cfgs) > 1 or first.seeds or first.policies):
        # one folder per member under run_dir, named as the pipeline names its runs (the
        # settings are in each folder's config.yaml, which refuses another training); also
        # for a single member asked for by seeds=/policies=, so the layout does not depend
        # on how many there are
        dirs = [Path(first.run_dir) / f"{c.env.name}-{c.policy}-s{c.seed}" for c in cfgs]
    if len(set(dirs)) < len(dirs):
        raise ConfigError(f"two members share a run folder: {[str(d) for d in dirs]}")
    opened = [open_run_dir(c, d) for c, d in zip(cfgs, dirs, strict=True)]
    todo = [i for i, (_, status) in enumerate(opened) if status != "finished"]
    if not todo:
        return dirs
    resuming = [opened[i][1] == "resume" for i in todo]
    for i, res in zip(todo, resuming, strict=True):
        if res and not (dirs[i] / "checkpoints" / "learner.pt").exists():
            raise ConfigError(
                f"{dirs[i]} holds a checkpoint of the sb3 learner: resume it with learner=sb3"
            )
    _train_members([cfgs[i] for i in todo], [dirs[i] for i in todo], resuming, progress,
                   sb3_streams)  # fmt: skip
    return dirs  # every member's, the finished ones' too


def _train_members(
    cfgs: list[ExperimentConfig],
    dirs: list[Path],
    resuming: list[bool],
    progress: bool,
    sb3_streams: bool = False,
) -> None:
    p, first = cfgs[0].profile, cfgs[0]
    e = p.n_envs
    if first.threads:
        torch.set_num_threads(first.threads)
    # members sharing a traffic config share one vector environment (per-env seeds and
    # random streams keep each member's episodes those of its own training)
    configs = [env_config(c, c.mix_sampling) for c in cfgs]
    keys = [json.dumps(c, sort_keys=True, default=str) for c in configs]
    groups: list[_Group] = []
    for key in dict.fromkeys(keys):
        members = [k for k, other in enumerate(keys) if other == key]
        venv = make_vector_env(
            configs[members[0]], len(members) * e, first.backend,
            asynchronous=first.backend == "highway",
        )  # fmt: skip
        groups.append(_Group(venv, members, e))
    space = groups[0].venv.single_observation_space
    for g in groups:
        if g.venv.single_observation_space.shape != space.shape:
            raise ConfigError(
                "members of one batched learner need the same observation shape: "
                f"{g.venv.single_observation_space.shape} vs {space.shape} (env settings)"
            )
    obs_dim, n_actions = int(np.prod(space.shape)), int(groups[0].venv.single_action_space.n)
    schedule = Schedule(
        e, p.train_steps, p.exploration_decay_steps or first.agent.exploration_decay_steps
    )
    seeds = [c.seed for c in cfgs]
    learner = BatchedDQN(first.agent, schedule, seeds, obs_dim, n_actions, sb3_streams=sb3_streams)
    if sb3_streams:
        np.random.seed(first.seed)  # noqa: NPY002 (SB3's set_random_seed)
    writers = [SummaryWriter(str(d / "tb" / "batched_1")) for d in dirs]
    monitors = []
    for k, (c, d) in enumerate(zip(cfgs, dirs, strict=True)):

        def log(key: str, value: float, k: int = k) -> None:
            writers[k].add_scalar(key, value, int(learner.num_timesteps[k]))

        monitors.append(
            TrainingMonitor(
                d, e, env_config(c), c.backend, max_episodes=p.train_episodes,
                eval_every=p.eval_every_episodes, eval_episodes=p.eval_during_training,
                eval_seed=c.val_seed, log=log,
            )
        )  # fmt: skip
    states = [
        pickle.loads((d / "checkpoints" / "state.pkl").read_bytes()) if res else None
        for d, res in zip(dirs, resuming, strict=True)
    ]
    obs = np.zeros((len(cfgs), e, *space.shape), dtype=np.float32)
    for g in groups:
        seeds = []
        for k in g.members:
            start = cfgs[k].seed
            if states[k] is not None and states[k]["env"] is None:  # highway-env: fresh seeds
                start = cfgs[k].seed + 1_000_003 * (1 + states[k]["monitor"]["episodes"])
            seeds += [start + j for j in range(e)]
        first_obs, _ = g.venv.reset(seed=seeds)
        for pos, k in enumerate(g.members):
            obs[k] = first_obs[g.envs_of(pos)]
            if states[k] is not None:
                learner.load_member_state(k, torch.load(
                    dirs[k] / "checkpoints" / "learner.pt", weights_only=False
                ))  # fmt: skip
                monitors[k].restore(states[k])
                if states[k]["env"] is not None:
                    g.venv.load_state_dict(states[k]["env"], envs=g.envs_of(pos))
                    obs[k] = g.venv.observations()[g.envs_of(pos)]
    template = build_model(
        first,
        DummyVecEnv([lambda: _DummyEnv(space, groups[0].venv.single_action_space)] * e),
        dirs[0] / "tb",
    )

    def save_model(k: int, path: Path) -> None:
        template.policy.q_net.load_state_dict(learner.member_network(k))
        template.policy.q_net_target.load_state_dict(learner.member_network(k, target=True))
        template.num_timesteps = int(learner.num_timesteps[k])
        template._n_updates = int(learner.n_updates[k])
        template._n_calls = int(learner.n_calls[k])
        template.exploration_rate = float(learner.exploration_rate[k])
        template.seed = cfgs[k].seed
        template.save(path)

    def checkpoint(k: int) -> None:
        g, pos = where[k]
        monitors[k].state["steps"] = int(learner.num_timesteps[k])
        env_state = g.venv.state_dict(envs=g.envs_of(pos)) if first.backend == "vector" else None
        monitors[k].checkpoint(
            {
                "model.zip": lambda path: save_model(k, path),
                "learner.pt": lambda path: torch.save(learner.member_state(k), path),
            },
            {"env": env_state, "learner": "batched"},
        )
        last_ckpt[k] = learner.num_timesteps[k]
        writers[k].flush()

    def finish(k: int) -> None:
        checkpoint(k)
        save_model(k, dirs[k] / "model.zip")
        writers[k].close()
        plot_learning_curves(dirs[k])
        active[k] = False

    where = {k: (g, pos) for g in groups for pos, k in enumerate(g.members)}
    active = learner.num_timesteps < p.train_steps
    last_ckpt = learner.num_timesteps.copy()
    interrupted = _Interrupt()
    bar = tqdm(total=int(p.train_steps * len(cfgs)), initial=int(learner.num_timesteps.sum()),
               disable=not progress, unit="step", desc=f"{len(cfgs)} trainings")  # fmt: skip
    try:
        with interrupted:
            for k in np.flatnonzero(~active):  # resumed at its budget: only the end is left
                finish(k)
            while active.any():
                members = np.flatnonzero(active)
                if interrupted.requested:
                    for k in members:
                        checkpoint(k)
                    raise KeyboardInterrupt
                for k in members[learner.num_timesteps[members] - last_ckpt[members]
                                 >= p.checkpoint_every]:  # fmt: skip
                    checkpoint(k)
                actions = learner.act(obs, members)
                new_obs = np.empty_like(obs)
                next_obs = np.empty_like(obs)
                rewards = np.zeros((len(cfgs), e), dtype=np.float32)
                terminated = np.zeros((len(cfgs), e), dtype=bool)
                truncated = np.zeros((len(cfgs), e), dtype=bool)
                infos: list[dict[str, Any]] = [{} for _ in cfgs]
                for g in groups:
                    o, r, term, trunc, info = g.venv.step(actions[g.members].reshape(-1))
                    final = final_observations(o, term | trunc, info)
                    for pos, k in enumerate(g.members):
                        envs = g.envs_of(pos)
                        new_obs[k], next_obs[k], rewards[k] = o[envs], final[envs], r[envs]
                        terminated[k], truncated[k] = term[envs], trunc[envs]
                        infos[k] = _member_info(info, envs)
                learner.num_timesteps[members] += e
                bar.update(e * len(members))
                keep = []
                for k in members:
                    monitors[k].state["steps"] = int(learner.num_timesteps[k])
                    go_on = monitors[k].on_step(
                        rewards[k], infos[k], terminated[k] | truncated[k],
                        _MemberPolicy(learner, k, save_model),
                    )  # fmt: skip
                    if go_on:
                        keep.append(k)
                    else:  # the episode budget: SB3 stops before storing this transition
                        finish(k)
                keep_ = np.asarray(keep, dtype=np.int64)
                if len(keep_):
                    step = (obs, next_obs, actions, rewards, terminated, truncated)
                    learner.observe(keep_, *(a[keep_] for a in step))
                obs = new_obs
                learner.train(keep_)
                for k in keep_:
                    if learner.num_timesteps[k] % 1000 < e:
                        writers[k].add_scalar("train/loss", learner.last_loss[k],
                                              int(learner.num_timesteps[k]))  # fmt: skip
                        writers[k].add_scalar("rollout/exploration_rate",
                                              learner.exploration_rate[k],
                                              int(learner.num_timesteps[k]))  # fmt: skip
                    if learner.num_timesteps[k] >= p.train_steps:
                        finish(k)
    except KeyboardInterrupt:
        steps = ", ".join(f"{d.name}: {int(n)}" for d, n in zip(dirs, last_ckpt, strict=True))
        raise Interrupted(
            f"batched training stopped; checkpoints at steps {steps}; continue with the same "
            "command and resume=true"
        ) from None
    finally:
        bar.close()
        for g in groups:
            g.venv.close()


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


class _Interrupt:
    """The first Ctrl-C asks for checkpoints at the next whole step; a second one stops at
    once (as :class:`~bgap.agents.monitor.SB3Monitor`)."""

    def __enter__(self) -> _Interrupt:
        self.requested, self._previous = False, None
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handle)
        return self

    def _handle(self, signum: int, frame: Any) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True

    def __exit__(self, *exc: Any) -> None:
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)


@app("train", "bgap.train", SCHEMAS)
def main(dcfg: DictConfig) -> None:
    cfg: ExperimentConfig = load(dcfg)
    cfgs = member_configs(cfg)
    if cfg.learner == "batched":
        dirs = train_batched(cfgs)
    else:
        dirs = [train(c) for c in cfgs]
    for run_dir in dirs:
        print(f"model: {run_dir / 'model.zip'}")


if __name__ == "__main__":
    main()
