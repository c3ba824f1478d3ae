"""The generalisation study's training traffic on the vector backend: ``MixtureHighway``, one
gymnasium vector environment whose episodes draw their traffic from the mixture of
:mod:`bgap.traffic.mixture` (``docs/notes/2026-12-07-generalisation-plan.md``).

    env = MixtureHighway(config, num_envs=64, mixture=MixtureConfig(tables=[...]))
    obs, info = env.reset(seed=0)          # env k seeded seed + k, as VectorHighway
    env.sources()                          # each env's current episode's source

The vector backend holds one vehicle count per batch, and a replayed table brings its own
lanes and vehicles, so the environment is a row of member batches, each a
:class:`~bgap.sim.vector.VectorHighway`, stepped one after another:

- **simulated members**, one per vehicle count, sharing the simulated environments as
  :func:`~bgap.traffic.mixture.vehicle_groups` says. Each episode draws bgap's drivers (a
  behaviour preset, an aggressive share, a factor per vehicle on its IDM and MOBIL
  parameters) or highway-env's stock traffic, with the two sources' weights;
- **replayed members**, one per table, reactive, whose windows come from the table's
  training scenes only (:func:`bgap.traffic.scenes.split_scenes`).

So the replay source is drawn per environment, not per episode as the plan's table says: a
replayed environment cannot turn into a simulated one at a reset. Its weight is the share of
the environments (rounded, at least one per table while the weight is positive), and so,
near enough, of the training steps. Every member observes the same number of rows, so one
policy reads them all.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode

from bgap.common.errors import check
from bgap.common.presets import shipped
from bgap.sim import core
from bgap.sim.highway_params import class_table
from bgap.sim.vector import VectorHighway, env_seeds
from bgap.traffic.behaviors import BehaviorConfig, count_aggressive, env_behavior
from bgap.traffic.mixture import EpisodeTraffic, MixtureConfig, draw, vehicle_groups
from bgap.traffic.replay import SIDES
from bgap.traffic.scenes import split_scenes, table_name

VEHICLE_LENGTH = 5.0
"""highway-env's Vehicle.LENGTH: a DISTANCE_WANTED column holds the bumper gap plus it."""
SCALED = (core.P_T, core.P_A, core.P_B, core.P_POLITENESS, core.P_GAIN, core.P_BSAFE)
"""The IDM and MOBIL parameter columns a vehicle's factor multiplies, beside the bumper gap
(DELTA keeps highway-env's own per-vehicle draw; v0 keeps its class's spread)."""
_STREAM = 0x6D6978
"""Mixed into an env's seed for its own stream of traffic draws (:func:`draw_stream`)."""


def draw_stream(seed: int) -> np.random.Generator:
    """The stream of an env seeded ``seed`` that draws its episodes' traffic: its own, so the
    scene draws are the scene stream's whatever the mixture draws."""
    return np.random.default_rng([_STREAM, int(seed)])


def scale_parameters(p: np.ndarray, factors: np.ndarray) -> None:
    """Multiply each vehicle's (row's) IDM and MOBIL parameters by its factor, in place; the
    minimum gap is scaled bumper to bumper."""
    f = np.asarray(factors, dtype=float)[:, None]
    p[:, SCALED] *= f
    gap = p[:, core.P_D0] - VEHICLE_LENGTH
    p[:, core.P_D0] = gap * f[:, 0] + VEHICLE_LENGTH


