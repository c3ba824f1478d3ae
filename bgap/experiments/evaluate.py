"""Evaluation: policies x grid cells x seeded episodes -> collision %, speed, lane changes.

    python -m bgap.evaluate models=[outputs/runs/RUN_A,outputs/runs/RUN_B] grid=paper

Every policy plays the same episodes: episode k of a cell is seeded ``eval_seed + k``, so
differences between policies are paired. Per episode we record whether it ended in a crash,
the ego's average speed (sampled each policy step) and its lane changes (actions that moved
its target lane, see ``info["lane_change"]``). Per cell: collision frequency (% of episodes
that end in a crash, 95% Wilson interval), mean speed and mean lane changes (95% t interval),
and the split of the crashes by kind (``ending``: rear end, rear-ended, lane change; see
:class:`bgap.sim.rollout.EpisodeStats`).
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Iterable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from omegaconf import DictConfig, OmegaConf
from tqdm import tqdm

from bgap.agents import zoo
from bgap.agents.policies import ALGORITHMS, as_policy, load_model, model_path, rollout
from bgap.analysis.episodes import EPISODES, MODELS
from bgap.analysis.stats import per_100km, spread_interval, wilson_interval
from bgap.cmetric import boundary as classes
from bgap.common.config import app, load
from bgap.common.errors import ConfigError
from bgap.common.plotting import pyplot
from bgap.common.presets import CONF_DIR
from bgap.common.runs import (
    CONFIG,
    MODEL,
    VOLATILE,
    as_before,
    digest,
    model_file,
    run_folders,
    save_run_metadata,
    write_atomic,
)
from bgap.common.scores import episode_distance
from bgap.common.tables import read_table
from bgap.common.vocab import BASELINES, CRASH_KINDS
from bgap.experiments.config import SCHEMAS, ExperimentConfig
from bgap.runner.cluster import connected
from bgap.runner.jobs import run_jobs
from bgap.runner.locks import exclusive
from bgap.traffic.replay import load_replay
from bgap.traffic.scenario import env_config, env_preset


@dataclass(frozen=True)
class Cell:
    """One evaluation cell: simulated traffic at a mix, or a replayed table (``table``,
    ``mode``; its ``mix`` is the table's aggressive share)."""

    mix: float
    density: str
    radius: float
    table: str = ""
    mode: str = ""

    @property
    def replay(self) -> str:
        """The replay cell's name in the episode tables, ``<table>/<mode>`` (a table named
        ``trajectories.*`` by its folder's name); "" for simulated traffic."""
        if not self.table:
            return ""
        path = Path(self.table)
        name = path.parent.name if path.stem == "trajectories" else path.stem
        return f"{name}/{self.mode}"


def grid_cells(cfg: ExperimentConfig) -> list[Cell]:
    """The cells of ``cfg.grid``; empty axes take the run's own mix, density and radius.
    Replay cells (``grid.replays``) follow the simulated ones: each table x mode x radius."""
    g = cfg.grid
    cells = [
        Cell(float(m), str(d), float(r))
        for d in (g.densities or [cfg.env.name])
        for m in (g.mixes or [cfg.mix])
        for r in (g.radii or [cfg.radius])
    ] if g.simulated else []  # fmt: skip
    for density, table in g.replay_tables():
        env = env_preset(density) if density else cfg.env
        share = replay_mix(table, env.simulation_frequency, cfg.traffic.min_duration)
        cells += [Cell(share, env.name, float(r), table, mode)
                  for mode in g.modes for r in (g.radii or [cfg.radius])]  # fmt: skip
    return cells


def replay_mix(table: str, simulation_frequency: float, min_duration: float) -> float:
    """A replayed table's aggressive share, so that its cells read beside the simulated
    mixes: from its labels (:meth:`bgap.traffic.replay.Replay.aggressive_share`), or without
    them, the share of its vehicles whose CMetric aggressiveness lies above the class
    boundary the pipeline fixed on bgap's labelled tables (:mod:`bgap.cmetric.boundary`)."""
    share = load_replay(table, simulation_frequency, min_duration).aggressive_share()
    return classes.share(table, classes.packaged()) if share is None else share


def cell_env_config(cfg: ExperimentConfig, cell: Cell) -> dict[str, Any]:
    """highway-env config of one cell: the run's reward and behaviours, the cell's traffic."""
    env = cfg.env if cell.density == cfg.env.name else env_preset(cell.density)
    traffic = cfg.traffic
    if cell.table:
        traffic = replace(traffic, name="replay", source="replay", table=cell.table,
                          mode=cell.mode)  # fmt: skip
    return env_config(replace(cfg, env=env, mix=cell.mix, radius=cell.radius, traffic=traffic))


def _evaluate_chunk(
    name: str, spec: Any, cell: Cell, env_cfg: dict, seeds: list[int], backend: str = "highway"
) -> list:
    policy, rows = as_policy(spec, env_cfg)
    if rows is not None and rows != env_cfg["observation"]["vehicles_count"]:
        return []  # a model sees a fixed number of vehicles: only its own density
    key = {"policy": name, "mix": cell.mix, "density": cell.density, "radius": cell.radius}
    if cell.table:
        key["replay"] = cell.replay
    episodes = rollout(env_cfg, policy, seeds, backend).episodes
    episodes["distance"] = episode_distance(episodes, env_cfg["policy_frequency"])
    return [{**key, **row} for row in episodes.to_dict(orient="records")]


EVALUATE_FIX = (
    "evaluate it under the settings its card records (played_under), or watch or simulate it "
    "with zoo_override=true"
)
"""What a refused zoo policy's line suggests in ``bgap.evaluate`` (which has no override:
a study's table never mixes policies played under other settings than they trained for)."""


def _check_densities(
    policies: dict[str, Any], cells: list[Cell], cfg: ExperimentConfig
) -> dict[str, int | None]:
    """A model sees a fixed number of vehicles: each must have a cell of its density.
    Returns the observation rows each policy needs (None: any)."""
    rows = {c.density: cell_env_config(cfg, c)["observation"]["vehicles_count"] for c in cells}
    needed = {}
    for name, spec in policies.items():
        scripted = isinstance(spec, str) and spec in BASELINES  # any rows: none loaded here
        needs = needed[name] = None if scripted else as_policy(spec)[1]
        if needs is not None and needs not in rows.values():
            raise ConfigError(
                f"policy {name} observes {needs} vehicles (density "
                f"{_density_of(needs)}), but the grid's densities {sorted(rows)} have "
                f"{sorted(set(rows.values()))}; evaluate it at its own density (env=... or "
                "grid.densities=[...])"
            )
    return needed


def _own_density(needed: dict[str, int | None], cells: list[Cell], configs: list[dict]) -> set:
    """The (policy, cell index) pairs a model cannot play (another density's cells), each
    model's skip said in one line: it plays only the cells of its own density."""
    skipped = set()
    for name, needs in needed.items():
        other = [
            k
            for k, c in enumerate(configs)
            if needs not in (None, c["observation"]["vehicles_count"])
        ]
        if other:
            skipped.update((name, k) for k in other)
            densities = sorted({cells[k].density for k in other})
            print(
                f"{name} plays only the cells of its own density ({_density_of(needs)}): "
                f"{len(other)} cells of {', '.join(densities)} skipped"
            )
    return skipped


def _shippable(spec: Any) -> Any:
    """A policy spec a cluster's node can play: a saved model as ``(file name, bytes)`` (the
    node needs no access to this machine's files), anything else as it is."""
    if isinstance(spec, (str, Path)) and str(spec) not in BASELINES:
        algo, sep, rest = str(spec).partition(":")
        named = bool(sep) and algo.lower() in ALGORITHMS  # ppo:run/model.zip
        return (f"{algo}:" if named else "", model_path(rest if named else spec).read_bytes())
    return spec


PROCESS_EPISODES = 5_000
"""Vector-backend evaluations of fewer episodes run in this process: a spawned worker takes
seconds to import torch and bgap."""

_MODELS: dict[str, Any] = {}
"""A worker process's loaded models by path (an SB3 load builds the networks again)."""


def _evaluate_job(name: str, spec: Any, *rest: Any) -> list:
    """:func:`_evaluate_chunk` wherever it runs: a saved model loaded once per process (an
    SB3 load builds the networks again: ~0.3 s, 1,200 times in the paper's grid), a model
    shipped to a cluster's node (:func:`_shippable`) written to a file of its own first."""
    if isinstance(spec, tuple):
        prefix, data = spec
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "model.zip"
            path.write_bytes(data)
            return _evaluate_chunk(name, load_model(f"{prefix}{path}"), *rest)
    if isinstance(spec, (str, Path)) and str(spec) not in BASELINES:
        if str(spec) not in _MODELS:
            _MODELS[str(spec)] = load_model(spec)
        spec = _MODELS[str(spec)]
    return _evaluate_chunk(name, spec, *rest)


def _density_of(rows: int) -> str:

    names = sorted(p.stem for p in (Path(CONF_DIR) / "env").glob("*.yaml"))
    found = [n for n in names if env_preset(n).observed_vehicles == rows]
    return found[0] if found else "unknown"


def evaluate(
    cfg: ExperimentConfig,
    policies: dict[str, str],
    cells: Iterable[Cell] | None = None,
    episodes: int | None = None,
    progress: bool = True,
    chunk: int = 5,
) -> pd.DataFrame:
    """Play ``episodes`` seeded episodes of every policy on every cell; one row per episode.

    ``policies`` maps a display name to any policy :func:`bgap.sim.rollout.as_policy` accepts: a
    baseline (idle, random, left), a model path, a loaded SB3 model or a callable from
    observations to actions (your own agent; it must be picklable when ``workers`` > 1 on
    highway-env).
    """
    cells = list(cells or grid_cells(cfg))
    episodes = episodes or cfg.profile.eval_episodes
    seeds = [cfg.eval_seed + k for k in range(episodes)]
    workers = cfg.workers
    if cfg.backend == "vector":  # one batch per cell and policy
        chunk = episodes
        named = all(isinstance(spec, (str, Path)) for spec in policies.values())
        if not named or len(cells) * len(policies) * episodes < PROCESS_EPISODES:
            workers = 1  # in-process: any policy object; no process start for a small run
    _MODELS.clear()  # models loaded by an earlier evaluation here: their files may be new
    needed = _check_densities(policies, cells, cfg)
    configs = [cell_env_config(cfg, cell) for cell in cells]
    for spec in policies.values():  # a zoo policy plays only under the settings it trained for
        if isinstance(spec, (str, Path)) and zoo.card(Path(spec)):
            for config in configs:
                zoo.check_played_under(Path(spec), config, fix=EVALUATE_FIX)
    skipped = _own_density(needed, cells, configs)
    jobs = [
        (name, spec, cell, configs[k], seeds[i : i + chunk], cfg.backend)
        for k, cell in enumerate(cells)
        for name, spec in policies.items()
        if (name, k) not in skipped  # the progress bar counts the episodes played
        for i in range(0, episodes, chunk)
    ]
    with connected(cfg.cluster):  # an unreachable cluster fails here, before any output
        rows = _play(cfg, jobs, chunk, workers, progress, policies)
    if any(c.table for c in cells):  # simulated cells beside replays: "" (never a NaN key)
        rows = [{**row, "replay": row.get("replay", "")} for row in rows]
    return pd.DataFrame(rows)


def _play(
    cfg: ExperimentConfig, jobs: list[tuple], chunk: int, workers: int, progress: bool,
    policies: dict[str, Any],
) -> list[dict]:  # fmt: skip
    """Every job of :func:`evaluate` (:func:`bgap.runner.jobs.run_jobs`: here, in worker
    processes of one thread each, or as Ray tasks). One thread: a process's kernels and its
    policies' forward passes alternate, so a process with threads leaves cores idle."""
    bar = tqdm(total=len(jobs) * chunk, unit="ep", desc="evaluate", disable=not progress)
    if cfg.cluster.enabled:  # a model travels as its file's bytes
        shipped = {name: _shippable(spec) for name, spec in policies.items()}
        jobs = [(name, shipped[name], *rest) for name, _, *rest in jobs]
    try:
        parts = run_jobs(
            _evaluate_job, jobs, workers=workers, numba_threads=1, cluster=cfg.cluster,
            done=lambda k, part: bar.update(chunk),
            kept="no episode was written; the same command plays them again",
        )  # fmt: skip
    finally:
        bar.close()
    return [row for part in parts for row in part]


STORED = {
    "avg_speed": "float32", "distance": "float32", "return": "float32", "lane_changes": "int16",
    "steps": "int16", "seed": "int64", "mix": "float64", "radius": "float64",
}  # fmt: skip
"""Stored types of the episode columns: single precision (7 digits) for the per-episode
measures keeps the study's episodes in a few MB of parquet. The commands apply it before
they summarise, so every summary, figure and claim reads the numbers that are stored
(:func:`evaluate` itself returns full precision)."""


def compact(episodes: pd.DataFrame) -> pd.DataFrame:
    """The episode table in its stored types (:data:`STORED`; reward terms ``r_*``
    single precision too)."""
    types = {c: t for c, t in STORED.items() if c in episodes}
    types |= {c: "float32" for c in episodes if c.startswith("r_")}
    return episodes.astype(types)


def summarize(episodes: pd.DataFrame) -> pd.DataFrame:
    """Per policy and cell: collision %, average speed, lane changes, each with a 95% CI."""
    rows = []
    keys = ["policy", "mix", "density", "radius", *(["replay"] if "replay" in episodes else [])]
    for key, g in episodes.groupby(keys, sort=False):
        crashes, n = int(g.crashed.sum()), len(g)
        lo, hi = wilson_interval(crashes, n)
        s_lo, s_hi = spread_interval(g.avg_speed.to_numpy())
        l_lo, l_hi = spread_interval(g.lane_changes.to_numpy(dtype=float), counts=True)
        rows.append(
            dict(zip(keys, key, strict=True))
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
                **crash_split(g),
                **exposure(g),
            }
        )
    return pd.DataFrame(rows)


