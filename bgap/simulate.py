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
    if cfg.backend == "vector":
        if gif_path:
            raise ValueError("render=true needs backend=highway (the vector backend draws nothing)")
        return simulate_vector(cfg, episodes, progress)
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


def simulate_vector(
    cfg: SimulateConfig, episodes: int, progress: bool = True, batch: int = 64
) -> pd.DataFrame:
    """:func:`simulate` on the vectorised backend: ``batch`` episodes side by side, every
    frame recorded in the same schema. The random ego draws from one stream per episode."""
    from bgap.config import env_config
    from bgap.recorder import table_from_states
    from bgap.sim.vector import LABEL_NAMES, VectorHighway, initial_states

    config = env_config(cfg)
    tables = []
    bar = tqdm(total=episodes, desc="episodes", disable=not progress, unit="ep")
    for start in range(0, episodes, batch):
        seeds = [cfg.seed + k for k in range(start, min(start + batch, episodes))]
        venv = VectorHighway(config, len(seeds), record=True)
        venv.reset(seed=seeds)
        labels = [[LABEL_NAMES[c] for c in venv.g[b, :, 4]] for b in range(len(seeds))]
        frames = [[s] for s in initial_states(venv)]
        rngs = [np.random.default_rng(s) for s in seeds]
        live = np.ones(len(seeds), dtype=bool)
        while live.any():
            actions = np.full(len(seeds), IDLE)
            if cfg.policy == "random":
                actions = np.array([r.integers(5) for r in rngs])
            _, _, terminated, truncated, _ = venv.step(actions)
            for b in np.flatnonzero(live):
                frames[b].append(venv.frames[b].copy())
            finished = live & (terminated | truncated)
            bar.update(int(finished.sum()))
            live &= ~finished
        for b, seed in enumerate(seeds):
            states = np.concatenate(frames[b])
            tables.append(table_from_states(states, labels[b], seed - cfg.seed, venv.dt))
    bar.close()
    return pd.concat(tables, ignore_index=True)


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