class DrawnTraffic(VectorHighway):
    """A VectorHighway whose every episode draws its traffic from ``mixture``'s simulated
    sources (bgap's drivers, stock traffic) with their weights."""

    def __init__(self, config: dict[str, Any], num_envs: int, mixture: MixtureConfig) -> None:
        super().__init__(config, num_envs)
        simulated = {k: w for k, w in mixture.sources.items() if k != "replay" and w > 0}
        self.mixture = replace(mixture, sources=simulated)
        self._tables = {"stock": class_table(_behavior("stock"))}
        for name in self.mixture.classes:
            self._tables[name] = class_table(_behavior(name))
        self._draw_rngs = [np.random.default_rng() for _ in range(self.num_envs)]
        self.drawn: list[EpisodeTraffic | None] = [None] * self.num_envs
        """Each env's current episode's draw."""

    def reset(self, *, seed: Any = None, options: dict | None = None):
        seeds = env_seeds(seed, self.num_envs)
        if seeds is not None:
            self._draw_rngs = [draw_stream(s) for s in seeds]
        return super().reset(seed=seeds, options=options)

    def state_dict(self, envs: Sequence[int] | None = None) -> dict[str, Any]:
        """VectorHighway's state, with each env's traffic-draw stream and current draw."""
        idx = list(range(self.num_envs)) if envs is None else list(envs)
        state = super().state_dict(envs)
        state["draw_rngs"] = [self._draw_rngs[b].bit_generator.state for b in idx]
        state["drawn"] = [self.drawn[b] for b in idx]
        return state

    def load_state_dict(self, state: dict[str, Any], envs: Sequence[int] | None = None) -> None:
        idx = list(range(self.num_envs)) if envs is None else list(envs)
        super().load_state_dict(state, envs)
        for b, bit_state, drawn in zip(idx, state["draw_rngs"], state["drawn"], strict=True):
            self._draw_rngs[b] = np.random.default_rng()
            self._draw_rngs[b].bit_generator.state = bit_state
            self.drawn[b] = drawn

    def _spawn(self, envs: np.ndarray) -> None:
        """Each env's episode drawn, then the scenes spawned with the drawn classes and shares
        (stock traffic: no vehicle labelled aggressive), one compiled call per class table
        (one per env cost 7 ms each, a thread pool's start), then each vehicle's factor
        applied."""
        envs = np.asarray(envs, dtype=np.int64)
        tables: dict[str, list[int]] = {}
        for b in envs:
            episode = draw(self.mixture, self._draw_rngs[b], self.n)
            self.drawn[b] = episode
            stock = episode.source == "stock"
            self.n_aggressive[b] = 0 if stock else count_aggressive(episode.mix, self.n)
            tables.setdefault("stock" if stock else episode.behavior, []).append(int(b))
        for name, members in tables.items():
            self._spawn_scenes(np.array(members, dtype=np.int64), self._tables[name])
        self.steps[envs] = 0
        for b in envs:
            if self.drawn[b].scale:
                scale_parameters(self.p[b, 1:], np.asarray(self.drawn[b].scale))


def _behavior(name: str) -> dict[str, Any]:
    """The packaged behaviour preset ``name`` as the environment config's ``behavior``."""
    missing = f"mixture.classes: no behaviour preset {name!r}"
    return env_behavior(shipped(BehaviorConfig, "behavior", name, missing))


class SplitReplay(VectorHighway):
    """A VectorHighway replaying ``table``, its windows drawn from one side of the table's
    scenes (``traffic.scenes``, :func:`bgap.traffic.scenes.split_scenes`): ``train`` (the
    mixture's replay source) or ``test`` (the held-out scenes a generalisation test plays)."""

    def __init__(
        self,
        config: dict[str, Any],
        num_envs: int,
        table: str,
        min_duration: float,
        side: str = "train",
        mode: str = "reactive",
    ) -> None:
        split = SIDES[1:]  # a side of the split, not "all"
        check(side in split, "side", side, f"one of {split}")
        traffic = {"source": "replay", "table": str(table), "mode": mode, "scenes": side}
        traffic |= {"min_duration": min_duration, "vehicle": None, "start": None, "scene": None}
        super().__init__({**config, "traffic": traffic}, num_envs)
        numbers = [scene.number for scene in self.replay.scenes]
        self.training_scenes, self.test_scenes = split_scenes(table_name(table), numbers)


