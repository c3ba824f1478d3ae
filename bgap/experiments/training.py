"""What every training shares, whichever learner runs it: the config as trained, its
identity (what changes what is learnt) and run folder, and the SB3 model it is saved as."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any, TypeVar

import torch
from omegaconf import OmegaConf

from bgap.agents.attention import EgoAttention
from bgap.agents.dqn import DQN
from bgap.agents.monitor import (
    choose_again,
    recover_checkpoint,
)
from bgap.agents.observation import MODEL_ATTRIBUTE
from bgap.agents.per import PrioritizedReplayBuffer, check_replay_memory
from bgap.common.errors import ConfigError
from bgap.common.runs import (
    CHECKPOINT_STATE,
    VOLATILE,
    digest,
    read_or_refuse,
    save_run_metadata,
)
from bgap.experiments.compat import ADDED_LATER, as_before, upgrade
from bgap.experiments.config import ExperimentConfig, first_validation_seed
from bgap.traffic.behaviors import BehaviorConfig

NOT_LEARNT = (
    *VOLATILE,
    "models",
    "baselines",
    "grid",
    "eval_seed",
    "val_seed",
    "out",
    "seeds",
    "policies",
    "threads",
    "checkpoint",
)
"""Settings of a training's config that do not change what it learns (run folder checks).
(``val_seed`` only moves the periodic evaluations' episodes; ``eval_seed`` the tests'.)"""


T = TypeVar("T")


def training_config(cfg: ExperimentConfig, policy: str | None = None) -> ExperimentConfig:
    """The config a policy trains under: ``default`` swaps in stock traffic; under the
    mixture (``traffic=mixture``), the mixture's stock source alone, at its vehicle counts:
    the stock-only learner that the mixture's is read against."""
    policy = policy or cfg.policy
    cfg = replace(cfg, policy=policy)
    if policy == "default":
        cfg = replace(cfg, behavior=BehaviorConfig(name="stock"), mix_sampling="fixed")
        if cfg.traffic.source == "mixture":
            stock = replace(cfg.traffic.mixture, sources={"stock": 1.0}, tables=[])
            cfg = replace(cfg, traffic=replace(cfg.traffic, mixture=stock))
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
    # settings added later, at the value every earlier training had, leave its name as it was
    keys = as_before(keys | {"traffic": asdict(cfg.traffic)})
    keys["mix"] = cfg.mix if cfg.policy == "behavior_rich" else None
    if cfg.learner != "sb3":  # (the SB3 runs' names predate this setting)
        keys["learner"] = cfg.learner
    keys["profile"] = {
        k: v
        for k, v in asdict(cfg.profile).items()
        if k not in ("eval_episodes", "name") and ADDED_LATER.get(f"profile.{k}", ...) != v
    }
    return keys


def validation_seed(cfg: ExperimentConfig) -> int:
    """The first seed of a training's periodic validations: the checkpoint rule's block."""
    return first_validation_seed(cfg.profile.checkpoint_rule, cfg.val_seed)


def run_name(cfg: ExperimentConfig) -> str:
    """Readable prefix plus a hash of everything that changes what is learnt."""
    mix = f"mix{cfg.mix:g}" if cfg.mix_sampling == "fixed" else f"mix-{cfg.mix_sampling}"
    mix = mix if cfg.policy == "behavior_rich" else "stock"
    density = cfg.env.name
    if cfg.traffic.source == "mixture":  # every density and share, drawn per episode
        density, mix = "mixture", "drawn"
    name = f"{density}-{cfg.policy}-{mix}-{cfg.profile.name}-s{cfg.seed}"
    name += f"-{cfg.learner}" if cfg.learner != "sb3" else ""
    return f"{name}-{digest(training_identity(cfg))}"


def run_dir_for(cfg: ExperimentConfig) -> Path:
    return Path(cfg.run_dir) if cfg.run_dir else Path(cfg.root) / "runs" / run_name(cfg)


def build_model(cfg: ExperimentConfig, env, tb_dir: Path) -> Any:
    """The SB3 model of ``cfg.agent.algo`` (:func:`model_class`), the agent's hyperparameters;
    it records the agent's observation options, saved in its file (``env`` observes them)."""
    model = _build_model(cfg, env, tb_dir)
    if cfg.agent.observation:
        setattr(model, MODEL_ATTRIBUTE, list(cfg.agent.observation))
    return model


