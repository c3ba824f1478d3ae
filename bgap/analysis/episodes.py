"""The evaluation episodes read back: policies parsed from their run folders, and per arm,
policy family and cell the mean over training seeds with its interval."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from bgap.analysis.stats import (
    mean_interval,
    seed_per_100km_interval,
    seed_rate_interval,
)
from bgap.common.errors import ConfigError
from bgap.common.tables import read_table
from bgap.common.vocab import CRASH_KINDS
from bgap.traffic.behaviors import count_aggressive
from bgap.traffic.scenario import env_preset

MODEL = re.compile(
    r"^(?:(?P<path>.*)/)?(?P<density>[a-z]+)-(?P<family>behavior_rich|default)-s(?P<seed>\d+)$"
)
"""A trained policy's name: its run folder's path. The pipeline's layout is
``[...]/<arm>/<density>/<density>-<family>-s<seed>``; a name without the arm's and the
density's folders above it (``bgap.run``'s) is arm ``main``."""


def policy_parts(names: pd.Series) -> pd.DataFrame:
    """``arm``, ``density``, ``family`` and ``seed`` of trained policies' names (NaN family:
    not a trained policy)."""
    parsed = names.str.extract(MODEL)
    folders = parsed["path"].fillna("").str.split("/")
    in_layout = [
        len(f) >= 2 and f[-1] == d for f, d in zip(folders, parsed["density"], strict=True)
    ]
    parsed["arm"] = [f[-2] if ok else "main" for f, ok in zip(folders, in_layout, strict=True)]
    return parsed


METRICS = {"collision_pct": "collision %", "avg_speed": "speed m/s", "lane_changes": "lane changes"}
KEYS = ["arm", "family", "traffic", "density", "mix", "radius"]
MIXTURE_ARMS = ("main", "authors")
"""Arms that train both families, behaviour-rich on the mixture of the paper's mixes; so does
every learner arm (:data:`LEARNER_ARM` followed by its algorithm)."""
LEARNER_ARM = "learner-"
"""Prefix of the learner arms: ``learner-<algo>`` trains the algorithm with
the network, observation and recipe its search chose (``results/recipe/<algo>``)."""
ARM_NAMES = {
    "main": "recipe (main arm)",
    "authors": "authors' 2020 configuration",
    "mix0": "behaviour-rich trained at 0% aggressive",
    "mix50": "behaviour-rich trained at 50% aggressive",
    "mix100": "behaviour-rich trained at 100% aggressive",
}
ALGO_NAMES = {"dqn": "DQN", "qrdqn": "QR-DQN", "ppo": "PPO"}


SELECTED = re.compile(r"(?P<algo>.+)-k(?P<k>\d+)")
"""A learner arm that kept the best of each group of k training seeds on validation
(``learner-<algo>-k<k>``: params.yaml ``selections``, :mod:`bgap.experiments.select`)."""


def learner_arm(arm: str) -> tuple[str, int | None] | None:
    """A learner arm's algorithm key and, for a selection arm (``learner-<algo>-k<k>``), its
    k; None for an arm that is no learner arm."""
    if not arm.startswith(LEARNER_ARM):
        return None
    rest = arm[len(LEARNER_ARM) :]
    kept = SELECTED.fullmatch(rest)
    return (kept["algo"], int(kept["k"])) if kept else (rest, None)


def arm_algo(arm: str) -> str:
    """The algorithm an arm trains (``DQN`` but for a learner arm's)."""
    learner = learner_arm(arm)
    algo = learner[0] if learner else "dqn"
    return ALGO_NAMES.get(algo, algo)


def arm_name(arm: str) -> str:
    """An arm as the tables and figures name it."""
    learner = learner_arm(arm)
    if learner is None:
        return ARM_NAMES.get(arm, arm)
    algo, k = learner
    best = f", best of {k} training seeds on validation" if k else ""
    return (
        f"{ALGO_NAMES.get(algo, algo)} learner (its search's network, observation and recipe{best})"
    )


def mixture_arms(arms) -> list[str]:
    """Those of ``arms`` that train both families on the mixture, main and authors' first."""
    found = set(arms)
    learners = sorted(a for a in found if isinstance(a, str) and a.startswith(LEARNER_ARM))
    return [a for a in MIXTURE_ARMS if a in found] + learners


ALPHA = 0.05


def n_of(density: str) -> int | str:
    """The paper's name of a density: its number of background vehicles n."""
    try:
        return env_preset(density).vehicles_count
    except ValueError:
        return density


# ---------------------------------------------------------------------- episodes
EPISODES, MODELS, INPUTS = "episodes.parquet", "models.csv", "inputs.json"
"""What ``bgap.evaluate`` writes into an evaluation folder: the per-episode table (zstd
parquet), one row per evaluated model (its checkpoint choice and settings) and the content
hashes of every cell's traffic inputs (``cell -> input -> sha256``)."""
EPISODE_FILES = (EPISODES, "episodes.csv")
"""An evaluation folder's episodes (the csv: evaluations before the parquet)."""


def evaluation_folders(source: str | Path) -> list[Path]:
    """``source`` itself when it holds an evaluation's episodes, else every folder below it
    that does (the pipeline's ``results/evaluation/<arm>/<traffic>``), sorted."""
    source = Path(source)
    if any((source / name).exists() for name in EPISODE_FILES):
        return [source]
    found = sorted({p.parent for name in EPISODE_FILES for p in source.rglob(name)})
    if not found:
        raise FileNotFoundError(f"no evaluation episodes in {source}: run bgap.evaluate first")
    return found


REPLAY = "replay/"
"""Prefix of a replay cell's traffic, ``replay/<table>/<mode>`` (:mod:`bgap.traffic.replay`)."""


def is_replay(traffic: pd.Series) -> pd.Series:
    """Whether each row's traffic is a replayed table."""
    return traffic.astype(str).str.startswith(REPLAY)


def traffic_of(folder: Path) -> str:
    """``stock`` for an evaluation in highway-env's stock traffic (its saved
    ``behavior.name``), else ``paper`` (the behaviour presets of the grid)."""
    config = folder / "config.yaml"
    if not config.exists():
        return "paper"
    behavior = (yaml.safe_load(config.read_text()) or {}).get("behavior") or {}
    return "stock" if behavior.get("name") == "stock" else "paper"


def load_evaluations(
    sources: list[str | Path], stock: list[str | Path] = ()
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Every evaluation's episodes under ``sources`` (traffic from each one's settings;
    ``stock``: folders read as stock traffic whatever they say) with arm, family and training
    seed parsed, and their models tables (``models.csv``: empty where none was written).
    The same policy, traffic, cell and episode in two folders is refused."""
    frames, models = [], []
    for source, forced in [*((s, None) for s in sources), *((s, "stock") for s in stock)]:
        for folder in evaluation_folders(source):
            path = next(folder / n for n in EPISODE_FILES if (folder / n).exists())
            df = read_table(path)
            df["traffic"] = forced or traffic_of(folder)
            if "replay" in df:  # replay cells: traffic "replay/<table>/<mode>"
                replayed = df.replay.fillna("").astype(str) != ""
                df.loc[replayed, "traffic"] = REPLAY + df.replay[replayed].astype(str)
            frames.append(df)
            if (folder / MODELS).exists():
                models.append(read_table(folder / MODELS))
    df = parse_policies(pd.concat(frames, ignore_index=True))
    key = ["policy", "traffic", "mix", "density", "radius", "seed"]
    repeated = df.duplicated(key)
    if repeated.any():
        first = df[repeated].iloc[0]
        raise ConfigError(
            f"policy {first.policy} plays the same episodes in two of the evaluation folders "
            f"({int(repeated.sum())} repeated episodes); give each evaluation once"
        )
    return df, (pd.concat(models, ignore_index=True) if models else pd.DataFrame())


def parse_policies(df: pd.DataFrame) -> pd.DataFrame:
    """``arm``, ``family`` and ``train_seed`` columns parsed from policy names (baselines:
    their own name as family, arm "" and seed -1), and ``collision_pct`` per episode."""
    df = df.copy()
    parsed = policy_parts(df.policy)
    trained = parsed["family"].notna()
    df["family"] = parsed["family"].fillna(df.policy)
    df["arm"] = parsed["arm"].where(trained, "")
    df["train_seed"] = pd.to_numeric(parsed["seed"]).fillna(-1).astype(int)
    df["collision_pct"] = 100.0 * df.crashed.astype(float)
    if "traffic" not in df:
        df["traffic"] = "paper"
    return df


def duplicates(df: pd.DataFrame) -> dict[tuple[str, float], float]:
    """(density, mix) -> the earlier mix that gives the same traffic (the same number of
    aggressive drivers, e.g. 3 of 5 at mixes 0.5 and 0.6): such a cell repeats the other's
    episodes and is counted once in averages over mixes."""
    out = {}
    if "traffic" in df:  # a replay's mix is its table's share: it repeats no simulated cell
        df = df[~is_replay(df.traffic)]
    for density in sorted(set(df.density)):
        seen: dict[int, float] = {}
        n = n_of(density)
        for mix in sorted(set(df[df.density == density].mix)):
            k = count_aggressive(mix, n) if isinstance(n, int) else mix
            if k in seen:
                out[(density, mix)] = seen[k]
            else:
                seen[k] = mix
    return out


def distinct_cells(df: pd.DataFrame) -> pd.DataFrame:
    """Rows of cells that are not duplicates of another mix."""
    dup = duplicates(df)
    keep = [(d, m) not in dup for d, m in zip(df.density, df.mix, strict=True)]
    return df[np.asarray(keep, dtype=bool)]


def _groups(df: pd.DataFrame, metric: str) -> dict[int, np.ndarray]:
    """Training seed -> that seed's episode values of ``metric`` (seed order, the episodes
    in a fixed order: cell, then episode seed)."""
    ordered = df.sort_values(["mix", "radius", "seed"])
    return {s: g[metric].to_numpy(dtype=float) for s, g in ordered.groupby("train_seed")}


def _crashes(df: pd.DataFrame) -> list[np.ndarray]:
    """Each training seed's episodes as 0/1 crashes (:func:`_groups` order)."""
    return [x / 100 for x in _groups(df, "collision_pct").values()]


