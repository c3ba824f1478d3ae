"""The one seam between the simulators and everything that drives them.

:func:`make_vector_env` returns a gymnasium ``VectorEnv`` for either backend: highway-env
(the reference; its environments in gymnasium's ``SyncVectorEnv``) or bgap's vectorised
port (:class:`~bgap.sim.vector.VectorHighway`, natively batched). Both follow the same
conventions, so no caller branches on the backend:

- same-step auto-reset; the ``info`` of an env that finished in a step describes that step
  (the finished episode's last observation is in ``info["final_obs"]``);
- ``info`` holds arrays of ``ego_speed``, ``crashed``, ``lane_change``, ``lane`` and the
  reward terms (``info["rewards"]``);
- with ``record=True``: ``info["frames"]`` after a step, the simulation frames of that step
  (``(B, frames per step, n + 1, 7)``, fields :data:`RECORD_FIELDS`), and after a reset
  ``info["reset_frames"]`` (``(B, 1, n + 1, 7)``) and ``info["labels"]`` (``(B, n + 1)``
  class codes of :data:`bgap.common.vocab.LABEL_CODES`), masked by ``info["_reset_frames"]`` for
  envs reset inside a step.
"""

from __future__ import annotations

from functools import partial
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AsyncVectorEnv, AutoresetMode, SyncVectorEnv

from bgap.common.errors import ConfigError, check
from bgap.common.vocab import BACKENDS, LABEL_CODES
from bgap.sim.mixture import MixtureHighway
from bgap.sim.recorder import RECORD_FIELDS
from bgap.sim.vector import VectorHighway
from bgap.traffic.mixture import MixtureConfig

__all__ = ["RECORD_FIELDS", "make_vec_highway", "make_vector_env"]


def make_vector_env(
    config: dict[str, Any],
    num_envs: int,
    backend: str = "vector",
    *,
    record: bool = False,
    render: bool = False,
    asynchronous: bool = False,
) -> gym.vector.VectorEnv:
    """``num_envs`` copies of the behaviour-rich highway on ``backend``.

    Args:
        config: the environment's config dictionary (:func:`bgap.traffic.scenario.env_config`).
        record: report every simulation frame in ``info`` (trajectory recording).
        render: also put highway-env's pictures of every third frame in
            ``info["images"]`` (highway-env only: the vector backend draws nothing).
        asynchronous: highway-env's copies in subprocesses (gymnasium's ``AsyncVectorEnv``),
            one per core, instead of one after the other in this process. The vector backend
            is batched and threaded already and ignores it.
    """
    check(backend in BACKENDS, "backend", backend, f"use one of {BACKENDS}")
    traffic = config.get("traffic") or {}
    if traffic.get("source") == "mixture":  # the generalisation study's training traffic
        if backend != "vector" or record or render:
            raise ConfigError(
                "traffic=mixture runs on backend=vector only, without recording or rendering; "
                "record or watch its sources one at a time (traffic=simulated, traffic=replay)"
            )
        mixture = MixtureConfig(**traffic["mixture"])
        env = MixtureHighway(config, num_envs, mixture, traffic["min_duration"])
        lanes = int(config.get("lanes_count", 4))
        for member in env.members:
            check(  # the scripted egos (the checkpoint rule's references) read one road
                member.lanes == lanes,
                "traffic.mixture.tables",
                member.traffic.get("table"),
                f"has {member.lanes} lanes where the road has {lanes} (env.lanes_count): the "
                "hand-built egos read every environment as that road; give tables of its lanes",
            )
        return env
    if backend == "vector":
        if render:
            raise ConfigError(
                "render=true needs backend=highway (the vector backend draws nothing)"
            )
        return VectorHighway(config, num_envs, record=record)
    make = partial(_highway_env, config, record=record, render=render)
    vector = AsyncVectorEnv if asynchronous else SyncVectorEnv
    return SameStepInfo(vector([make] * num_envs, autoreset_mode=AutoresetMode.SAME_STEP))


