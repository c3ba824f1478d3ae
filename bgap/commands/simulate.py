"""``bgap simulate``: record behaviour-rich traffic as a trajectory table."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from bgap.agents import zoo
from bgap.agents.policies import as_policy, check_rows, load_model, model_path
from bgap.common.config import app, load
from bgap.common.runs import save_run_metadata, write_atomic
from bgap.common.vocab import BASELINES
from bgap.datasets.config import SCHEMAS, SimulateConfig
from bgap.datasets.simulate import INTERRUPTED, record
from bgap.runner.locks import exclusive
from bgap.traffic.scenario import env_config


@app("simulate", "bgap.simulate", SCHEMAS, INTERRUPTED)
def main(dcfg: DictConfig) -> None:
    cfg: SimulateConfig = load(dcfg)
    if cfg.policy not in BASELINES:  # a file that is no model, or a model of another
        # observation, fails before anything is written
        config = env_config(cfg)
        if zoo.is_zoo(cfg.policy):
            zoo.check_played_under(model_path(cfg.policy), config, cfg.zoo_override)
        check_rows(cfg.policy, as_policy(load_model(cfg.policy), config)[1], config)
    with exclusive(cfg.out):
        _write(cfg, save_run_metadata(cfg.out, dcfg))


def _write(cfg: SimulateConfig, out: Path) -> None:
    result = record(cfg, render=cfg.render)
    if result.images:
        # Imported here: imageio only when a GIF is asked for (render=true).
        import imageio.v2 as imageio

        imageio.mimsave(out / "episode0.gif", result.images, duration=0.2, loop=0)
    table = result.trajectories
    path = out / "trajectories.parquet"
    # each file whole or not at all: a kill never leaves half a table
    write_atomic(path, lambda tmp: table.to_parquet(tmp, index=False))
    write_atomic(out / "episodes.csv", lambda tmp: result.episodes.to_csv(tmp, index=False))
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
