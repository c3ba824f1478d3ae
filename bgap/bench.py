"""Benchmarks, run by hand (never by the test suite): they print figures.

    python -m bgap.bench env        # policy steps/s of our environment vs highway-v0
    python -m bgap.bench cmetric    # CMetric vehicle-frames/s vs a networkx baseline

Figures are reported beside a baseline measured in the same run, since machines are noisy.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np


def steps_per_second(env, seconds: float, seed: int = 0) -> float:
    """Random ego actions, auto-reset, for about ``seconds`` of wall time."""
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        _, _, term, trunc, _ = env.step(int(rng.integers(env.action_space.n)))
        steps += 1
        if term or trunc:
            env.reset(seed=seed + steps)
    return steps / (time.perf_counter() - start)


def bench_env(seconds: float) -> None:
    import gymnasium as gym
    import highway_env  # noqa: F401

    from bgap.config import compose, validate
    from bgap.envs import make_env

    print(f"{'scenario':<10}{'highway-v0':>14}{'bgap paper':>14}{'bgap stock':>14}{'ratio':>8}")
    for density, n in (("sparse", 5), ("dense", 40)):
        settings = {
            "lanes_count": 4,
            "vehicles_count": n,
            "duration": 60,
            "policy_frequency": 1,
            "simulation_frequency": 15,
        }
        ref = steps_per_second(gym.make("highway-v0", config=settings), seconds)
        paper = steps_per_second(
            make_env(validate(compose("simulate", [f"env={density}"]))), seconds
        )
        stock = steps_per_second(
            make_env(validate(compose("simulate", [f"env={density}", "behavior=stock"]))), seconds
        )
        print(f"{density:<10}{ref:>14.1f}{paper:>14.1f}{stock:>14.1f}{paper / ref:>8.2f}")
    print("policy steps/s, random ego actions; ratio = bgap paper / highway-v0")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m bgap.bench", description=__doc__)
    parser.add_argument("what", choices=sorted(BENCHES))
    parser.add_argument("--seconds", type=float, default=10.0, help="wall time per measurement")
    args = parser.parse_args(argv)
    BENCHES[args.what](args.seconds)


BENCHES: dict[str, Callable[[float], None]] = {"env": bench_env}

if __name__ == "__main__":
    main()
