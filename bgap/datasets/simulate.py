"""``python -m bgap.simulate``: generate a behaviour-rich trajectory dataset.

    python -m bgap.simulate env=dense mix=0.6 episodes=20 render=true backend=highway out=data/d60
    python -m bgap.simulate env=dense policy=zoo:main/sparse/default/s0  # record a trained policy

writes ``trajectories.parquet`` (schema in :mod:`bgap.sim.recorder`), ``episodes.csv`` (one row
per episode: crash, ego speed, lane changes, ...), ``config.yaml``, ``command.txt`` and, with
``render=true``, ``episode0.gif`` (ego green, aggressive red, conservative blue).
"""

from __future__ import annotations

import pandas as pd
from tqdm import tqdm

from bgap.agents.policies import rollout
from bgap.datasets.config import SimulateConfig
from bgap.sim.rollout import Rollout
from bgap.traffic.road import LANE_WIDTH
from bgap.traffic.scenario import env_config


def record(
    cfg: SimulateConfig, episodes: int | None = None, progress: bool = True, render: bool = False
) -> Rollout:
    """Play ``cfg.policy`` on ``episodes`` seeded episodes (seeds ``cfg.seed + k``; episode
    ``k`` in the table), recording every frame (and with ``render``, the first episode's
    pictures)."""
    episodes = cfg.episodes if episodes is None else episodes
    config = env_config(cfg)
    if render:
        config |= whole_scene_view(config, cfg.seed)
    with tqdm(total=episodes, desc="episodes", disable=not progress, unit="ep") as bar:
        return rollout(
            config,
            cfg.policy,
            range(cfg.seed, cfg.seed + episodes),
            cfg.backend,
            record=True,
            render=render,
            progress=bar.update,
        )


def whole_scene_view(config: dict, seed: int, width: int = 1800) -> dict:
    """highway-env's render settings that show the whole scene of the episode seeded
    ``seed`` at its start: every vehicle, the ego included (highway-env's default view is
    600 px at 5.5 px/m around the ego, about 110 m of a dense scene that spans 800 m)."""
    # Imported here: highway-env (and pygame) load only where highway-env's own backend is used.
    from bgap.envs import make_highway

    env = make_highway(config)
    env.reset(seed=seed)
    xs = [v.position[0] for v in env.unwrapped.road.vehicles]
    ego = env.unwrapped.vehicle.position[0]
    env.close()
    margin = 30.0  # m beyond the first and last vehicle
    span = max(xs) - min(xs) + 2 * margin
    scaling = min(width / span, 5.5)  # no closer than highway-env's own view
    road = config["lanes_count"] * LANE_WIDTH
    return {
        "screen_width": width,
        # the view is centred on the ego's lane: room for the whole road on either side
        "screen_height": int(2 * scaling * road + 20),
        "scaling": scaling,
        "centering_position": [(ego - min(xs) + margin) / span, 0.5],
    }


def simulate(
    cfg: SimulateConfig, episodes: int | None = None, progress: bool = True
) -> pd.DataFrame:
    """Every frame of ``episodes`` seeded episodes (seeds ``cfg.seed + k``) as a table."""
    return record(cfg, episodes, progress).trajectories


INTERRUPTED = (
    "no table was written (the output folder holds only its config.yaml and command.txt, "
    "which do not block a rerun); rerun the command"
)