def exposure(episodes: pd.DataFrame) -> dict[str, float]:
    """Kilometres driven and collisions per 100 km with their exact Poisson interval
    (:func:`bgap.analysis.stats.per_100km`); nothing for episodes recorded without the
    ego's distance."""
    if "distance" not in episodes:
        return {}
    rate, lo, hi = per_100km(episodes.crashed.to_numpy(), episodes.distance.to_numpy(float))
    return {"km": float(episodes.distance.sum()) / 1000, "per_100km": rate,
            "per_100km_lo": lo, "per_100km_hi": hi}  # fmt: skip


def crash_split(episodes: pd.DataFrame) -> dict[str, float]:
    """% of episodes ending in each kind of crash (``<kind>_pct``, :data:`CRASH_KINDS`)."""
    if "ending" not in episodes:  # episodes recorded before the endings were
        return {}
    share = episodes.ending.value_counts(normalize=True)
    return {f"{kind}_pct": 100.0 * float(share.get(kind, 0.0)) for kind in CRASH_KINDS}


def write_results(out: Path, episodes: pd.DataFrame, summary: pd.DataFrame) -> None:
    out.mkdir(parents=True, exist_ok=True)
    write_atomic(
        out / EPISODES,
        lambda tmp: episodes.to_parquet(tmp, index=False, compression="zstd", compression_level=19),
    )
    write_atomic(out / "summary.csv", lambda tmp: summary.to_csv(tmp, index=False))
    write_atomic(out / "summary.json", json.dumps(summary.to_dict(orient="records"), indent=1))


