"""``python -m bgap.simulate``: generate a behaviour-rich trajectory dataset.

    python -m bgap.simulate env=dense mix=0.6 episodes=20 render=true out=data/dense60

writes ``trajectories.parquet`` (schema in :mod:`bgap.recorder`), ``config.yaml``,
``command.txt`` and, with ``render=true``, ``episode0.gif`` (ego green, aggressive red,
conservative blue).
"""

from __future__ import annotations

from pathlib import Path

import hydra
import numpy as np
import pandas as pd
from omegaconf import DictConfig
from tqdm import tqdm

from bgap.config import CONF_DIR, SimulateConfig, load, register_configs
from bgap.envs import make_env
from bgap.recorder import TrajectoryRecorder
from bgap.runs import save_run_metadata

IDLE = 1  # DiscreteMetaAction index of IDLE


def simulate(
    cfg: SimulateConfig,
    episodes: int | None = None,
    progress: bool = True,
    gif_path: str | Path | None = None,
) -> pd.DataFrame:
    """Run ``episodes`` seeded episodes (seeds ``cfg.seed + k``) and return every frame."""
    episodes = cfg.episodes if episodes is None else episodes
    env = make_env(cfg, render_mode="rgb_array" if gif_path else None)
    recorder = TrajectoryRecorder(env)
    images: list[np.ndarray] = []
    filming = [bool(gif_path)]  # the first episode only

    def film(e) -> None:
        if filming[0] and e.frame % 3 == 0:  # a 5 Hz animation of the 15 Hz simulation
            images.append(e.render())

    env.unwrapped.frame_listeners.append(film)
    rng = np.random.default_rng(cfg.seed)
    for k in tqdm(range(episodes), desc="episodes", disable=not progress, unit="ep"):
        filming[0] = bool(gif_path) and k == 0
        env.reset(seed=cfg.seed + k)
        done = False
        while not done:
            action = IDLE if cfg.policy == "idle" else int(rng.integers(env.action_space.n))
            _, _, terminated, truncated, _ = env.step(action)
            done = terminated or truncated
    env.close()
    if gif_path and images:
        import imageio.v2 as imageio

        imageio.mimsave(gif_path, images, duration=0.2, loop=0)
    return recorder.to_frame()


register_configs()


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="simulate")
def main(dcfg: DictConfig) -> None:
    cfg: SimulateConfig = load(dcfg)
    out = save_run_metadata(cfg.out, dcfg)
    table = simulate(cfg, gif_path=out / "episode0.gif" if cfg.render else None)
    path = out / "trajectories.parquet"
    table.to_parquet(path, index=False)
    summary = (
        table[~table.is_ego]
        .groupby("label")
        .agg(vehicles=("vehicle_id", "nunique"), mean_speed=("speed", "mean"))
    )
    print(f"wrote {len(table):,} rows to {path}\n{summary.to_string()}")


if __name__ == "__main__":
    main()
