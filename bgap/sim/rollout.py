"""Playing a policy on seeded episodes: the one rollout loop of bgap.

    from bgap.agents.policies import rollout   # this loop, with policies named or loaded
    result = rollout(env_config(cfg), "idle", seeds=range(100, 200), backend="vector")
    result.episodes   # one row per episode: crashed, avg_speed, lane_changes, steps, ...

Evaluation, dataset generation (``record=True`` adds every vehicle's trajectory), the
parity study, calibration and training's periodic evaluation all play their episodes here,
on either simulator (:func:`bgap.sim.simulators.make_vector_env`). Episode ``k`` is seeded
``seeds[k]``, and so is the policy's own randomness in it, so every policy meets the same
traffic and a result does not depend on which episodes were played beside it.

Here a policy is a loaded model (anything with SB3's ``predict``), played greedily; a
callable from a batch of observations ``(B, V, 5)`` to ``B`` actions; or a callable
``(observations, rngs) -> actions`` that also gets one seeded random stream per episode.
Baseline names (``idle``, ``rule``, ...) and model paths are the agents' business:
:func:`bgap.agents.policies.rollout` resolves them and plays them here.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from bgap.common.vocab import FINISHED, LABEL_NAMES, LANE_CHANGE_WINDOW
from bgap.sim.recorder import table_from_states
from bgap.sim.simulators import make_vector_env
from bgap.traffic.road import IDLE

Policy = Callable[[np.ndarray, list[np.random.Generator]], np.ndarray]
"""A batch of observations (B, V, 5) and one random stream per episode -> B actions."""

TERMS = ("collision", "lane_change", "right_lane", "high_speed")
"""Reward terms whose per-step mean each episode row reports (``r_<term>``)."""


# ---------------------------------------------------------------------------- policies
def greedy(model: Any) -> Policy:
    """A trained model (SB3's ``predict``) as a policy: its greedy actions, one batched call."""
    return lambda obs, rngs: np.asarray(model.predict(obs, deterministic=True)[0]).reshape(-1)


def as_callable(spec: Any) -> tuple[Policy, int | None]:
    """A loaded model (SB3's ``predict``) or a callable as a :data:`Policy`, with the number
    of observation rows it needs (None: any). Names and paths of policies are resolved by
    :func:`bgap.agents.policies.as_policy`, above the simulators."""
    if isinstance(spec, (str, Path)):
        raise TypeError(
            f"policy {str(spec)!r} is a name or a path: play it with bgap.agents.policies.rollout"
        )
    if hasattr(spec, "predict"):
        return greedy(spec), int(spec.observation_space.shape[0])
    if not callable(spec):
        raise TypeError(f"{spec!r} is not a policy (a baseline name, a model or a callable)")
    try:
        positional = [
            p
            for p in inspect.signature(spec).parameters.values()
            if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD) and p.default is p.empty
        ]
    except (TypeError, ValueError):  # builtins without a signature: observations only
        positional = [None]
    if len(positional) == 1:
        return (lambda obs, rngs: spec(obs)), None
    return spec, None