def format_table(summary: pd.DataFrame) -> str:
    """The paper's three bars as text: collision %, speed, lane changes with 95% CIs, and
    collisions per 100 km of ego travel where the episodes hold the distance."""
    split = all(f"{kind}_pct" in summary for kind in CRASH_KINDS)
    km = "per_100km" in summary
    w = max(15, *(len(str(p)) + 1 for p in summary.policy))
    replays = summary.replay.fillna("") if "replay" in summary else pd.Series("", summary.index)
    rw = max(len(x) for x in replays) + 2 if replays.any() else 0  # the replay cells' names
    lines = [
        f"{'policy':<{w}}{'traffic' if rw else '':<{rw}}{'mix':>5}{'density':>9}{'radius':>8}"
        f"{'episodes':>9}"
        f"{'collisions %':>22}"
        + (f"{'per 100 km':>22}" if km else "")
        + f"{'speed m/s':>20}{'lane changes':>20}"
        + ("   crashes %: rear-end / rear-ended / lane change / other" if split else "")
    ]
    for r, replay in zip(summary.itertuples(), replays, strict=True):
        lines.append(
            f"{r.policy:<{w}}{(replay or 'simulated') if rw else '':<{rw}}{r.mix:>5.2f}"
            f"{r.density:>9}{r.radius:>8.0f}{r.episodes:>9}"
            f"{r.collision_pct:>8.1f} [{r.collision_lo:5.1f},{r.collision_hi:5.1f}]"
            + (f"{r.per_100km:>8.1f} [{r.per_100km_lo:5.1f},{r.per_100km_hi:5.1f}]" if km else "")
            + f"{r.avg_speed:>8.2f} [{r.speed_lo:5.2f},{r.speed_hi:5.2f}]"
            f"{r.lane_changes:>8.2f} [{r.lane_changes_lo:5.2f},{r.lane_changes_hi:5.2f}]"
            + (
                "   " + " / ".join(f"{getattr(r, f'{kind}_pct'):.0f}" for kind in CRASH_KINDS)
                if split
                else ""
            )
        )
    return "\n".join(lines)


