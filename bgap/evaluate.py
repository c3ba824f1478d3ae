"""Evaluation: policies x grid cells x seeded episodes -> collision %, speed, lane changes.

    python -m bgap.evaluate models=[outputs/runs/RUN_A,outputs/runs/RUN_B] grid=paper

Every policy plays the same episodes: episode k of a cell is seeded ``eval_seed + k``, so
differences between policies are paired. Per episode we record whether it ended in a crash,
the ego's average speed (sampled each policy step) and its lane changes (actions that moved
its target lane, see ``info["lane_change"]``). Per cell: collision frequency (% of episodes
that end in a crash, 95% Wilson interval), mean speed and mean lane changes (95% t interval).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import hydra
import numpy as np
import pandas as pd
from omegaconf import DictConfig
from tqdm import tqdm

from bgap.config import (
    BASELINES,
    CONF_DIR,
    ExperimentConfig,
    env_config,
    env_preset,
    load,
    register_configs,
)

IDLE, LANE_LEFT = 1, 0
Policy = Callable[[np.ndarray, list[np.random.Generator]], np.ndarray]
"""A batch of observations (B, V, 5) and one random stream per episode -> B actions."""


@dataclass(frozen=True)
class Cell:
    mix: float
    density: str
    radius: float


def grid_cells(cfg: ExperimentConfig) -> list[Cell]:
    """The cells of ``cfg.grid``; empty axes take the run's own mix, density and radius."""
    g = cfg.grid
    return [
        Cell(float(m), str(d), float(r))
        for d in (g.densities or [cfg.env.name])
        for m in (g.mixes or [cfg.mix])
        for r in (g.radii or [cfg.radius])
    ]


def cell_env_config(cfg: ExperimentConfig, cell: Cell) -> dict[str, Any]:
    """highway-env config of one cell: the run's reward and behaviours, the cell's traffic."""
    env = cfg.env if cell.density == cfg.env.name else env_preset(cell.density)
    return env_config(replace(cfg, env=env, mix=cell.mix, radius=cell.radius))


def load_policy(spec: str) -> tuple[Policy, int | None]:
    """A scripted baseline name or a model path; returns the policy and the number of
    observation rows it expects (None: any)."""
    if spec == "idle":
        return (lambda obs, rngs: np.full(len(obs), IDLE)), None
    if spec == "left":
        return (lambda obs, rngs: np.full(len(obs), LANE_LEFT)), None
    if spec == "random":
        return (lambda obs, rngs: np.array([r.integers(5) for r in rngs])), None
    from bgap.agents.dqn import DQN

    model = DQN.load(model_path(spec), device="cpu")
    return greedy(model), model.observation_space.shape[0]


def greedy(model) -> Policy:
    """A trained model as a policy: its greedy (deterministic) actions, one batched call."""
    return lambda obs, rngs: np.asarray(model.predict(obs, deterministic=True)[0]).reshape(-1)


def model_path(spec: str | Path) -> Path:
    path = Path(spec)
    if path.is_dir():
        path = path / "model.zip"
    if not path.exists():
        raise FileNotFoundError(f"no model at {path}; train it with python -m bgap.train")
    return path


def run_episode(env, policy: Policy, seed: int) -> dict[str, Any]:
    """One seeded episode on a highway-env environment; the policy's own randomness is
    seeded by the episode too."""
    rngs = [np.random.default_rng(seed)]
    obs, _ = env.reset(seed=seed)
    speeds, lane_changes, total, done, info = [], 0, 0.0, False, {}
    while not done:
        action = int(policy(obs[None], rngs)[0])
        obs, reward, terminated, truncated, info = env.step(action)
        speeds.append(info["ego_speed"])
        lane_changes += int(info["lane_change"])
        total += float(reward)
        done = terminated or truncated
    return {
        "crashed": bool(info["crashed"]),
        "avg_speed": float(np.mean(speeds)),
        "lane_changes": lane_changes,
        "steps": len(speeds),
        "return": total,
    }


def run_episodes_vector(env_cfg: dict, policy: Policy, seeds: list[int]) -> list[dict[str, Any]]:
    """The episodes ``seeds`` played side by side on the vectorised backend (one env each;
    an env that finishes early idles in its next episode, which is not counted)."""
    from bgap.sim.vector import VectorHighway

    venv = VectorHighway(env_cfg, len(seeds))
    obs, _ = venv.reset(seed=list(seeds))
    rngs = [np.random.default_rng(seed) for seed in seeds]
    b = len(seeds)
    live = np.ones(b, dtype=bool)
    speed_sum, steps, lanes = np.zeros(b), np.zeros(b, dtype=int), np.zeros(b, dtype=int)
    total, crashed = np.zeros(b), np.zeros(b, dtype=bool)
    while live.any():
        actions = np.full(b, IDLE)
        idx = np.flatnonzero(live)
        actions[idx] = policy(obs[idx], [rngs[i] for i in idx])
        obs, reward, terminated, truncated, info = venv.step(actions)
        speed_sum[idx] += info["ego_speed"][idx]
        steps[idx] += 1
        lanes[idx] += info["lane_change"][idx]
        total[idx] += reward[idx]
        crashed[idx] = info["crashed"][idx]
        live &= ~(terminated | truncated)
    return [
        {
            "crashed": bool(crashed[i]),
            "avg_speed": float(speed_sum[i] / steps[i]),
            "lane_changes": int(lanes[i]),
            "steps": int(steps[i]),
            "return": float(total[i]),
        }
        for i in range(b)
    ]