# ---------------------------------------------------------------------------- statistics
class EpisodeStats:
    """Running per-episode statistics of B environments, from the step infos both backends
    share; :meth:`row` gives a finished episode's figures. Used by the rollout and by
    training, so both count speed, lane changes and crashes the same way.

    How a crash happened (``ending``, :data:`bgap.common.vocab.ENDINGS`): ``lane_change`` when the
    ego started a lane change in the step of the crash or the step before (at the paper's
    1 Hz, contact within :data:`~bgap.common.vocab.LANE_CHANGE_WINDOW` = 2 s of its start);
    otherwise ``rear_end`` when the vehicle it touched is ahead of it (``info["contact_dx"]``
    > 0), ``rear_ended`` when behind. Our definitions; the paper counts crashes only."""

    def __init__(
        self, num_envs: int, policy_frequency: float = 1.0, overtakes: bool = False
    ) -> None:
        self.speed = np.zeros(num_envs)
        self.passed = np.zeros(num_envs, dtype=np.int64)
        self.count_overtakes = overtakes  # an ``overtakes`` column (the generalisation study)
        self.steps = np.zeros(num_envs, dtype=np.int64)
        self.lanes = np.zeros(num_envs, dtype=np.int64)
        self.total = np.zeros(num_envs)
        self.crashed = np.zeros(num_envs, dtype=bool)
        self.terms = np.zeros((num_envs, len(TERMS)))
        self.last_lane_change = np.full(num_envs, -(10**9), dtype=np.int64)
        self.contact = np.full(num_envs, np.nan)
        self.log_contact = np.zeros(num_envs, dtype=bool)
        self.replayed = False  # replayed traffic reports log contacts (bgap.traffic.replay)
        # Steps whose crash a lane change started in them or before them is blamed for.
        self.window = max(int(np.ceil(LANE_CHANGE_WINDOW * policy_frequency)) - 1, 0)

    def add(self, idx: np.ndarray, reward: np.ndarray, info: dict[str, Any]) -> None:
        """Account one step of envs ``idx`` (their rewards and the vector step's info)."""
        self.speed[idx] += np.asarray(info["ego_speed"], dtype=float)[idx]
        self.steps[idx] += 1
        changed = np.asarray(info["lane_change"], dtype=np.int64)[idx]
        self.lanes[idx] += changed
        if "overtakes" in info:
            self.passed[idx] += np.asarray(info["overtakes"], dtype=np.int64)[idx]
        self.last_lane_change[idx[changed > 0]] = self.steps[idx[changed > 0]]
        self.total[idx] += np.asarray(reward, dtype=float)[idx]
        self.crashed[idx] = np.asarray(info["crashed"], dtype=bool)[idx]
        if "contact_dx" in info:
            self.contact[idx] = np.asarray(info["contact_dx"], dtype=float)[idx]
        if "log_contact" in info:
            self.replayed = True
            self.log_contact[idx] = np.asarray(info["log_contact"], dtype=bool)[idx]
        rewards = info.get("rewards", {})
        for k, term in enumerate(TERMS):
            if f"{term}_reward" in rewards:
                self.terms[idx, k] += np.asarray(rewards[f"{term}_reward"], dtype=float)[idx]

    def ending(self, i: int) -> str:
        """How env ``i``'s episode ended (so far): :data:`bgap.common.vocab.ENDINGS`."""
        if not self.crashed[i]:
            return "timeout"
        if self.steps[i] - self.last_lane_change[i] <= self.window:
            return "lane_change"
        dx = self.contact[i]
        if np.isnan(dx) or dx == 0.0:  # no partner reported
            return "other"
        return "rear_end" if dx > 0 else "rear_ended"

    def row(self, i: int) -> dict[str, Any]:
        """Env ``i``'s episode so far: crash, how it ended, mean ego speed, lane changes,
        steps, return and each reward term's mean per step."""
        steps = max(int(self.steps[i]), 1)
        return {
            "crashed": bool(self.crashed[i]),
            "ending": self.ending(i),
            "avg_speed": float(self.speed[i] / steps),
            "lane_changes": int(self.lanes[i]),
            **({"overtakes": int(self.passed[i])} if self.count_overtakes else {}),
            "steps": int(self.steps[i]),
            "return": float(self.total[i]),
            **{f"r_{term}": float(self.terms[i, k] / steps) for k, term in enumerate(TERMS)},
            # replayed traffic: the crash partner still followed its log (it could not react)
            **({"log_contact": bool(self.log_contact[i])} if self.replayed else {}),
        }

    def clear(self, i: int) -> None:
        for array in (self.speed, self.steps, self.lanes, self.total, self.crashed, self.passed):
            array[i] = 0
        self.terms[i] = 0.0
        self.last_lane_change[i] = -(10**9)
        self.contact[i] = np.nan
        self.log_contact[i] = False


