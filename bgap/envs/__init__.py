"""Gymnasium environments of bgap. Importing this module registers them."""

from __future__ import annotations

from typing import Any

import gymnasium as gym

ENV_ID = "bgap/BehaviorHighway-v0"

if ENV_ID not in gym.registry:
    gym.register(id=ENV_ID, entry_point="bgap.envs.highway:BehaviorHighwayEnv")


def make_env(cfg: Any, render_mode: str | None = None) -> gym.Env:
    """Build the behaviour-rich highway from a bgap config (dataclass or composed DictConfig)."""
    from bgap.config import env_config

    config = env_config(cfg)
    # Off-screen drawing needs no display (highway-env disables drawing under SDL's dummy driver).
    config["offscreen_rendering"] = render_mode == "rgb_array"
    return gym.make(ENV_ID, config=config, render_mode=render_mode)