def _build_model(cfg: ExperimentConfig, env, tb_dir: Path) -> Any:
    a = cfg.agent
    network = {"net_arch": list(a.net_arch)}
    if a.extractor == "attention":
        network |= {
            "features_extractor_class": EgoAttention,
            "features_extractor_kwargs": {"embed_dim": a.attention_dim, "heads": a.attention_heads},
        }
    common = dict(
        env=env,
        learning_rate=a.learning_rate,
        gamma=a.gamma,
        max_grad_norm=a.max_grad_norm,
        tensorboard_log=str(tb_dir),
        seed=cfg.seed,
        device="cpu",
        verbose=0,
    )
    if a.algo == "ppo":
        return model_class("ppo")(
            "MlpPolicy",
            n_steps=a.n_steps,
            batch_size=a.batch_size,
            n_epochs=a.n_epochs,
            gae_lambda=a.gae_lambda,
            clip_range=a.clip_range,
            ent_coef=a.ent_coef,
            vf_coef=a.vf_coef,
            policy_kwargs=network,
            **common,
        )
    per = a.replay == "per"
    check_replay_memory(a.buffer_size, math.prod(env.observation_space.shape))
    off_policy = dict(
        buffer_size=a.buffer_size,
        learning_starts=a.learning_starts,
        batch_size=a.batch_size,
        train_freq=a.train_freq,
        gradient_steps=a.gradient_steps,
        target_update_interval=a.target_update_interval,
        exploration_initial_eps=a.exploration_initial,
        exploration_final_eps=a.exploration_final,
        exploration_decay_steps=cfg.profile.exploration_decay_steps or a.exploration_decay_steps,
        replay_buffer_class=PrioritizedReplayBuffer if per else None,
        replay_buffer_kwargs={"alpha": a.per_alpha, "beta0": a.per_beta0} if per else None,
        per_beta_steps=cfg.profile.train_steps,
    )
    if a.algo == "qrdqn":
        # torch's Adam as DQN's (sb3-contrib would otherwise set its Atari epsilon)
        kwargs = {**network, "n_quantiles": a.n_quantiles, "optimizer_class": torch.optim.Adam}
        return model_class("qrdqn")("MlpPolicy", policy_kwargs=kwargs, **off_policy, **common)
    return DQN(
        "MlpPolicy",
        loss=a.loss,
        policy_kwargs=network,
        **off_policy,
        **common,
    )


def model_class(algo: str) -> type:
    """The class a training of ``algo`` builds, saves and resumes as."""
    if algo == "qrdqn":
        # Imported here: sb3-contrib loads only for the trainings that use it.
        from bgap.agents.qrdqn import QRDQN

        return QRDQN
    if algo == "ppo":
        from stable_baselines3 import PPO

        return PPO
    return DQN


def open_run_dir(cfg: ExperimentConfig, run_dir: Path | None = None) -> tuple[Path, str]:
    """The run folder of training ``cfg`` (its config and command saved) and what to do in
    it: ``new``, ``resume`` (a checkpoint and resume=true) or ``finished`` (model.zip is
    written last; its kept checkpoint chosen again under today's rule,
    :func:`~bgap.agents.monitor.choose_again`). A folder of another training is refused,
    naming what differs; an unfinished one without resume=true too."""
    run_dir = run_dir or run_dir_for(cfg)
    ckpt = run_dir / "checkpoints"
    recover_checkpoint(run_dir)  # a kill in the middle of writing one
    # The config it trains under (for policy=default the stock traffic, not the composed
    # behaviour preset).
    save_run_metadata(run_dir, OmegaConf.structured(cfg), ignore=NOT_LEARNT, upgrade=upgrade)
    if (run_dir / "model.zip").exists():
        choose_again(run_dir, cfg.profile.checkpoint_rule)  # under today's rule
        return run_dir, "finished"  # also with resume=true, which bgap.run always passes
    if (ckpt / CHECKPOINT_STATE).exists():
        if not cfg.resume:
            raise ConfigError(
                f"{run_dir} holds an unfinished training: resume=true continues it (or "
                "choose another run_dir)"
            )
        return run_dir, "resume"
    return run_dir, "new"


def member_configs(cfg: ExperimentConfig) -> list[ExperimentConfig]:
    """The trainings ``bgap.train`` makes: every seed of ``seeds`` (or ``seed``) for every
    policy of ``policies`` (or ``policy``)."""
    return [
        training_config(replace(cfg, seed=seed, policy=policy))
        for policy in (cfg.policies or [cfg.policy])
        for seed in (cfg.seeds or [cfg.seed])
    ]


def member_dirs(cfgs: list[ExperimentConfig]) -> list[Path]:
    """The run folders of :func:`member_configs`' trainings: each its own under ``root``;
    with ``run_dir`` and several trainings (or ``seeds=``/``policies=``), one folder per
    training under it, named as the pipeline names its runs (``<density>-<policy>-s<seed>``;
    the settings are in each folder's config.yaml, which refuses another training), so the
    layout does not depend on how many there are."""
    first = cfgs[0]
    if first.run_dir and (len(cfgs) > 1 or first.seeds or first.policies):
        return [Path(first.run_dir) / f"{c.env.name}-{c.policy}-s{c.seed}" for c in cfgs]
    return [run_dir_for(c) for c in cfgs]


def read_checkpoint(ckpt: Path, read: Callable[[], T]) -> T:
    """``read()`` of files in the checkpoint folder ``ckpt``; a damaged file is one line
    saying so and how to go on, not a traceback."""
    return read_or_refuse(
        read,
        f"{ckpt} holds a damaged checkpoint",
        "restore it, or delete that folder and train again without resume=true",
    )