# ---------------------------------------------------------------------------- rollout
@dataclass
class Rollout:
    """What :func:`rollout` played: one row per episode, and with ``record=True`` every
    vehicle's trajectory (:mod:`bgap.sim.recorder`'s schema; ``episode`` is the index of the
    seed in ``seeds``)."""

    episodes: pd.DataFrame
    trajectories: pd.DataFrame | None = None
    images: list[np.ndarray] = field(default_factory=list)
    """With ``render=True``: pictures of the first episode (highway-env only)."""


def rollout(
    config: dict[str, Any],
    policy: Any,
    seeds: Iterable[int],
    backend: str = "vector",
    *,
    batch: int | None = None,
    record: bool = False,
    render: bool = False,
    progress: Callable[[int], Any] | None = None,
    overtakes: bool = False,
) -> Rollout:
    """Play ``policy`` for one episode per seed in the environment ``config`` on ``backend``.

    Episodes run ``batch`` at a time side by side (default: all of them, at most 256, on the
    vector backend; one at a time on highway-env, whose copies would idle once finished).
    ``progress(k)`` is called with the number of episodes each batch finished.
    ``overtakes``: each row also counts the vehicles the ego passed (``overtakes``).
    """
    seeds = [int(s) for s in seeds]
    act, _ = as_callable(policy)
    if batch is None:
        batch = min(len(seeds), 256) if backend == "vector" else 1
    rows, tables, images = [], [], []
    for start in range(0, len(seeds), max(batch, 1)):
        chunk = seeds[start : start + batch]
        film = render and start == 0
        venv = make_vector_env(config, len(chunk), backend, record=record, render=film)
        reset = getattr(policy, "reset", None)
        if callable(reset):  # stateful policies (a scripted ego) start over per batch
            reset()
        try:
            frequency = config.get("policy_frequency", 1)
            result = _play(venv, act, chunk, record, film, frequency, overtakes)
        finally:
            venv.close()
        rows.extend({"seed": seed, **row} for seed, row in zip(chunk, result[0], strict=True))
        if record:
            dt = 1.0 / float(config.get("simulation_frequency", 15))
            tables.extend(
                table_from_states(states, labels, start + b, dt)
                for b, (states, labels) in enumerate(result[1])
            )
        images.extend(result[2])
        if progress is not None:
            progress(len(chunk))
    trajectories = pd.concat(tables, ignore_index=True) if record else None
    return Rollout(pd.DataFrame(rows), trajectories, images)


def _play(
    venv: Any,
    act: Policy,
    seeds: Sequence[int],
    record: bool,
    film: bool,
    policy_frequency: float,
    overtakes: bool = False,
) -> tuple[list[dict], list[tuple[np.ndarray, list[str]]], list[np.ndarray]]:
    """Every env's first episode after a seeded reset; an env that finished idles or, on the
    vector backend, stops (its next episode is not counted)."""
    b = len(seeds)
    obs, info = venv.reset(seed=list(seeds))
    rngs = [np.random.default_rng(seed) for seed in seeds]
    stats = EpisodeStats(b, policy_frequency, overtakes)
    live = np.ones(b, dtype=bool)
    frames = [[info["reset_frames"][i]] for i in range(b)] if record else []
    labels = [[LABEL_NAMES[int(c)] for c in info["labels"][i]] for i in range(b)] if record else []
    images = list(info["images"][0]) if film else []
    # a finished env idles; the vector backend skips it (FINISHED): the same episodes, fewer
    # frames (a batch runs until its longest episode ends)
    rest = FINISHED if getattr(venv, "skips_finished", False) else IDLE
    while live.any():
        idx = np.flatnonzero(live)
        actions = np.full(b, rest)
        actions[idx] = act(obs[idx], [rngs[i] for i in idx])
        obs, reward, terminated, truncated, info = venv.step(actions)
        stats.add(idx, reward, info)
        if record:
            for i in idx:  # copies: a backend may reuse its frame buffer
                frames[i].append(np.array(info["frames"][i], copy=True))
        if film and live[0]:
            images.extend(info["images"][0])
        live &= ~(terminated | truncated)
    episodes = [stats.row(i) for i in range(b)]
    trajectories = [(np.concatenate(frames[i]), labels[i]) for i in range(b)] if record else []
    return episodes, trajectories, images