MAX_BARS = 240
"""Policies x cells beyond which :func:`plot_comparison` draws nothing (a study's 40
trainings on 42 cells would be 1,680 bars: the figures stage plots those)."""


def plot_comparison(summary: pd.DataFrame, path: Path, title: str = "") -> bool:
    """Bars per policy (one group per cell) with 95% CIs, as in the paper's figures; False
    (nothing drawn) beyond :data:`MAX_BARS` bars."""
    if len(summary) > MAX_BARS:
        return False
    plt = pyplot()

    metrics = [
        ("collision_pct", "collision_lo", "collision_hi", "collisions [% episodes]"),
        ("avg_speed", "speed_lo", "speed_hi", "ego speed [m/s]"),
        ("lane_changes", "lane_changes_lo", "lane_changes_hi", "lane changes / episode"),
    ]
    keys = ["mix", "density", "radius", *(["replay"] if "replay" in summary else [])]
    cells = [tuple(c) for c in summary[keys].drop_duplicates().itertuples(index=False)]
    policies = list(dict.fromkeys(summary.policy))
    fig, axes = plt.subplots(1, 3, figsize=(4 + 1.2 * len(cells) * len(policies) / 2, 3.8))
    width = 0.8 / len(policies)
    for ax, (col, lo, hi, label) in zip(axes, metrics, strict=True):
        for p_i, pol in enumerate(policies):
            sub = summary[summary.policy == pol].set_index(keys)
            vals = [sub.loc[c] if c in sub.index else None for c in cells]
            x = np.arange(len(cells)) + p_i * width
            y = [v[col] if v is not None else np.nan for v in vals]
            err = np.array(
                [[v[col] - v[lo], v[hi] - v[col]] if v is not None else [0, 0] for v in vals]
            ).T
            ax.bar(x, y, width, yerr=np.nan_to_num(err), capsize=2, label=pol)
        ax.set_xticks(np.arange(len(cells)) + 0.4 - width / 2)
        ax.set_xticklabels([_cell_label(*c) for c in cells], fontsize=7)
        ax.set_ylabel(label)
    axes[0].legend(fontsize=7)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    write_atomic(path, lambda p: fig.savefig(p, dpi=120))
    plt.close(fig)
    return True


