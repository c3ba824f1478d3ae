"""Measure how often an episode starts where no action avoids a collision.

A start is *feasible* when at least one of the five meta-actions, held for the first policy
period, ends that period without an ego collision. This measures the share of infeasible
starts on the seeds the study evaluates (100,000 upwards), per density and mix, on bgap's
vector backend, on highway-env's backend with bgap's drivers, and in highway-env's own
``highway-v0`` on the same seeds (which has no mix: its drivers are stock IDM and MOBIL).
It also counts the starts where *every* action is safe, and where only some are, and the
same with each action held for the first three policy periods (the early window in which
the study's crashes cluster).

    python tools/starts.py [EPISODES] [HIGHWAY_EPISODES]   # defaults 2000 and 100

highway-env's backend steps one environment at a time (about 0.5 s per dense start and
action here), hence its smaller count; its seeds are the first of the vector backend's.
"""

from __future__ import annotations

import sys
import time
import warnings
from functools import partial

import gymnasium as gym
import numpy as np
import pandas as pd

import bgap  # noqa: F401  (registers bgap/BehaviorHighway-v0)
from bgap.sim.vector import VectorHighway

ACTIONS = 5
FIRST_SEED = 100_000
DENSITIES = {"sparse": 5, "dense": 40}
MIXES = (0.0, 0.5, 1.0)


def _config(vehicles: int, mix: float) -> dict:
    return {"vehicles_count": vehicles, "mix": mix, "observation": {"vehicles_count": vehicles}}


def vector_safe(vehicles: int, mix: float, seeds: list[int], periods: int) -> np.ndarray:
    """safe[i, a]: seed i's start survives action a held for ``periods`` policy periods."""
    env = VectorHighway(_config(vehicles, mix), len(seeds) * ACTIONS)
    env.reset(seed=[s for s in seeds for _ in range(ACTIONS)])
    crashed = np.zeros(len(seeds) * ACTIONS, dtype=bool)
    for _ in range(periods):  # an env that crashed restarts; its first crash is kept
        _, _, _, _, info = env.step(np.tile(np.arange(ACTIONS), len(seeds)))
        crashed |= np.asarray(info["crashed"], dtype=bool)
    return ~crashed.reshape(len(seeds), ACTIONS)


def highway_safe(env_id: str, config: dict, seeds: list[int], periods: int) -> np.ndarray:
    """The same on a highway-env environment, one reset per seed and action."""
    env = gym.make(env_id, config=config)
    safe = np.ones((len(seeds), ACTIONS), dtype=bool)
    for i, s in enumerate(seeds):
        for a in range(ACTIONS):
            env.reset(seed=s)
            for _ in range(periods):
                _, _, terminated, _, info = env.step(a)
                if info["crashed"]:
                    safe[i, a] = False
                if terminated:
                    break
    env.close()
    return safe


def summary(safe: np.ndarray) -> dict[str, float]:
    some = safe.any(axis=1)
    return {
        "infeasible %": 100 * float((~some).mean()),
        "every action safe %": 100 * float(safe.all(axis=1).mean()),
        "some actions crash %": 100 * float((some & ~safe.all(axis=1)).mean()),
    }


def main(episodes: int = 2000, highway_episodes: int = 100) -> None:
    warnings.filterwarnings("ignore")
    seeds = list(range(FIRST_SEED, FIRST_SEED + episodes))
    few = seeds[:highway_episodes]
    rows = []

    def row(density, mix, traffic, starts, fn) -> None:
        for periods in (1, 3):
            start = time.perf_counter()
            safe = fn(periods)
            rows.append(
                {
                    "density": density,
                    "mix": mix,
                    "traffic": traffic,
                    "starts": starts,
                    "periods held": periods,
                    **summary(safe),
                    "s": time.perf_counter() - start,
                }
            )

    for density, n in DENSITIES.items():
        for mix in MIXES:
            row(density, mix, "bgap, vector", len(seeds), partial(vector_safe, n, mix, seeds))
            row(density, mix, "bgap, vector", len(few), partial(vector_safe, n, mix, few))
            bgap_env = partial(highway_safe, "bgap/BehaviorHighway-v0", _config(n, mix), few)
            row(density, mix, "bgap, highway-env", len(few), bgap_env)
        stock = partial(highway_safe, "highway-v0", {"vehicles_count": n}, few)
        row(density, float("nan"), "highway-v0 (stock)", len(few), stock)
    print(f"seeds from {FIRST_SEED}\n")
    print(pd.DataFrame(rows).to_markdown(index=False, floatfmt=".1f"))


if __name__ == "__main__":
    args = [int(a) for a in sys.argv[1:3]]
    main(*args)