def member_sizes(mixture: MixtureConfig, num_envs: int) -> tuple[list[tuple[int, int]], list[int]]:
    """(vehicle count, environments) per simulated member and environments per replayed
    table: the replay weight's share of ``num_envs``, rounded, at least one per table while
    the weight is positive, the rest simulated."""
    total = sum(mixture.sources.values())
    replay_weight = mixture.sources.get("replay", 0.0) / total
    tables = list(mixture.tables)
    check(
        replay_weight == 0 or bool(tables),
        "mixture.tables",
        tables,
        "one replay table or more (the replay source has weight "
        f"{replay_weight:g}), or mixture.sources.replay=0",
    )
    simulated = replay_weight < 1
    least = len(mixture.vehicles) * simulated + len(tables) * (replay_weight > 0)
    check(
        num_envs >= least,
        "n_envs",
        num_envs,
        f"at least {least} environments for the mixture: one per vehicle count "
        f"({len(mixture.vehicles) * simulated}) and per replay table "
        f"({len(tables) * (replay_weight > 0)}) (profile.n_envs)",
    )
    replayed = 0
    if replay_weight > 0:
        replayed = max(len(tables), int(round(replay_weight * num_envs)))
        replayed = min(replayed, num_envs - len(mixture.vehicles) * simulated)
    shares = [replayed // len(tables) + (i < replayed % len(tables)) for i in range(len(tables))]
    groups = vehicle_groups(mixture, num_envs - replayed) if replay_weight < 1 else []
    return groups, shares if replayed else [0] * len(tables)


class MixtureHighway(gym.vector.VectorEnv):
    """``num_envs`` highways whose traffic is drawn from ``mixture`` (module docstring).

    Args:
        config: the environment's config dictionary (:func:`bgap.traffic.scenario.env_config`);
            its vehicle count and traffic are the mixture's, the rest (observation rows,
            radius, reward, speeds) every member's.
        num_envs: environments in all.
        mixture: the weights and ranges, and the replay tables (``mixture.tables``).
        min_duration: a replayed window's shortest length [s].
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(
        self,
        config: dict[str, Any],
        num_envs: int,
        mixture: MixtureConfig,
        min_duration: float = 20.0,
    ) -> None:
        groups, shares = member_sizes(mixture, int(num_envs))
        base = {k: v for k, v in config.items() if k != "traffic"}
        self.members: list[VectorHighway] = [
            DrawnTraffic({**base, "vehicles_count": count}, n, mixture) for count, n in groups
        ]
        self.members += [
            SplitReplay(base, n, table, min_duration)
            for table, n in zip(mixture.tables, shares, strict=True)
            if n
        ]
        self.num_envs = sum(m.num_envs for m in self.members)
        self._edges = np.cumsum([0] + [m.num_envs for m in self.members])
        self.env_lanes = np.concatenate([np.full(m.num_envs, m.lanes) for m in self.members])
        """Each environment's lanes (a replayed table's road may differ from bgap's)."""
        self.single_observation_space = self.members[0].single_observation_space
        self.single_action_space = spaces.Discrete(5)
        rows = self.single_observation_space.shape
        self.observation_space = spaces.Box(-1.0, 1.0, (self.num_envs, *rows), np.float32)
        self.action_space = spaces.MultiDiscrete(np.full(self.num_envs, 5))

    def sources(self) -> list[str]:
        """Each env's current episode's source: ``bgap``, ``stock`` or ``replay``."""
        out: list[str] = []
        for m in self.members:
            drawn = getattr(m, "drawn", None)
            out += [d.source for d in drawn] if drawn is not None else ["replay"] * m.num_envs
        return out

    def reset(self, *, seed: Any = None, options: dict | None = None):
        seeds = env_seeds(seed, self.num_envs)
        parts = []
        for m, lo, hi in zip(self.members, self._edges[:-1], self._edges[1:], strict=True):
            parts.append(m.reset(seed=None if seeds is None else seeds[lo:hi], options=options))
        return np.concatenate([o for o, _ in parts]), _merge([i for _, i in parts])

    def step(self, actions: np.ndarray):
        actions = np.asarray(actions, dtype=np.int64).reshape(self.num_envs)
        parts = [
            m.step(actions[lo:hi])
            for m, lo, hi in zip(self.members, self._edges[:-1], self._edges[1:], strict=True)
        ]
        obs, rewards, terminated, truncated = (
            np.concatenate([p[k] for p in parts]) for k in range(4)
        )
        return obs, rewards, terminated, truncated, _merge([p[4] for p in parts])

    def state_dict(self) -> dict[str, Any]:
        """Every member's state (:meth:`VectorHighway.state_dict`), to resume exactly."""
        return {"members": [m.state_dict() for m in self.members]}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """A :meth:`state_dict` put back (the same mixture and number of environments)."""
        check(
            len(state["members"]) == len(self.members),
            "state",
            f"{len(state['members'])} members",
            f"a state of this mixture's {len(self.members)} member batches",
        )
        for m, part in zip(self.members, state["members"], strict=True):
            m.load_state_dict(part)

    def observations(self) -> np.ndarray:
        """Every env's current observation (after :meth:`load_state_dict`)."""
        return np.concatenate([m.observations() for m in self.members])

    def close(self, **kwargs: Any) -> None:
        for m in self.members:
            m.close()


def _merge(infos: list[dict[str, Any]]) -> dict[str, Any]:
    """Members' info dicts as one: each per-env array concatenated, a key some member lacks
    filled (``final_obs`` and its ``_`` mask: None and False) and the reward terms merged."""
    sizes = [len(i["speed"]) for i in infos]
    out: dict[str, Any] = {}
    keys = [k for k in dict.fromkeys(k for i in infos for k in i) if k != "rewards"]
    for key in keys:
        parts = []
        for info, n in zip(infos, sizes, strict=True):
            if key in info:
                parts.append(np.asarray(info[key]))
            elif key == "final_obs":
                parts.append(np.full(n, None, dtype=object))
            else:
                parts.append(np.zeros(n, dtype=bool))  # a mask, or a replay-only flag
        out[key] = np.concatenate(parts)
    if all("rewards" in i for i in infos):
        out["rewards"] = {
            k: np.concatenate([i["rewards"][k] for i in infos]) for k in infos[0]["rewards"]
        }
    return out
