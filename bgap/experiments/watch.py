"""``python -m bgap.watch``: a policy driving, as a video (rl-zoo3's ``enjoy`` with
``record_video``).

    python -m bgap.watch policy=zoo:learner-dqn-k3/dense/behavior_rich/s8 mix=0.5
    python -m bgap.watch policy=outputs/runs/RUN episodes=3 behavior=stock

By default the policy plays in the traffic it was trained in (its zoo card, or its run
folder's ``config.yaml``: density, behaviour, reward, traffic); any of them can be set on the
command line (``behavior=stock``, ``env=dense``, ``mix=0.8``; replayed traffic is refused:
the vector backend records no frames of it). Each
episode is written as ``episode<k>.mp4`` (H.264 through imageio-ffmpeg, 15 pictures per
second of simulated time: every simulation frame) or, where that writer is missing,
``episode<k>.gif``; ``episodes.csv`` holds each episode's outcome, which is also printed.
Pictures come from the recorded frames (:mod:`bgap.sim.film`), so both backends are drawn
alike.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import pandas as pd
from omegaconf import OmegaConf

from bgap.agents import zoo
from bgap.agents.policies import as_policy, check_rows, model_path
from bgap.common.errors import check
from bgap.common.runs import CONFIG, digest, write_atomic
from bgap.common.scores import episode_distance
from bgap.common.vocab import BASELINES
from bgap.sim.config import SCHEMAS as SIM_SCHEMAS
from bgap.sim.config import BaseConfig
from bgap.sim.film import frames
from bgap.sim.rollout import rollout
from bgap.traffic.scenario import env_config

FORMATS = ("mp4", "gif")


@dataclass
class WatchConfig(BaseConfig):
    """``python -m bgap.watch``: render a policy's episodes to video files."""

    policy: str = "???"
    """A zoo name (``zoo:<arm>/<density>/<family>/s<seed>``), a ``model.zip`` or its run
    folder, or a baseline (``rule``, ``idle``, ...)."""
    episodes: int = 1
    seed: int = 100000
    """Episode ``k`` is seeded ``seed + k`` (default: the study's first test episode)."""
    out: str = ""
    """Output folder; default ``outputs/watch/<policy>-<hash of the settings>``."""
    format: str = "mp4"
    """``mp4`` (falls back to ``gif`` where imageio-ffmpeg is missing) or ``gif``."""
    zoo_override: bool = False
    """Play a zoo policy under other ego speeds or frequencies than it was trained with (its
    number of observed vehicles is the network's input: never overridden)."""
    backend: str = "vector"

    def __post_init__(self) -> None:
        # before the base checks: refused whatever the table
        check(
            self.traffic.source != "replay",
            "traffic",
            self.traffic.name,
            "replayed traffic cannot be watched yet (the vector backend, which alone replays, "
            "records no frames of it): watch the policy in simulated or stock traffic",
        )
        super().__post_init__()
        check(self.episodes >= 1, "episodes", self.episodes, "must be >= 1")
        check(self.format in FORMATS, "format", self.format, f"use one of {FORMATS}")
        check(
            self.policy in BASELINES or zoo.is_zoo(self.policy) or Path(self.policy).exists(),
            "policy",
            self.policy,
            f"use a zoo name (zoo:<arm>/<density>/<family>/s<seed>), a model.zip or run folder, "
            f"or one of {BASELINES}",
        )


SCHEMAS = (*SIM_SCHEMAS, (None, "base_watch", WatchConfig))


def own_settings(policy: str) -> list[str]:
    """The overrides that put ``policy`` in the traffic it was trained in: its zoo card's
    ``watch`` list, or its run folder's settings; none for a baseline."""
    if policy in BASELINES:
        return []
    path = model_path(policy)
    card = zoo.card(path)
    if card:
        return list(card.get("watch", []))
    stored = path.parent / CONFIG
    if not stored.exists():
        return []
    cfg = OmegaConf.to_container(OmegaConf.load(stored), resolve=True)
    keys = {
        "env": ("env", "name"),
        "behavior": ("behavior", "name"),
        "reward": ("reward", "name"),
        "traffic": ("traffic", "name"),
    }
    return [f"{k}={cfg[a][b]}" for k, (a, b) in keys.items() if a in cfg and b in cfg[a]]


def default_out(cfg: WatchConfig) -> Path:
    """``outputs/watch/<policy>-<digest>``: one folder per policy and settings."""
    slug = cfg.policy.removeprefix(zoo.PREFIX).replace("/", "-").replace(".", "_")
    settings = {k: v for k, v in asdict(cfg).items() if k != "out"}
    return Path("outputs") / "watch" / f"{slug.strip('-_')[-60:]}-{digest(settings)}"


def writer_format(asked: str) -> str:
    """``mp4`` where imageio-ffmpeg is installed, else ``gif``."""
    if asked == "mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError:
            print("imageio-ffmpeg is not installed: writing GIF (pip install imageio-ffmpeg)")
            return "gif"
    return asked


def write_video(path: Path, images: list, fps: float) -> None:
    """``images`` as an MP4 or GIF at ``fps`` pictures per second, whole or not at all."""
    # Imported here: imageio only where a video is written.
    import imageio.v2 as imageio

    def write(tmp: Path) -> None:
        if path.suffix == ".mp4":
            with imageio.get_writer(
                tmp, format="FFMPEG", fps=fps, codec="libx264", quality=7, macro_block_size=16
            ) as video:
                for image in images:
                    video.append_data(image)
        else:
            imageio.mimsave(tmp, images, format="GIF", duration=1000 / fps, loop=0)

    write_atomic(path, write)


def watch(cfg: WatchConfig, out: Path) -> pd.DataFrame:
    """Play ``cfg.policy`` on ``cfg.episodes`` seeded episodes and write each as a video."""
    config = env_config(cfg)
    if zoo.is_zoo(cfg.policy):
        zoo.check_played_under(model_path(cfg.policy), config, cfg.zoo_override)
    policy, rows = as_policy(cfg.policy, config)
    check_rows(cfg.policy, rows, config)  # a network reads its own number of rows only
    seeds = range(cfg.seed, cfg.seed + cfg.episodes)
    played = rollout(config, policy, seeds, cfg.backend, record=True)
    fps = float(config["simulation_frequency"])  # every simulation frame: real time
    suffix = writer_format(cfg.format)
    episodes = played.episodes.copy()
    episodes["distance"] = episode_distance(episodes, config["policy_frequency"])
    for k in range(cfg.episodes):
        table = played.trajectories[played.trajectories.episode == k]
        path = out / f"episode{k}.{suffix}"
        write_video(path, frames(table, int(config["lanes_count"])), fps)
        print(describe(k, episodes.iloc[k], path))
    write_atomic(out / "episodes.csv", lambda tmp: episodes.to_csv(tmp, index=False))
    return episodes


def describe(k: int, row: Any, path: Path) -> str:
    """One episode's outcome in one line."""
    crash = f"crashed ({row.ending})" if row.crashed else "no crash"
    return (
        f"episode {k} (seed {int(row.seed)}): {crash} after {int(row.steps)} steps, "
        f"{row.avg_speed:.2f} m/s, {int(row.lane_changes)} lane changes, "
        f"{row.distance:.0f} m -> {path}"
    )
