"""Training a navigation policy: ``python -m bgap.train policy=behavior_rich env=sparse``.

One run folder holds everything (rl-baselines3-zoo style): ``model.zip``, ``config.yaml``
(resolved), ``command.txt``, ``tb/`` (TensorBoard: episode reward, collision rate, average
speed, lane changes, epsilon, loss, periodic evaluations), ``checkpoints/`` (the latest
model, replay buffer, counters and, on the vector backend, the environments' and random
streams' state, every ``profile.checkpoint_every`` steps and on Ctrl-C) and
``evaluations.csv``. ``resume=true`` continues from the checkpoint: exactly as if never
interrupted on the vector backend; on highway-env (whose environments are not saved) the
environments restart on fresh seeds.

``policy=behavior_rich`` trains in the enriched traffic (mix per ``mix_sampling``);
``policy=default`` trains in highway-env's stock traffic, the paper's "default policy".
"""

from __future__ import annotations

import pickle
import warnings
from collections.abc import Sequence
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from stable_baselines3.common.vec_env import VecMonitor
from tqdm import TqdmExperimentalWarning

from bgap.agents.dqn import DQN
from bgap.agents.monitor import (
    SB3Monitor,
    TrainingMonitor,
    plot_learning_curves,
    recover_checkpoint,
)
from bgap.agents.per import PrioritizedReplayBuffer
from bgap.behaviors import BehaviorConfig
from bgap.config import ExperimentConfig, app, load
from bgap.errors import ConfigError, Interrupted
from bgap.runs import VOLATILE, digest, save_run_metadata
from bgap.scenario import env_config
from bgap.sim.sb3 import SB3VecEnv
from bgap.sim.vector import VectorHighway
from bgap.simulators import make_vector_env

NOT_LEARNT = (
    *VOLATILE, "models", "baselines", "grid", "eval_seed", "val_seed", "out", "seeds"
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
    keys["profile"] = {
        k: v for k, v in asdict(cfg.profile).items() if k not in ("eval_episodes", "name")
    }
    return keys


def run_name(cfg: ExperimentConfig) -> str:
    """Readable prefix plus a hash of everything that changes what is learnt."""
    mix = f"mix{cfg.mix:g}" if cfg.mix_sampling == "fixed" else f"mix-{cfg.mix_sampling}"
    mix = mix if cfg.policy == "behavior_rich" else "stock"
    name = f"{cfg.env.name}-{cfg.policy}-{mix}-{cfg.profile.name}-s{cfg.seed}"
    return f"{name}-{digest(training_identity(cfg))}"


def run_dir_for(cfg: ExperimentConfig) -> Path:
    return Path(cfg.run_dir) if cfg.run_dir else Path(cfg.root) / "runs" / run_name(cfg)


def make_training_env(cfg: ExperimentConfig, n_envs: int, seed: int) -> VecMonitor:
    """``n_envs`` training environments (:func:`bgap.simulators.make_vector_env`: one batched
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


def train(cfg: ExperimentConfig, progress: bool = True, callbacks: Sequence = ()) -> Path:
    """Train ``cfg.policy`` (resuming if ``cfg.resume``); returns the run folder.

    ``callbacks``: extra SB3 callbacks (the sweeps' pruning evaluations)."""
    cfg = training_config(cfg)
    run_dir = run_dir_for(cfg)
    ckpt = run_dir / "checkpoints"
    recover_checkpoint(run_dir)  # a kill in the middle of writing one
    resuming = cfg.resume and (ckpt / "state.pkl").exists()
    # The config it trains under (for policy=default the stock traffic, not the composed
    # behaviour preset); a folder of another training is refused, naming what differs.
    save_run_metadata(run_dir, OmegaConf.structured(cfg), ignore=NOT_LEARNT)
    if (run_dir / "model.zip").exists():
        # finished already, with these settings (model.zip is written last); also with
        # resume=true, which bgap.run always passes
        return run_dir
    if (ckpt / "state.pkl").exists() and not cfg.resume:
        raise ConfigError(
            f"{run_dir} holds an unfinished training: resume=true continues it (or choose "
            "another run_dir)"
        )
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


@app("train", "bgap.train")
def main(dcfg: DictConfig) -> None:
    cfg: ExperimentConfig = load(dcfg)
    run_dir = train(cfg)
    print(f"model: {run_dir / 'model.zip'}")


if __name__ == "__main__":
    main()