def _rate(df: pd.DataFrame, rng: np.random.Generator) -> tuple[float, float, float, int]:
    """Collision % averaged over training seeds, its 95% interval
    (:func:`bgap.analysis.stats.seed_rate_interval`) and the number of seeds."""
    pct = list(_groups(df, "collision_pct").values())
    lo, hi = seed_rate_interval([x / 100 for x in pct], rng)
    return float(np.mean([x.mean() for x in pct])), 100 * lo, 100 * hi, len(pct)


# ---------------------------------------------------------------------- cells
def cell_stats(df: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Per arm, family, traffic and cell: mean over training seeds of each metric and its 95%
    interval; returns (cells, per-seed means). Collision %: the two-level bootstrap across
    seeds widened to the pooled Wilson interval (:func:`bgap.analysis.stats.seed_rate_interval`,
    never of zero width); collisions per 100 km (episodes with the ego's distance): each
    seed's crashes over its kilometres, averaged over seeds, the two-level bootstrap widened
    to the pooled Poisson interval; speed and lane changes: Student t across seed means (across
    episodes with one seed)."""
    keys = [k for k in KEYS if k in df]
    per_seed = df.groupby([*keys, "train_seed"])[list(METRICS)].mean().reset_index()
    dup = duplicates(df)
    rng = np.random.default_rng(0)
    seed_means = dict(iter(per_seed.groupby(keys, sort=True)))
    rows = []
    for key, episodes in df.groupby(keys, sort=True):
        row = dict(zip(keys, key, strict=True))
        g = seed_means[key]
        rate, lo, hi, n_seeds = _rate(episodes, rng)
        row |= {"seeds": n_seeds, "n_seeds": n_seeds, "n_episodes": len(episodes)}
        row |= {"collision_pct": rate, "collision_pct_lo": lo, "collision_pct_hi": hi}
        if "distance" in episodes:
            by_seed = episodes.sort_values(["mix", "radius", "seed"]).groupby("train_seed")
            row["per_100km"], row["per_100km_lo"], row["per_100km_hi"] = seed_per_100km_interval(
                [g.crashed.to_numpy(float) for _, g in by_seed],
                [g.distance.to_numpy(float) for _, g in by_seed],
                rng,
            )
            row["km"] = float(episodes.distance.sum()) / 1000
        for m in ("avg_speed", "lane_changes"):
            row[m] = float(g[m].mean())
            values = g[m].to_numpy() if len(g) > 1 else episodes[m].to_numpy(dtype=float)
            if m == "lane_changes" and np.ptp(values) == 0:  # no spread: counts' own interval
                lo, hi = mean_interval(episodes[m].to_numpy(dtype=float), counts=True)
            else:
                lo, hi = mean_interval(values)
            row[f"{m}_lo"], row[f"{m}_hi"] = max(lo, 0.0), hi
        if "ending" in episodes:
            share = episodes.ending.value_counts(normalize=True)
            row |= {f"{k}_pct": 100.0 * float(share.get(k, 0.0)) for k in CRASH_KINDS}
        replayed = str(row.get("traffic", "")).startswith(REPLAY)
        row["duplicate_of"] = np.nan if replayed else dup.get((row["density"], row["mix"]), np.nan)
        rows.append(row)
    return pd.DataFrame(rows), per_seed
