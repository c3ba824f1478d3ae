"""Stable-Baselines3 adapter: a bgap vector environment as an SB3 ``VecEnv``.

Takes any vector environment that follows the conventions of :mod:`bgap.sim.simulators`
(:class:`~bgap.sim.vector.VectorHighway`, or highway-env through ``make_vector_env``): info
as a dict of arrays, same-step auto-reset with ``info["final_obs"]``. SB3 expects a list of
per-env ``info`` dicts, the last observation in ``info["terminal_observation"]``, and
``TimeLimit.truncated`` on time-outs; this is all the adapter adds. Wrap it in
``VecMonitor`` for SB3's episode statistics.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

# The per-env info keys bgap's training and evaluation read.
INFO_KEYS = (
    "ego_speed",
    "crashed",
    "lane_change",
    "lane",
    "contact_dx",
    "aggressive_fraction",
    "aggressive_fraction_observed",
    "observed_count",
)


class SB3VecEnv(VecEnv):
    def __init__(self, venv: gym.vector.VectorEnv) -> None:
        self.venv = venv
        self.render_mode = None
        super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)
        self._actions: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        seeds = None if any(s is None for s in self._seeds) else list(self._seeds)
        obs, _ = self.venv.reset(seed=seeds)
        self._reset_seeds()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self):
        obs, rewards, terminated, truncated, info = self.venv.step(self._actions)
        dones = terminated | truncated
        columns = {k: np.asarray(info[k]).tolist() for k in INFO_KEYS}
        infos: list[dict[str, Any]] = [
            {k: columns[k][b] for k in INFO_KEYS} for b in range(self.num_envs)
        ]
        for b in np.flatnonzero(dones):
            infos[b]["terminal_observation"] = info["final_obs"][b]
            infos[b]["TimeLimit.truncated"] = bool(truncated[b] and not terminated[b])
        return obs, rewards.astype(np.float32), dones, infos

    def close(self) -> None:
        self.venv.close()

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        if attr_name == "render_mode":
            return [None] * self.num_envs
        return [getattr(self.venv, attr_name)] * len(self._get_indices(indices))

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        raise AttributeError("the vectorised highway has no per-env attributes to set")

    def env_method(self, method_name: str, *args, indices=None, **kwargs) -> list[Any]:
        raise AttributeError(f"the vectorised highway has no per-env method {method_name!r}")

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False] * len(self._get_indices(indices))
