"""Gymnasium environments of bgap (registered by ``import bgap``) and their constructors."""

from __future__ import annotations

from typing import Any

import gymnasium as gym

from bgap import ENV_ID
from bgap.traffic.scenario import Scenario, env_config

__all__ = ["ENV_ID", "make_env", "make_highway"]


def make_highway(config: dict[str, Any], render_mode: str | None = None) -> gym.Env:
    """The behaviour-rich highway (highway-env) from its config dictionary."""
    # Off-screen drawing needs no display (highway-env disables drawing under SDL's dummy driver).
    config = {**config, "offscreen_rendering": render_mode == "rgb_array"}
    return gym.make(ENV_ID, config=config, render_mode=render_mode)


def make_env(cfg: Scenario, render_mode: str | None = None, mix_sampling: str = "fixed") -> gym.Env:
    """The behaviour-rich highway from a bgap config (any with env, reward, behavior, mix
    and radius)."""
    return make_highway(env_config(cfg, mix_sampling), render_mode)
