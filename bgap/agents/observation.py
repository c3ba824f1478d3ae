"""Observation options of a learner: columns added to the paper's observation.

    agent.observation=[closing,ttc]      # or the presets: observation=ttc | rule | ttc_rule

The paper's observation (presence, x, y, vx, vy of V vehicles, the ego's row first, the
others relative to it, normalised as highway-env's ``KinematicObservation``) stays what both
simulators produce; a learner that asks for more columns gets them computed from it, after
``vy`` (so the paper's five keep their meaning and index):

- ``closing``: per observed vehicle, the speed [m/s] at which its longitudinal gap to the ego
  shrinks, ``-sign(dx) (vx_j - vx_ego)`` (> 0: closing in, ahead or behind), normalised by
  highway-env's velocity range (80 m/s) and clipped to [-1, 1] like ``vx``;
- ``ttc``: its time to collision, the bumper-to-bumper gap ``|dx| - length`` over the closing
  speed when it closes in and the two overlap laterally (``|dy| < width``), capped at
  :data:`TTC_HORIZON` and divided by it (1: no collision course within the horizon, 0: in
  contact). One column, continuous where the closing speed crosses zero;
- ``rule``: the rule-based ego's suggested meta-action (:mod:`bgap.agents.rule_based`), five
  one-hot columns in the ego's row. The policy is still learnt: it may ignore the suggestion.

The ego's row has ``closing`` 0 and ``ttc`` 1; absent rows stay all zero (highway-env's
padding). Because every column is a function of the paper's observation, the two backends
agree on them whenever they agree on the observation (their parity tests), and one
evaluation can play models with different options on the same episodes. A model records its
options in its file (:data:`MODEL_ATTRIBUTE`); :func:`bgap.agents.policies.as_policy` adds
the columns before each of its predictions. Our definitions: highway-env has no
per-vehicle closing speed or time to collision (its ``TimeToCollision`` observation is a
lane x speed grid for another network shape, not offered here).

Why written here: the columns derive from the normalised observation both backends already
share; computing them on the simulators' states would need a port in each backend.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from bgap.agents.config import OBSERVATION_OPTIONS, observation_options
from bgap.agents.rule_based import V_RANGE, X_RANGE, RuleBasedEgo, rule_based
from bgap.traffic.road import LANE_WIDTH, N_ACTIONS, VEHICLE_LENGTH, VEHICLE_WIDTH

TTC_HORIZON = 10.0
"""[s] Times to collision at or beyond it read 1 (highway-env's TimeToCollision horizon)."""
MODEL_ATTRIBUTE = "observation_features"
"""The attribute a trained model saves its options under (SB3 saves a model's attributes)."""


class ObservationFeatures:
    """The columns ``features`` add to batches of the paper's observation ``(B, V, 5)``, in an
    environment of ``config`` (its lanes scale ``y``; the rule-based ego reads its speeds)."""

    def __init__(self, features: Sequence[str], config: dict[str, Any] | None = None) -> None:
        self.features = observation_options(list(features))
        self.config = config or {}
        self.lanes = int(self.config.get("lanes_count", 4))
        self._rules: dict[int, RuleBasedEgo] = {}

    def rule(self, lanes: int) -> RuleBasedEgo:
        """The rule-based ego on a road of ``lanes`` lanes (the config's speeds)."""
        if lanes not in self._rules:
            self._rules[lanes] = rule_based({**self.config, "lanes_count": lanes})
        return self._rules[lanes]

    @property
    def columns(self) -> int:
        """How many columns the options add."""
        return sum(OBSERVATION_OPTIONS[f] for f in self.features)

    def __bool__(self) -> bool:
        return bool(self.features)

    def __call__(self, obs: np.ndarray, lanes: Any = None) -> np.ndarray:
        """``obs`` (B, V, 5) or (V, 5) with the added columns, float32. ``lanes``: each
        row's road (B,) or one for all, where environments differ (the mixture's replayed
        tables); default the config's."""
        obs = np.asarray(obs, dtype=np.float32)
        if not self.features:
            return obs
        single = obs.ndim == 2
        batch = obs[None] if single else obs
        lanes = np.broadcast_to(np.asarray(self.lanes if lanes is None else lanes), len(batch))
        parts = [batch]
        present = batch[:, :, 0] > 0.5
        others = present.copy()
        others[:, 0] = False
        if "closing" in self.features or "ttc" in self.features:
            o = batch.astype(np.float64)
            y_range = LANE_WIDTH * lanes[:, None]
            dx, dy, dvx = o[:, :, 1] * X_RANGE, o[:, :, 2] * y_range, o[:, :, 3] * V_RANGE
            closing = np.where(others, -np.sign(dx) * dvx, 0.0)
            if "closing" in self.features:
                parts.append(np.clip(closing / V_RANGE, -1.0, 1.0)[..., None])
            if "ttc" in self.features:
                gap = np.abs(dx) - VEHICLE_LENGTH
                course = others & (np.abs(dy) < VEHICLE_WIDTH)
                with np.errstate(divide="ignore", invalid="ignore"):
                    ttc = np.where(gap <= 0.0, 0.0, gap / closing)
                ttc = np.where(course & ((closing > 0.0) | (gap <= 0.0)), ttc, TTC_HORIZON)
                ttc = np.minimum(ttc, TTC_HORIZON) / TTC_HORIZON
                parts.append(np.where(present, ttc, 0.0)[..., None])
        if "rule" in self.features:
            actions = np.empty(len(batch), dtype=np.int64)
            for road in np.unique(lanes):
                rows = lanes == road
                actions[rows] = self.rule(int(road))(batch[rows])
            onehot = np.zeros((*batch.shape[:2], N_ACTIONS))
            onehot[np.arange(len(batch)), 0, actions] = 1.0
            parts.append(onehot)
        out = np.concatenate([p.astype(np.float32) for p in parts], axis=-1)
        return out[0] if single else out

    def space(self, base: spaces.Box) -> spaces.Box:
        """The observation space with the added columns (``base``: the paper's ``(V, 5)``)."""
        rows, cols = base.shape
        return spaces.Box(-1.0, 1.0, (rows, cols + self.columns), np.float32)


def model_features(model: Any) -> list[str]:
    """The observation options a trained model was trained with ([]: the paper's)."""
    return list(getattr(model, MODEL_ATTRIBUTE, None) or [])


class WithFeatures(gym.vector.VectorWrapper):
    """A vector environment of either backend whose observations (those of ``reset``,
    ``step``, ``observations()`` and ``info["final_obs"]``) carry ``features``' columns.
    The vector backend's ``state_dict``/``load_state_dict`` pass through (exact resumes)."""

    def __init__(self, env: gym.vector.VectorEnv, features: ObservationFeatures) -> None:
        super().__init__(env)
        self.features = features
        self.lanes = getattr(env, "env_lanes", None)
        """Each environment's lanes where they differ (:class:`bgap.sim.mixture.MixtureHighway`)."""
        self.single_observation_space = features.space(env.single_observation_space)
        self.observation_space = gym.vector.utils.batch_space(
            self.single_observation_space, env.num_envs
        )

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict]:
        obs, info = self.env.reset(**kwargs)
        return self.features(obs, self.lanes), info

    def step(self, actions: Any) -> tuple[Any, Any, Any, Any, dict]:
        obs, rewards, terminated, truncated, info = self.env.step(actions)
        if "final_obs" in info:
            final = info["final_obs"].copy()
            for b in np.flatnonzero(info.get("_final_obs", terminated | truncated)):
                final[b] = self.features(final[b], None if self.lanes is None else self.lanes[b])
            info["final_obs"] = final
        return self.features(obs, self.lanes), rewards, terminated, truncated, info

    def observations(self) -> np.ndarray:
        return self.features(self.env.observations(), self.lanes)

    def state_dict(self, *args: Any, **kwargs: Any) -> dict[str, Any]:
        return self.env.state_dict(*args, **kwargs)

    def load_state_dict(self, *args: Any, **kwargs: Any) -> None:
        self.env.load_state_dict(*args, **kwargs)


def with_features(
    env: gym.vector.VectorEnv, features: Sequence[str], config: dict[str, Any]
) -> gym.vector.VectorEnv:
    """``env`` unchanged when ``features`` is empty (the paper's observation), else wrapped."""
    return WithFeatures(env, ObservationFeatures(features, config)) if features else env