def play(env_cfg: dict, policy: Policy, seeds: list[int], backend: str) -> list[dict[str, Any]]:
    """Seeded episodes of ``policy`` on either backend, one result dict per seed."""
    if backend == "vector":
        return run_episodes_vector(env_cfg, policy, seeds)
    import gymnasium as gym

    import bgap.envs

    env = gym.make(bgap.envs.ENV_ID, config=env_cfg)
    try:
        return [run_episode(env, policy, seed) for seed in seeds]
    finally:
        env.close()


def _evaluate_chunk(
    name: str, spec: str, cell: Cell, env_cfg: dict, seeds: list[int], backend: str = "highway"
) -> list:
    policy, rows = load_policy(spec)
    if rows is not None and rows != env_cfg["observation"]["vehicles_count"]:
        return []  # a model sees a fixed number of vehicles: only its own density
    key = {"policy": name, "mix": cell.mix, "density": cell.density, "radius": cell.radius}
    results = play(env_cfg, policy, seeds, backend)
    return [{**key, "seed": seed, **r} for seed, r in zip(seeds, results, strict=True)]


def evaluate(
    cfg: ExperimentConfig,
    policies: dict[str, str],
    cells: Iterable[Cell] | None = None,
    episodes: int | None = None,
    progress: bool = True,
    chunk: int = 5,
) -> pd.DataFrame:
    """Play ``episodes`` seeded episodes of every policy on every cell; one row per episode.

    ``policies`` maps a display name to a baseline (idle, random, left) or a model path.
    """
    cells = list(cells or grid_cells(cfg))
    episodes = episodes or cfg.profile.eval_episodes
    seeds = [cfg.eval_seed + k for k in range(episodes)]
    if cfg.backend == "vector":  # one batch per cell and policy, compiled threads in-process
        chunk, workers = episodes, 1
    else:
        workers = cfg.workers
    jobs = [
        (name, spec, cell, cell_env_config(cfg, cell), seeds[i : i + chunk], cfg.backend)
        for cell in cells
        for name, spec in policies.items()
        for i in range(0, episodes, chunk)
    ]
    rows: list[dict] = []
    bar = tqdm(total=len(jobs) * chunk, unit="ep", desc="evaluate", disable=not progress)
    if workers > 1:
        with ProcessPoolExecutor(workers, mp_context=get_context("fork")) as pool:
            for part in pool.map(_evaluate_chunk, *zip(*jobs, strict=True)):
                rows.extend(part)
                bar.update(chunk)
    else:
        for job in jobs:
            rows.extend(_evaluate_chunk(*job))
            bar.update(chunk)
    bar.close()
    return pd.DataFrame(rows)