def _cell_label(mix: float, density: str, radius: float, replay: str = "") -> str:
    if replay:  # a replay's mix is its table's aggressive share
        return f"{replay}\n{density}\nmix {mix:.2f}\nr {radius:g}"
    return f"{density}\nmix {mix:g}\nr {radius:g}"


def policy_specs(cfg: ExperimentConfig) -> dict[str, str]:
    """Named policies of ``bgap.evaluate``: each model (named by its run folder) and baselines.

    A run folder contributes the model ``checkpoint`` names (:func:`bgap.common.runs.model_file`);
    a folder without ``model.zip`` stands for every run folder below it (a pipeline's runs:
    one folder per arm and density, one run folder per training), each named by its path
    below that folder. A zoo name or glob (``zoo:main/sparse/*/*``) contributes its policies
    under the names the study's tables give them (their cards' ``policy``). Two models of
    one name, or a model named like a baseline, are refused: one would replace the other."""
    specs: dict[str, str] = {}

    def add(name: str, spec: str, given: str) -> None:
        if name in specs or name in cfg.baselines:
            other = specs.get(name, "the baseline")
            raise ConfigError(
                f"models={given!r} gives a policy named {name!r}, as does {other}: one would "
                "replace the other in the tables; evaluate them apart (out=...) or rename a "
                "folder"
            )
        specs[name] = spec

    for given in cfg.models:
        if zoo.is_zoo(given):
            for archive in zoo.resolve(given):
                add(zoo.policy_name(archive), str(archive), given)
            continue
        m = Path(given)
        if m.is_dir() and not (m / MODEL).exists():
            found = run_folders(m)
            if not found:
                raise FileNotFoundError(f"no {MODEL} in {m} or its subfolders")
            # named by m's name and their path below it: <arm>/<density>/<density>-<family>-
            # s<seed> for an arm's folder, runs/<arm>/<density>/... for the pipeline's runs
            for d in found:
                name = f"{m.resolve().name}/{d.relative_to(m).as_posix()}"
                add(name, str(model_file(d, cfg.checkpoint)), given)
        elif m.is_dir():
            add(m.name, str(model_file(m, cfg.checkpoint)), given)
        else:
            add(m.parent.name, str(m), given)
    specs.update({b: b for b in cfg.baselines if b in BASELINES})
    return specs


