"""``VectorHighway``: B behaviour-rich highways advanced together (``backend=vector``).

The same traffic model as :class:`bgap.envs.highway.BehaviorHighwayEnv` (highway-env is the
reference), kept in arrays and stepped by the numba kernels of :mod:`bgap.sim.core`. It
takes the same config dictionary (:func:`bgap.traffic.scenario.env_config`), follows the
gymnasium vector-env API with same-step auto-reset, and loads highway-env scenes
(:func:`bgap.sim.highway_scenes.scene_from_highway`) so that the two can be compared from
identical starts.

Known differences from highway-env (README "Vectorised backend"):
- initial scenes are drawn from the same distributions with a different random stream, so a
  seed gives a different (equally likely) scene than highway-env's for the same seed;
- ``info`` describes the step just taken, also for an env that was reset in that step (its
  final observation is in ``info["final_obs"]``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numba
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode

from bgap.common.errors import ConfigError, check, check_memory
from bgap.common.vocab import FINISHED
from bgap.sim import core
from bgap.sim.core import (
    CRASHED,
    EGO,
    LABEL,
    LANE,
    N_FLOAT,
    N_INT,
    N_PARAM,
    SPEED,
    TARGET_LANE,
    TARGET_SPEED,
    X,
    Y,
)
from bgap.sim.highway_params import check_supported, class_table
from bgap.sim.passing import overtakes
from bgap.sim.recorder import RECORD_FIELDS, initial_states
from bgap.traffic.behaviors import (
    BehaviorVehicle,
    count_aggressive,
    episode_mix,
    mix_stream,
)
from bgap.traffic.replay import load_replay
from bgap.traffic.scenario import REWARD_TERMS, contact_dx, full_config

# The ctypes interface of numpy's PCG64, whose C functions every PCG64 stream shares: the
# compiled scene draw calls them on each env's stream (core.spawn).
_PCG64_KEPT = np.random.PCG64()  # alive, though only its functions are used
_PCG64 = _PCG64_KEPT.ctypes


@dataclass
class Scene:
    """One environment's state in the kernel layout (ego first), for loading and saving."""

    f: np.ndarray  # (n + 1, N_FLOAT)
    g: np.ndarray  # (n + 1, N_INT)
    p: np.ndarray  # (n + 1, N_PARAM)
    steps: int = 0


def env_seeds(seed: int | Sequence[int | None] | None, n: int) -> list[int | None] | None:
    """The seeds of ``n`` environments reset with ``seed``: ``seed + k`` for env k (or
    ``seed[k]``, one per env); None leaves every env's streams running."""
    if seed is None:
        return None
    seeds = list(seed) if isinstance(seed, Sequence) else [seed + k for k in range(n)]
    if len(seeds) != n:
        raise ValueError(f"got {len(seeds)} seeds for {n} envs")
    return seeds