def wilson_interval(k: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """95% Wilson interval of a rate of k events in n trials."""
    if n == 0:
        return math.nan, math.nan
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return centre - half, centre + half


def t_interval(x: np.ndarray) -> tuple[float, float]:
    """95% Student t interval of the mean of x (NaN below two values)."""
    from scipy.stats import t

    if len(x) < 2:
        return math.nan, math.nan
    half = t.ppf(0.975, len(x) - 1) * x.std(ddof=1) / math.sqrt(len(x))
    return x.mean() - half, x.mean() + half


def summarize(episodes: pd.DataFrame) -> pd.DataFrame:
    """Per policy and cell: collision %, average speed, lane changes, each with a 95% CI."""
    rows = []
    for key, g in episodes.groupby(["policy", "mix", "density", "radius"], sort=False):
        crashes, n = int(g.crashed.sum()), len(g)
        lo, hi = wilson_interval(crashes, n)
        s_lo, s_hi = t_interval(g.avg_speed.to_numpy())
        l_lo, l_hi = t_interval(g.lane_changes.to_numpy(dtype=float))
        rows.append(
            dict(zip(["policy", "mix", "density", "radius"], key, strict=True))
            | {
                "episodes": n,
                "collision_pct": 100.0 * crashes / n,
                "collision_lo": 100 * lo,
                "collision_hi": 100 * hi,
                "avg_speed": g.avg_speed.mean(),
                "speed_lo": s_lo,
                "speed_hi": s_hi,
                "lane_changes": g.lane_changes.mean(),
                "lane_changes_lo": l_lo,
                "lane_changes_hi": l_hi,
                "return": g["return"].mean(),
            }
        )
    return pd.DataFrame(rows)


def write_results(out: Path, episodes: pd.DataFrame, summary: pd.DataFrame) -> None:
    out.mkdir(parents=True, exist_ok=True)
    episodes.to_csv(out / "episodes.csv", index=False)
    summary.to_csv(out / "summary.csv", index=False)
    (out / "summary.json").write_text(json.dumps(summary.to_dict(orient="records"), indent=1))


def format_table(summary: pd.DataFrame) -> str:
    """The paper's three bars as text: collision %, speed, lane changes with 95% CIs."""
    lines = [
        f"{'policy':<15}{'mix':>5}{'density':>9}{'radius':>8}{'episodes':>9}"
        f"{'collisions %':>22}{'speed m/s':>20}{'lane changes':>20}"
    ]
    for r in summary.itertuples():
        lines.append(
            f"{r.policy:<15}{r.mix:>5.2f}{r.density:>9}{r.radius:>8.0f}{r.episodes:>9}"
            f"{r.collision_pct:>8.1f} [{r.collision_lo:5.1f},{r.collision_hi:5.1f}]"
            f"{r.avg_speed:>8.2f} [{r.speed_lo:5.2f},{r.speed_hi:5.2f}]"
            f"{r.lane_changes:>8.2f} [{r.lane_changes_lo:5.2f},{r.lane_changes_hi:5.2f}]"
        )
    return "\n".join(lines)


def plot_comparison(summary: pd.DataFrame, path: Path, title: str = "") -> None:
    """Bars per policy (one group per cell) with 95% CIs, as in the paper's figures."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    metrics = [
        ("collision_pct", "collision_lo", "collision_hi", "collisions [% episodes]"),
        ("avg_speed", "speed_lo", "speed_hi", "ego speed [m/s]"),
        ("lane_changes", "lane_changes_lo", "lane_changes_hi", "lane changes / episode"),
    ]
    cells = summary[["mix", "density", "radius"]].drop_duplicates().to_records(index=False)
    policies = list(dict.fromkeys(summary.policy))
    fig, axes = plt.subplots(1, 3, figsize=(4 + 1.2 * len(cells) * len(policies) / 2, 3.8))
    width = 0.8 / len(policies)
    for ax, (col, lo, hi, label) in zip(axes, metrics, strict=True):
        for p_i, pol in enumerate(policies):
            sub = summary[summary.policy == pol].set_index(["mix", "density", "radius"])
            vals = [sub.loc[tuple(c)] if tuple(c) in sub.index else None for c in cells]
            x = np.arange(len(cells)) + p_i * width
            y = [v[col] if v is not None else np.nan for v in vals]
            err = np.array(
                [[v[col] - v[lo], v[hi] - v[col]] if v is not None else [0, 0] for v in vals]
            ).T
            ax.bar(x, y, width, yerr=np.nan_to_num(err), capsize=2, label=pol)
        ax.set_xticks(np.arange(len(cells)) + 0.4 - width / 2)
        ax.set_xticklabels([f"{d}\nmix {m:g}\nr {r:g}" for m, d, r in cells], fontsize=7)
        ax.set_ylabel(label)
    axes[0].legend(fontsize=7)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def policy_specs(cfg: ExperimentConfig) -> dict[str, str]:
    """Named policies of ``bgap.evaluate``: each model (named by its run folder) and baselines.

    A folder without ``model.zip`` stands for every run folder inside it (a pipeline's runs)."""
    models: list[Path] = []
    for m in map(Path, cfg.models):
        if m.is_dir() and not (m / "model.zip").exists():
            found = sorted(p.parent for p in m.glob("*/model.zip"))
            if not found:
                raise FileNotFoundError(f"no model.zip in {m} or its subfolders")
            models.extend(found)
        else:
            models.append(m)
    specs = {m.name if m.is_dir() else m.parent.name: str(m) for m in models}
    specs.update({b: b for b in cfg.baselines if b in BASELINES})
    return specs


register_configs()


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="evaluate")
def main(dcfg: DictConfig) -> None:
    from bgap.runs import save_run_metadata

    cfg: ExperimentConfig = load(dcfg)
    out = Path(cfg.out or Path(cfg.root) / "results" / f"evaluate-{cfg.grid.name}")
    save_run_metadata(out, dcfg)
    episodes = evaluate(cfg, policy_specs(cfg))
    summary = summarize(episodes)
    write_results(out, episodes, summary)
    plot_comparison(summary, out / "comparison.png")
    print(format_table(summary))
    print(f"results in {out}")


if __name__ == "__main__":
    main()