def model_records(specs: dict[str, Any]) -> pd.DataFrame:
    """Per saved model in ``specs``: the file evaluated, the checkpoint its training's
    validations chose (``best.json``: episode and validation collision %) beside its last
    validation, and the training's reward, agent and profile settings (JSON), so that the
    figures describe the trainings without their run folders. A zoo policy's come from its
    card, which holds the same records."""
    rows = []
    for name, spec in specs.items():
        if not isinstance(spec, (str, Path)) or str(spec) in BASELINES:
            continue
        card = zoo.card(Path(spec))
        if card:
            rows.append({"policy": name, **card["records"]})
            continue
        rows.append({"policy": name, **run_records(Path(spec))})
    return pd.DataFrame(rows)


def run_records(model: Path) -> dict[str, Any]:
    """:func:`model_records`' row of the model file ``model`` in its run folder."""
    run = model.parent
    row: dict[str, Any] = {"model": model.name}
    if (run / "best.json").exists() and (run / "evaluations.csv").exists():
        best = json.loads((run / "best.json").read_text())
        validations = read_table(run / "evaluations.csv")
        row |= {
            "chosen_episodes": best["episodes"],
            "chosen_collision_pct": best["collision_pct"],
            "validated_episodes": int(validations.episodes.max()),
            "last_collision_pct": float(validations.collision_pct.iloc[-1]),
        }
    if (run / CONFIG).exists():
        settings = OmegaConf.to_container(OmegaConf.load(run / CONFIG), resolve=True)
        kept = {g: settings.get(g) for g in ("reward", "agent", "profile")}
        row["settings"] = json.dumps(kept, sort_keys=True)
    return row


def default_out(cfg: ExperimentConfig) -> Path:
    """``<root>/results/evaluate-<grid>-<hash of the settings>``: evaluations of other models
    or settings never share (and so never refuse) a folder."""
    settings = as_before({k: v for k, v in asdict(cfg).items() if k not in VOLATILE})
    return Path(cfg.root) / "results" / f"evaluate-{cfg.grid.name}-{digest(settings)}"


@app("evaluate", "bgap.evaluate", SCHEMAS, "no results were written; rerun the command")
def main(dcfg: DictConfig) -> None:

    cfg: ExperimentConfig = load(dcfg)
    with connected(cfg.cluster):  # a cluster out of reach: one line before anything is written
        _main(cfg, dcfg)


def _main(cfg: ExperimentConfig, dcfg: DictConfig) -> None:
    out = Path(cfg.out or default_out(cfg))
    specs = policy_specs(cfg)  # a bad model list fails before the folder is made
    if not specs:
        raise ConfigError(
            "nothing to evaluate: models=[] and no baseline; give models=[RUN_DIR,...] (run "
            "folders, model.zip files or zoo names) or baselines=[idle,random,rule]"
        )
    with exclusive(out):  # a second evaluation into the same folder is refused
        save_run_metadata(out, dcfg)
        episodes = compact(evaluate(cfg, specs))  # what is stored is what is summarised
        summary = summarize(episodes)
        write_results(out, episodes, summary)
        models = model_records(specs)
        if len(models):
            write_atomic(out / MODELS, lambda tmp: models.to_csv(tmp, index=False))
        drawn = plot_comparison(summary, out / "comparison.png")
    if not drawn:
        print(f"comparison.png not drawn: {len(summary)} bars (at most {MAX_BARS})")
    if len(summary) <= MAX_BARS:
        print(format_table(summary))
    print(f"results in {out}")


if __name__ == "__main__":
    main()
