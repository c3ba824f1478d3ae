"""``python -m bgap.simulate``: generate a behaviour-rich trajectory dataset.

    python -m bgap.simulate env=dense mix=0.6 episodes=20 render=true backend=highway out=data/d60
    python -m bgap.simulate env=dense policy=outputs/runs/RUN     # watch a trained policy

writes ``trajectories.parquet`` (schema in :mod:`bgap.recorder`), ``episodes.csv`` (one row
per episode: crash, ego speed, lane changes, ...), ``config.yaml``, ``command.txt`` and, with
``render=true``, ``episode0.gif`` (ego green, aggressive red, conservative blue).
"""

from __future__ import annotations

import pandas as pd
from omegaconf import DictConfig
from tqdm import tqdm

from bgap.config import SimulateConfig, app, load
from bgap.rollout import Rollout, rollout
from bgap.runs import save_run_metadata
from bgap.scenario import env_config


def record(
    cfg: SimulateConfig, episodes: int | None = None, progress: bool = True, render: bool = False
) -> Rollout:
    """Play ``cfg.policy`` on ``episodes`` seeded episodes (seeds ``cfg.seed + k``; episode
    ``k`` in the table), recording every frame (and with ``render``, the first episode's
    pictures)."""
    episodes = cfg.episodes if episodes is None else episodes
    with tqdm(total=episodes, desc="episodes", disable=not progress, unit="ep") as bar:
        return rollout(
            env_config(cfg),
            cfg.policy,
            range(cfg.seed, cfg.seed + episodes),
            cfg.backend,
            record=True,
            render=render,
            progress=bar.update,
        )


def simulate(
    cfg: SimulateConfig, episodes: int | None = None, progress: bool = True
) -> pd.DataFrame:
    """Every frame of ``episodes`` seeded episodes (seeds ``cfg.seed + k``) as a table."""
    return record(cfg, episodes, progress).trajectories


@app("simulate", "bgap.simulate", "nothing was written; rerun the command")
def main(dcfg: DictConfig) -> None:
    cfg: SimulateConfig = load(dcfg)
    out = save_run_metadata(cfg.out, dcfg)
    result = record(cfg, render=cfg.render)
    if result.images:
        import imageio.v2 as imageio

        imageio.mimsave(out / "episode0.gif", result.images, duration=0.2, loop=0)
    table = result.trajectories
    path = out / "trajectories.parquet"
    table.to_parquet(path, index=False)
    result.episodes.to_csv(out / "episodes.csv", index=False)
    background = table[~table.is_ego]
    summary = background.groupby("label").agg(mean_speed=("speed", "mean"))
    # Vehicle ids repeat in every episode: count (episode, vehicle) pairs.
    vehicles = background.drop_duplicates(["episode", "vehicle_id"]).groupby("label").size()
    summary.insert(0, "vehicles", vehicles)
    crashes = int(result.episodes.crashed.sum())
    print(
        f"wrote {len(table):,} rows to {path}\n{summary.to_string()}\n"
        f"ego: {crashes} of {len(result.episodes)} episodes ended in a crash"
    )


if __name__ == "__main__":
    main()