class VectorHighway(gym.vector.VectorEnv):
    """``num_envs`` behaviour-rich highways in lock step.

    Args:
        config: the environment's config dictionary (:func:`bgap.traffic.scenario.env_config`);
            missing keys take :func:`bgap.traffic.scenario.default_config`'s values. Its
            ``mix_sampling`` (``fixed``, ``uniform`` or ``paper``) draws a mix per env at
            every reset from the env's own stream.
        num_envs: B.
        record: report every simulation frame in ``info`` (:mod:`bgap.sim.simulators` gives
            the layout): ``frames`` after a step, ``reset_frames`` and ``labels`` after a
            reset.
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}
    skips_finished = True
    """An action ``FINISHED`` leaves its env as it is: no frames, no automatic reset (its
    returned row is stale). Evaluation sends it once an env's counted episode is over."""

    def __init__(
        self,
        config: dict[str, Any],
        num_envs: int,
        record: bool = False,
    ) -> None:
        self.config = full_config(config)
        check_supported(self.config)
        cfg = self.config
        self.num_envs = int(num_envs)
        check(self.num_envs >= 1, "num_envs", num_envs, "must be >= 1")
        self.traffic = cfg.get("traffic") or {}
        self.replay = None
        if self.traffic.get("source") == "replay":  # the road takes the table's lanes
            if record:
                raise ConfigError(
                    "recording replayed traffic is not supported; replay it "
                    "without recording (the table is the recording)"
                )
            self.replay = load_replay(
                self.traffic["table"],
                cfg["simulation_frequency"],
                self.traffic["min_duration"],
                self.traffic.get("scenes", "all"),
            )
            cfg["lanes_count"] = self.replay.lanes
            self._longest = int(round(float(cfg["duration"]) * cfg["simulation_frequency"]))
            cfg["vehicles_count"] = self.replay.most_vehicles(self._longest)
        self.lanes = int(cfg["lanes_count"])
        self.n = int(cfg["vehicles_count"])
        self.record = record
        self.n_aggressive = np.full(num_envs, count_aggressive(float(cfg["mix"]), self.n))
        self.radius = float(cfg["perception_radius"])
        self.rows = int(cfg["observation"]["vehicles_count"])
        self.frames_per_step = int(cfg["simulation_frequency"]) // int(cfg["policy_frequency"])
        self.dt = 1.0 / float(cfg["simulation_frequency"])
        self.max_steps = int(np.ceil(float(cfg["duration"]) * int(cfg["policy_frequency"]) - 1e-9))
        self.speeds = np.asarray(cfg["action"].get("target_speeds", [20, 25, 30]), dtype=float)
        n_veh, b = self.n + 1, self.num_envs
        check_memory(
            self._bytes_needed(),
            "env.vehicles_count",
            self.n,
            "fewer vehicles" + (f", or fewer environments than {b}" if b > 1 else ""),
        )
        self.f = np.zeros((b, n_veh, N_FLOAT))
        self.g = np.zeros((b, n_veh, N_INT), dtype=np.int64)
        self.p = np.zeros((b, n_veh, N_PARAM))
        self.steps = np.zeros(b, dtype=np.int64)
        shape = (b, self.frames_per_step, n_veh, len(RECORD_FIELDS)) if record else (1, 1, 1, 1)
        self.frames = np.zeros(shape)
        self._obs = np.zeros((b, self.rows, 5), dtype=np.float32)
        self._counts = np.zeros((b, 2), dtype=np.int64)
        self._terms = np.zeros((b, 5))
        self._rngs = [np.random.default_rng() for _ in range(b)]
        self._mix_rngs = [np.random.default_rng() for _ in range(b)]
        spread = float(np.exp(-5 / 40 * self.lanes))  # Vehicle.create_random's spacing factor
        ego_offset = float(cfg["ego_spacing"]) * (12 + 25.0) * spread
        self._setup = np.array([self.lanes, ego_offset, 1 / float(cfg["vehicles_density"]), spread])
        lane_id = cfg.get("initial_lane_id")
        self._ego_lane = -1 if lane_id is None else int(lane_id)
        self._classes = class_table(cfg["behavior"])
        self.single_observation_space = spaces.Box(-1.0, 1.0, (self.rows, 5), np.float32)
        self.single_action_space = spaces.Discrete(5)
        self.observation_space = spaces.Box(-1.0, 1.0, (b, self.rows, 5), np.float32)
        self.action_space = spaces.MultiDiscrete(np.full(b, 5))
        # Weights in the order of core.ego_terms' first four columns.
        self._w = np.array([float(cfg[k]) for k in REWARD_TERMS])
        # highway-env normalises x by 5 MAX_SPEED and v by 2 MAX_SPEED of the base Vehicle.
        self._x_range, self._v_range = 5.0 * core.EGO_MAX_SPEED, 2.0 * core.EGO_MAX_SPEED
        # replay (core.replay_frame): per vehicle (track, state, own v0), per env its scene
        # frame and the policy steps its window holds
        self._rp = np.zeros((b, n_veh, 3), dtype=np.int64)
        self._rframe = np.zeros(b, dtype=np.int64)
        self._window_steps = np.full(b, self.max_steps, dtype=np.int64)
        self._others = np.full(b, self.n, dtype=np.int64)  # background vehicles per env
        if self.replay is not None:
            self._tracks, *self._track_index, self._track_of = self.replay.tracks()

    def _bytes_needed(self) -> float:
        """The state arrays of every environment, their recorded frames, and the pair list
        (n (n - 1) / 2 indices) that each kernel thread holds while it checks collisions."""
        n_veh, b = self.n + 1, self.num_envs
        state = b * n_veh * (N_FLOAT + N_INT + N_PARAM + 3) * 8
        frames = b * self.frames_per_step * n_veh * len(RECORD_FIELDS) * 8 if self.record else 0
        pairs = min(b, numba.get_num_threads()) * n_veh * (n_veh - 1) / 2 * 8
        return state + frames + pairs

    # ------------------------------------------------------------------ scenes
    def _spawn(self, envs: np.ndarray) -> None:
        """highway-env's HighwayEnv._create_vehicles with bgap's classes, for each env in
        ``envs``: each env's mix from its mix stream here, its scene drawn by the compiled
        :func:`bgap.sim.core.spawn_batch` from its own stream."""
        envs = np.asarray(envs, dtype=np.int64)
        if self.replay is not None:
            for b in envs:
                self._spawn_replay(int(b))
            self.steps[envs] = 0
            return
        for b in envs:
            self.n_aggressive[b] = count_aggressive(
                episode_mix(self.config, self._mix_rngs[b]), self.n
            )
        self._spawn_scenes(envs, self._classes)
        self.steps[envs] = 0

    def _spawn_scenes(self, envs: np.ndarray, classes: np.ndarray) -> None:
        """The compiled scene draw (:func:`bgap.sim.core.spawn_batch`) for ``envs``, each
        from its own stream, with the class table ``classes`` (:func:`class_table`) and each
        env's ``n_aggressive``."""
        states = np.empty(envs.size, dtype=np.uint64)
        for a, b in enumerate(envs):
            bit_generator = self._rngs[b].bit_generator
            if not isinstance(bit_generator, np.random.PCG64):  # the kernel's draws are PCG64's
                raise TypeError(f"env {b}'s stream is {type(bit_generator).__name__}, not PCG64")
            states[a] = bit_generator.ctypes.state_address
        core.spawn_batch(
            self.f,
            self.g,
            self.p,
            envs,
            self.n_aggressive[envs],
            self._ego_lane,
            self._setup,
            self.speeds,
            classes,
            _PCG64.next_double,
            _PCG64.next_uint32,
            states,
        )

    def _spawn_replay(self, b: int) -> None:
        """bgap.envs.highway's _create_replay for env b, drawn from its stream as
        highway-env draws: the window, then per replayed vehicle in road order its IDM delta
        (unless its class sets one) and desired-speed spread (if its class sets v0). (After
        an automatic reset the streams part: highway-env draws a vehicle's parameters when
        it enters, this backend at the reset, for every vehicle the window may bring.)"""
        t, rng = self.traffic, self._rngs[b]
        w = self.replay.window(rng, self._longest, t["vehicle"], t["start"], t["scene"])
        self._window_steps[b] = w.frames // self.frames_per_step
        f, g, p, rp = self.f, self.g, self.p, self._rp
        f[b], g[b], p[b], rp[b] = 0.0, 0, 0.0, 0
        x, y, vx, vy = w.scene.state[w.start, w.ego]
        f[b, 0, X], f[b, 0, Y] = x, y
        f[b, 0, core.HEADING], f[b, 0, SPEED] = math.atan2(vy, vx), math.hypot(vx, vy)
        g[b, 0, LANE] = g[b, 0, TARGET_LANE] = core.closest_lane(y, self.lanes)
        idx = core.speed_to_index(f[b, 0, SPEED], self.speeds)
        g[b, 0, core.SPEED_INDEX], f[b, 0, TARGET_SPEED] = idx, self.speeds[idx]
        g[b, 0, LABEL] = EGO
        p[b, 0] = self._classes[0, 3:]
        end = w.start + self._window_steps[b] * self.frames_per_step
        scene = w.scene
        others = [
            v
            for v in range(len(scene.ids))
            if v != w.ego and scene.span(v)[1] >= w.start and scene.span(v)[0] <= end
        ]
        others.sort(key=lambda v: (max(scene.span(v)[0], w.start), v))  # road order
        _, start, first, _ = (None, *self._track_index)
        for slot, v in enumerate(others, start=1):
            label = scene.labels[v]
            c = 2 if label == "aggressive" else 1  # a label not of a class: conservative
            row = self._classes[c]
            p[b, slot] = row[3:]
            p[b, slot, core.P_OWN] = 1.0  # a ReplayVehicle is a BehaviorVehicle
            p[b, slot, core.P_VMAX] = BehaviorVehicle.MAX_SPEED
            if math.isnan(row[3 + core.P_DELTA]):
                p[b, slot, core.P_DELTA] = rng.uniform(3.5, 4.5)
            if not math.isnan(row[1]):
                rp[b, slot, core.R_OWN_V0] = 1
                f[b, slot, TARGET_SPEED] = row[1] * rng.uniform(1 - row[2], 1 + row[2])
            g[b, slot, LABEL] = int(row[0])
            track = self._track_of[(w.index, v)]
            rp[b, slot, core.R_TRACK] = track
            if first[track] <= w.start:
                rp[b, slot, core.R_STATE] = core.R_LOG
                core._replayed_state(
                    f, g, b, slot, self._tracks, start[track] + w.start - first[track], self.lanes
                )
                g[b, slot, TARGET_LANE] = g[b, slot, LANE]
                if not rp[b, slot, core.R_OWN_V0]:
                    f[b, slot, TARGET_SPEED] = f[b, slot, SPEED]
            else:
                rp[b, slot, core.R_STATE] = core.R_PENDING
                core._park(f, b, slot)
        for slot in range(len(others) + 1, self.n + 1):
            rp[b, slot, core.R_TRACK] = -1
            rp[b, slot, core.R_STATE] = core.R_PARKED
            core._park(f, b, slot)
        self._rframe[b] = w.start
        self.n_aggressive[b] = sum(scene.labels[v] == "aggressive" for v in others)
        self._others[b] = len(others)

    def load_scene(self, b: int, scene: Scene) -> None:
        """Put ``scene`` (e.g. from :func:`~bgap.sim.highway_scenes.scene_from_highway`)
        into env b."""
        if scene.f.shape[0] != self.n + 1:
            raise ValueError(f"scene has {scene.f.shape[0] - 1} vehicles, this env {self.n}")
        self.f[b], self.g[b], self.p[b] = scene.f, scene.g, scene.p
        self.steps[b] = scene.steps

    def scene(self, b: int) -> Scene:
        return Scene(self.f[b].copy(), self.g[b].copy(), self.p[b].copy(), int(self.steps[b]))

    def state_dict(self, envs: Sequence[int] | None = None) -> dict[str, Any]:
        """Everything the next steps depend on (every env's state and random streams), to
        resume a training exactly (:meth:`load_state_dict`); ``envs``: those envs only (one
        member's share of a batched learner's environments)."""
        idx = list(range(self.num_envs)) if envs is None else list(envs)
        return {
            "arrays": {
                k: getattr(self, k)[idx].copy()
                for k in ("f", "g", "p", "steps", "n_aggressive")
                + (("_rp", "_rframe", "_window_steps") if self.replay is not None else ())
            },
            "rngs": [self._rngs[b].bit_generator.state for b in idx],
            "mix_rngs": [self._mix_rngs[b].bit_generator.state for b in idx],
        }

    def load_state_dict(self, state: dict[str, Any], envs: Sequence[int] | None = None) -> None:
        """A :meth:`state_dict` put back, into every env or into ``envs``."""
        idx = list(range(self.num_envs)) if envs is None else list(envs)
        for key, value in state["arrays"].items():
            target = getattr(self, key)[idx]
            if target.shape != value.shape:
                raise ValueError(f"saved {key} has shape {value.shape}, this env {target.shape}")
            getattr(self, key)[idx] = value
        for rngs, saved in ((self._rngs, state["rngs"]), (self._mix_rngs, state["mix_rngs"])):
            for b, bit_state in zip(idx, saved, strict=True):
                rngs[b] = np.random.default_rng()
                rngs[b].bit_generator.state = bit_state
        self._observe()

    # ------------------------------------------------------------------ gymnasium API
    def reset(
        self, *, seed: int | Sequence[int | None] | None = None, options: dict | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset every env; env k takes seed ``seed + k`` (or ``seed[k]``)."""
        seeds = env_seeds(seed, self.num_envs)
        if seeds is not None:
            self._rngs = [np.random.default_rng(s) for s in seeds]
            self._mix_rngs = [mix_stream(s) for s in seeds]
        self._spawn(np.arange(self.num_envs))
        obs = self._observe()
        zero = np.zeros(self.num_envs, dtype=bool)
        info = self._info(zero)
        if self.record:
            info["reset_frames"] = initial_states(self.f, self.g, self.num_envs, self.n)
            info["labels"] = self.g[:, :, LABEL].copy()
        return obs.copy(), info

    def observations(self) -> np.ndarray:
        """Every env's current observation (after :meth:`load_state_dict`, where no reset or
        step returned one)."""
        return self._observe().copy()

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
        actions = np.asarray(actions, dtype=np.int64).reshape(self.num_envs)
        before = self.g[:, 0, TARGET_LANE].copy()
        x_before = self.f[:, :, X].copy()
        if self.replay is not None:
            start, first, length = self._track_index
            core.replay_batch(
                self.f,
                self.g,
                self.p,
                actions,
                self.speeds,
                self.frames_per_step,
                self.dt,
                self.lanes,
                self._rp,
                self._rframe,
                self._tracks,
                start,
                first,
                length,
                self.traffic["mode"] == "reactive",
            )
        else:
            core.step_batch(
                self.f,
                self.g,
                self.p,
                actions,
                self.speeds,
                self.frames_per_step,
                self.dt,
                self.lanes,
                self.frames,
            )
        self.steps += 1
        obs = self._observe()
        rewards, terms = self._rewards(before)
        terminated = terms["collision_reward"] > 0
        truncated = self.steps >= np.minimum(self.max_steps, self._window_steps)
        info = self._info(terms["lane_change_reward"] > 0)
        info["overtakes"] = overtakes(x_before, self.f[:, :, X])
        if self.replay is not None:  # the ego's crash partner still followed its log
            logs = (self._rp[:, :, core.R_STATE] >= core.R_LOG) & (self.g[:, :, CRASHED] > 0)
            info["log_contact"] = (self.g[:, 0, CRASHED] > 0) & logs[:, 1:].any(axis=1)
        info["rewards"] = terms
        if self.record:
            info["frames"] = self.frames.copy()
        done = (terminated | truncated) & (actions != FINISHED)  # finished envs stay as they are
        if done.any():
            info["final_obs"] = np.empty(self.num_envs, dtype=object)
            info["_final_obs"] = done.copy()
            for b in np.flatnonzero(done):
                info["final_obs"][b] = obs[b].copy()
            self._spawn(np.flatnonzero(done))
            obs = self._observe()
            if self.record:
                info["reset_frames"] = initial_states(self.f, self.g, self.num_envs, self.n)
                info["labels"] = self.g[:, :, LABEL].copy()
                info["_reset_frames"] = done.copy()
        return obs.copy(), rewards, terminated, truncated, info

    def close(self, **kwargs: Any) -> None:  # nothing to release
        pass

    # ------------------------------------------------------------------ observation, reward
    def _observe(self) -> np.ndarray:
        core.observe_batch(
            self.f,
            self.g,
            self.radius,
            self.lanes,
            self._x_range,
            self._v_range,
            self._obs,
            self._counts,
        )
        return self._obs

    def _rewards(self, before: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """HighwayEnv._rewards and BehaviorHighwayEnv._reward, for every env (``before``: the
        ego's target lane before the step)."""
        lo, hi = self.config["reward_speed_range"]
        t = self._terms
        core.ego_terms(self.f, self.g, before, self.lanes, float(lo), float(hi), t)
        terms = {
            "collision_reward": t[:, 0].copy(),
            "lane_change_reward": t[:, 1].copy(),
            "right_lane_reward": t[:, 2].copy(),
            "high_speed_reward": t[:, 3].copy(),
            "on_road_reward": t[:, 4].copy(),
        }
        w = self._w
        reward = t[:, :4] @ w
        if self.config["normalize_reward"]:
            low, high = np.minimum(w, 0).sum(), np.maximum(w, 0).sum()
            if high > low:
                reward = (reward - low) / (high - low)
        return reward * t[:, 4], terms

    def _contact_dx(self) -> np.ndarray:
        """:func:`bgap.traffic.scenario.contact_dx` of every env (0 where the ego has not
        crashed)."""
        out = np.zeros(self.num_envs)
        for b in np.flatnonzero(self.g[:, 0, CRASHED]):
            out[b] = contact_dx(self.f[b, :, X], self.f[b, :, Y], self.g[b, :, CRASHED] > 0)
        return out

    def _info(self, lane_change: np.ndarray) -> dict[str, Any]:
        """Per-env info arrays; the observation counts come from the last :meth:`_observe`."""
        seen, seen_aggressive = self._counts[:, 0].copy(), self._counts[:, 1]
        speed = self.f[:, 0, SPEED].copy()
        return {
            "speed": speed,
            "ego_speed": speed,
            "crashed": self.g[:, 0, CRASHED].astype(bool),
            "lane_change": lane_change.copy(),
            "lane": self.g[:, 0, LANE].copy(),
            "contact_dx": self._contact_dx(),
            "aggressive_fraction": self.n_aggressive / np.maximum(self._others, 1),
            "aggressive_fraction_observed": seen_aggressive / np.maximum(seen, 1),
            "observed_count": seen,
        }