def make_vec_highway(
    num_envs: int = 1,
    config: dict[str, Any] | None = None,
    render_mode: str | None = None,
    record: bool = False,
) -> VectorHighway:
    """The vector entry point of ``bgap/BehaviorHighway-v0``: what
    ``gym.make_vec("bgap/BehaviorHighway-v0", num_envs=N, config={...})`` returns.

    ``config`` is the single environment's (``gym.make(..., config=...)``): merged into
    :func:`bgap.traffic.scenario.default_config` and checked alike, an unknown key refused
    with the same :class:`~bgap.common.errors.ConfigError`. The vector backend draws nothing:
    for pictures, ``gym.make`` or ``gym.make_vec(..., vectorization_mode="sync")``
    (highway-env's copies).
    """
    if render_mode is not None:
        raise ConfigError(
            f"render_mode={render_mode!r}: the vector backend draws nothing; use "
            "gym.make(...) or gym.make_vec(..., vectorization_mode='sync') (highway-env)"
        )
    return VectorHighway(config or {}, num_envs, record=record)


def _highway_env(config: dict[str, Any], record: bool, render: bool) -> gym.Env:
    # Imported here: highway-env (and pygame) load only where highway-env's own backend is used.
    from bgap.envs import make_highway

    env = make_highway(config, render_mode="rgb_array" if render else None)
    return FrameRecorder(env, film=render) if record or render else env


class FrameRecorder(gym.Wrapper):
    """Puts the frames a highway-env episode simulates into ``info`` (the layout of
    :class:`~bgap.sim.vector.VectorHighway`'s recording), and with ``film=True`` a picture of
    every third frame (a 5 Hz animation of the 15 Hz simulation)."""

    def __init__(self, env: gym.Env, film: bool = False) -> None:
        super().__init__(env)
        self._frames: list[np.ndarray] = []
        self._images: list[np.ndarray] = []
        self._film = film
        env.unwrapped.frame_listeners.append(self._listen)

    def _listen(self, env: Any) -> None:
        self._frames.append(
            np.array(
                [
                    (*v.position, *v.velocity, v.speed, v.lane_index[2], v.crashed)
                    for v in env.road.vehicles
                ],
                dtype=float,
            )
        )
        if self._film and env.frame % 3 == 0:
            self._images.append(env.render())

    def reset(self, **kwargs: Any) -> tuple[Any, dict]:
        self._frames, self._images = [], []
        obs, info = self.env.reset(**kwargs)
        info["reset_frames"] = np.stack(self._frames)
        vehicles = self.env.unwrapped.road.vehicles
        info["labels"] = np.array([LABEL_CODES[v.bgap_label] for v in vehicles])
        if self._film:
            info["images"] = self._images
        return obs, info

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        self._frames, self._images = [], []
        obs, reward, terminated, truncated, info = self.env.step(action)
        info["frames"] = np.stack(self._frames)
        if self._film:
            info["images"] = self._images
        return obs, reward, terminated, truncated, info


class SameStepInfo(gym.vector.VectorWrapper):
    """gymnasium's same-step auto-reset returns, for an env that finished, the info of its
    reset and puts the finished step's info in ``info["final_info"]``; bgap's consumers read
    the step's info for every env (the vectorised backend's convention), so this merges
    ``final_info`` into ``info`` for the envs that finished. Reset-only keys
    (``reset_frames``, ``labels``) keep their masks."""

    def step(self, actions: Any) -> tuple[Any, Any, Any, Any, dict]:
        obs, rewards, terminated, truncated, info = self.env.step(actions)
        final = info.pop("final_info", None)
        info.pop("_final_info", None)
        if final is not None:
            _merge(info, final, terminated | truncated)
        if "reset_frames" in info:
            info["_reset_frames"] = terminated | truncated
        return obs, rewards, terminated, truncated, info


def _merge(info: dict, final: dict, done: np.ndarray) -> None:
    """``info[key][done] = final[key][done]`` for every key of ``final``, recursively."""
    for key, value in final.items():
        if key.startswith("_"):
            continue
        if isinstance(value, dict):
            _merge(info.setdefault(key, {}), value, done)
            continue
        if key not in info:
            info[key] = value
            continue
        merged = np.array(info[key], copy=True)
        if merged.dtype != value.dtype:
            merged = merged.astype(np.result_type(merged.dtype, value.dtype))
        merged[done] = value[done]
        info[key] = merged
