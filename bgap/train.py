"""Training a navigation policy: ``python -m bgap.train policy=behavior_rich env=sparse``.

One run folder holds everything (rl-baselines3-zoo style): ``model.zip``, ``config.yaml``
(resolved), ``command.txt``, ``tb/`` (TensorBoard: episode reward, collision rate, average
speed, lane changes, epsilon, loss, periodic evaluations), ``checkpoints/`` (the latest
model, replay buffer and counters, every ``profile.checkpoint_every`` steps and on Ctrl-C)
and ``evaluations.csv``. ``resume=true`` continues from the checkpoint.

``policy=behavior_rich`` trains in the enriched traffic (mix per ``mix_sampling``);
``policy=default`` trains in highway-env's stock traffic, the paper's "default policy".
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Sequence
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import gymnasium as gym
import hydra
import numpy as np
import pandas as pd
from omegaconf import DictConfig, OmegaConf
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

from bgap.agents.dqn import DQN
from bgap.agents.per import PrioritizedReplayBuffer
from bgap.behaviors import mix_stream, sample_mix
from bgap.config import (
    CONF_DIR,
    BehaviorConfig,
    ExperimentConfig,
    env_config,
    load,
    register_configs,
)
from bgap.envs import ENV_ID
from bgap.runs import save_run_metadata


def training_config(cfg: ExperimentConfig, policy: str | None = None) -> ExperimentConfig:
    """The config a policy trains under: ``default`` swaps in stock traffic."""
    policy = policy or cfg.policy
    cfg = replace(cfg, policy=policy)
    if policy == "default":
        cfg = replace(cfg, behavior=BehaviorConfig(name="stock"), mix_sampling="fixed")
    return cfg


def run_name(cfg: ExperimentConfig) -> str:
    """Readable prefix plus a hash of everything that changes what is learnt."""
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
    digest = hashlib.sha1(json.dumps(keys, sort_keys=True).encode()).hexdigest()[:8]
    mix = f"mix{cfg.mix:g}" if cfg.mix_sampling == "fixed" else f"mix-{cfg.mix_sampling}"
    mix = mix if cfg.policy == "behavior_rich" else "stock"
    return f"{cfg.env.name}-{cfg.policy}-{mix}-{cfg.profile.name}-s{cfg.seed}-{digest}"


def run_dir_for(cfg: ExperimentConfig) -> Path:
    return Path(cfg.run_dir) if cfg.run_dir else Path(cfg.root) / "runs" / run_name(cfg)


class MixSampler(gym.Wrapper):
    """Draws the aggressive fraction anew at every reset (the paper trains across mixes)."""

    def __init__(self, env: gym.Env, mode: str) -> None:
        super().__init__(env)
        self.mode = mode
        self._rng = np.random.default_rng(0)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self._rng = mix_stream(seed)
        rng = self._rng
        mix = sample_mix(rng, self.mode)
        self.env.unwrapped.config["mix"] = float(mix)
        return self.env.reset(seed=seed, options=options)


def make_training_env(cfg: ExperimentConfig, n_envs: int, seed: int):
    """``n_envs`` training environments as an SB3 VecEnv: subprocesses of highway-env, or
    one batched :class:`~bgap.sim.vector.VectorHighway` for ``backend=vector``."""
    config = env_config(cfg)
    if cfg.backend == "vector":
        from stable_baselines3.common.vec_env import VecMonitor

        from bgap.sim.sb3 import SB3VecEnv
        from bgap.sim.vector import VectorHighway

        venv = SB3VecEnv(VectorHighway(config, n_envs, mix_sampling=cfg.mix_sampling))
        venv.seed(seed)
        return VecMonitor(venv)
    wrapper = (lambda e: MixSampler(e, cfg.mix_sampling)) if cfg.mix_sampling != "fixed" else None
    vec_cls = SubprocVecEnv if n_envs > 1 else DummyVecEnv
    kwargs = {"start_method": "fork"} if n_envs > 1 else {}
    return make_vec_env(
        ENV_ID,
        n_envs=n_envs,
        seed=seed,
        env_kwargs={"config": config},
        wrapper_class=wrapper,
        vec_env_cls=vec_cls,
        vec_env_kwargs=kwargs,
    )


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


class Progress(BaseCallback):
    """Episode statistics to TensorBoard, the episode budget, periodic greedy evaluations
    and checkpoints (model, replay buffer, counters)."""

    def __init__(self, cfg: ExperimentConfig, run_dir: Path, state: dict[str, Any]) -> None:
        super().__init__()
        self.cfg, self.run_dir, self.state = cfg, run_dir, state
        self.history: list[dict] = []

    def _on_training_start(self) -> None:
        n = self.training_env.num_envs
        self._speed = [[] for _ in range(n)]
        self._lanes = [0] * n
        self._last_ckpt = self.num_timesteps

    def _on_step(self) -> bool:
        infos, dones = self.locals["infos"], self.locals["dones"]
        for i, (info, done) in enumerate(zip(infos, dones, strict=True)):
            self._speed[i].append(info["ego_speed"])
            self._lanes[i] += int(info["lane_change"])
            if done:
                self._episode_end(i, info)
        if self.num_timesteps - self._last_ckpt >= self.cfg.profile.checkpoint_every:
            self.checkpoint()
        budget = self.cfg.profile.train_episodes
        return budget is None or self.state["episodes"] < budget

    def _episode_end(self, i: int, info: dict) -> None:
        self.state["episodes"] += 1
        ep = {
            "crashed": float(info["crashed"]),
            "avg_speed": float(np.mean(self._speed[i])),
            "lane_changes": self._lanes[i],
            "reward": info.get("episode", {}).get("r", np.nan),
        }
        self.history = (self.history + [ep])[-20:]
        for key in ("crashed", "avg_speed", "lane_changes"):
            name = "collision_rate" if key == "crashed" else key
            self.logger.record(f"episode/{name}", float(np.mean([h[key] for h in self.history])))
        self.logger.record("episode/count", self.state["episodes"])
        self._speed[i], self._lanes[i] = [], 0
        every = self.cfg.profile.eval_every_episodes
        if every and self.state["episodes"] % every == 0:
            self.periodic_evaluation()

    def periodic_evaluation(self) -> None:
        from bgap.evaluate import greedy, play

        seeds = [self.cfg.eval_seed + k for k in range(self.cfg.profile.eval_during_training)]
        rows = play(env_config(self.cfg), greedy(self.model), seeds, self.cfg.backend)
        frame = pd.DataFrame(rows)
        record = {
            "episodes": self.state["episodes"],
            "steps": self.num_timesteps,
            "collision_pct": 100 * frame.crashed.mean(),
            "avg_speed": frame.avg_speed.mean(),
            "lane_changes": frame.lane_changes.mean(),
            "return": frame["return"].mean(),
        }
        for k in ("collision_pct", "avg_speed", "lane_changes", "return"):
            self.logger.record(f"eval/{k}", record[k])
        path = self.run_dir / "evaluations.csv"
        pd.DataFrame([record]).to_csv(path, mode="a", header=not path.exists(), index=False)

    def checkpoint(self) -> None:
        """Write the latest model, replay buffer and counters; atomic per file."""
        ckpt = self.run_dir / "checkpoints"
        ckpt.mkdir(parents=True, exist_ok=True)
        self.model.save(ckpt / "model.tmp.zip")
        os.replace(ckpt / "model.tmp.zip", ckpt / "model.zip")
        self.model.save_replay_buffer(ckpt / "replay.tmp.pkl")
        os.replace(ckpt / "replay.tmp.pkl", ckpt / "replay.pkl")
        self.state["steps"] = int(self.model.num_timesteps)
        (ckpt / "state.json").write_text(json.dumps(self.state))
        self._last_ckpt = self.num_timesteps


def train(cfg: ExperimentConfig, progress: bool = True, callbacks: Sequence = ()) -> Path:
    """Train ``cfg.policy`` (resuming if ``cfg.resume``); returns the run folder.

    ``callbacks``: extra SB3 callbacks (the sweeps' pruning evaluations)."""
    import torch

    cfg = training_config(cfg)
    run_dir = run_dir_for(cfg)
    ckpt = run_dir / "checkpoints"
    resuming = cfg.resume and (ckpt / "state.json").exists()
    if (run_dir / "model.zip").exists() and not resuming:
        return run_dir  # finished already
    # The config it trains under: for policy=default that is the stock traffic, not the
    # composed behaviour preset.
    save_run_metadata(run_dir, OmegaConf.structured(cfg))
    torch.set_num_threads(1)  # small MLP: threads cost more than they give; keeps runs exact
    env = make_training_env(cfg, cfg.profile.n_envs, cfg.seed)
    state = {"episodes": 0, "steps": 0}
    if resuming:
        state = json.loads((ckpt / "state.json").read_text())
        model = DQN.load(
            ckpt / "model.zip", env=env, device="cpu", tensorboard_log=str(run_dir / "tb")
        )
        model.load_replay_buffer(ckpt / "replay.pkl")
    else:
        model = build_model(cfg, env, run_dir / "tb")
    callback = Progress(cfg, run_dir, state)
    remaining = cfg.profile.train_steps - model.num_timesteps
    try:
        if remaining > 0:
            model.learn(
                total_timesteps=remaining,
                callback=[callback, *callbacks],
                progress_bar=progress,
                reset_num_timesteps=not resuming,
                tb_log_name="dqn",
            )
    except KeyboardInterrupt:
        callback.checkpoint()
        print(
            f"\ninterrupted at step {model.num_timesteps}: checkpoint saved; rerun with "
            f"resume=true run_dir={run_dir} to continue"
        )
        raise
    finally:
        env.close()
    callback.checkpoint()
    model.save(run_dir / "model.zip")
    return run_dir


register_configs()


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="train")
def main(dcfg: DictConfig) -> None:
    cfg: ExperimentConfig = load(dcfg)
    run_dir = train(cfg)
    print(f"model: {run_dir / 'model.zip'}")


if __name__ == "__main__":
    main()
