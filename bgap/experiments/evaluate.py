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

import tempfile
from collections.abc import Iterable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import pandas as pd

from bgap.agents import zoo
from bgap.agents.hybrid import Hybrid
from bgap.agents.policies import (
    ALGORITHMS,
    HYBRID,
    as_policy,
    hybrid_spec,
    load_model,
    model_path,
    rollout,
)
from bgap.cmetric import boundary as classes
from bgap.common.errors import ConfigError
from bgap.common.presets import CONF_DIR
from bgap.common.runs import (
    VOLATILE,
    digest,
)
from bgap.common.scores import episode_distance
from bgap.common.vocab import BASELINES
from bgap.experiments.compat import as_before
from bgap.experiments.config import ExperimentConfig
from bgap.runner.cluster import connected
from bgap.runner.jobs import run_jobs
from bgap.traffic.replay import load_replay
from bgap.traffic.scenario import env_config, env_preset
from bgap.traffic.scenes import table_name


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
        return f"{table_name(self.table)}/{self.mode}"

    @property
    def key(self) -> str:
        """The cell's name in ``inputs.json``."""
        where = f"{self.density}, mix {self.mix:g}, radius {self.radius:g}"
        return where + (f", replay {self.replay}" if self.table else "")


def grid_cells(cfg: ExperimentConfig) -> list[Cell]:
    """The cells of ``cfg.grid``; empty axes take the run's own mix, density and radius.
    Replay cells (``grid.replays``) follow the simulated ones: each table x mode x radius."""
    g = cfg.grid
    cells = (
        [
            Cell(float(m), str(d), float(r))
            for d in (g.densities or [cfg.env.name])
            for m in (g.mixes or [cfg.mix])
            for r in (g.radii or [cfg.radius])
        ]
        if g.simulated
        else []
    )
    for density, table in g.replay_tables():
        env = env_preset(density) if density else cfg.env
        share = replay_mix(table, env.simulation_frequency, cfg.traffic.min_duration)
        cells += [
            Cell(share, env.name, float(r), table, mode)
            for mode in g.modes
            for r in (g.radii or [cfg.radius])
        ]
    return cells


def replay_mix(table: str, simulation_frequency: float, min_duration: float) -> float:
    """A replayed table's aggressive share, so that its cells read beside the simulated
    mixes: from its labels (:meth:`bgap.traffic.replay.Replay.aggressive_share`), or without
    them, the share of its vehicles whose CMetric aggressiveness lies above the class
    boundary the pipeline fixed on bgap's labelled tables (:mod:`bgap.cmetric.boundary`)."""
    share = load_replay(table, simulation_frequency, min_duration).aggressive_share()
    return classes.share(table, classes.packaged()) if share is None else share


def cell_env_config(cfg: ExperimentConfig, cell: Cell) -> dict[str, Any]:
    """highway-env config of one cell: the run's reward and behaviours, the cell's traffic
    (a run trained on the mixture is tested in bgap's drivers and on the replayed tables'
    held-out scenes, every policy observing the rows it trained with)."""
    env = cfg.env if cell.density == cfg.env.name else env_preset(cell.density)
    traffic = cfg.traffic
    held_out = traffic.source == "mixture"  # a mixture's learner: one traffic at a time
    if held_out:  # bgap's drivers in the simulated cells, every one observed as it learnt
        traffic = replace(traffic, name="simulated", source="simulated", mixture=None)
        env = replace(env, observed_vehicles=cfg.env.observed_vehicles)
    if cell.table:  # of a mixture's learner, only the scenes it never trained on
        scenes = "test" if held_out else traffic.scenes
        traffic = replace(
            traffic, name="replay", source="replay", table=cell.table, mode=cell.mode, scenes=scenes
        )
    return env_config(replace(cfg, env=env, mix=cell.mix, radius=cell.radius, traffic=traffic))


def _evaluate_chunk(
    name: str,
    spec: Any,
    cell: Cell,
    env_cfg: dict,
    seeds: list[int],
    backend: str = "highway",
    overtakes: bool = False,
    threshold: float | None = None,
) -> list:
    """One policy's episodes on one cell; ``threshold``: played as a hybrid with the
    rule-based ego's fallback (:mod:`bgap.agents.hybrid`), its share of decisions in a
    ``fallback_share`` column."""
    policy, rows = as_policy(spec, env_cfg)
    if rows is not None and rows != env_cfg["observation"]["vehicles_count"]:
        return []  # a model sees a fixed number of vehicles: only its own density
    if threshold is not None:
        policy = Hybrid(policy, env_cfg, threshold)
    key = {"policy": name, "mix": cell.mix, "density": cell.density, "radius": cell.radius}
    if cell.table:
        key["replay"] = cell.replay
    episodes = rollout(env_cfg, policy, seeds, backend, overtakes=overtakes).episodes
    episodes["distance"] = episode_distance(episodes, env_cfg["policy_frequency"])
    if threshold is not None:
        episodes["fallback_share"] = policy.share
    return [{**key, **row} for row in episodes.to_dict(orient="records")]


def learned_part(spec: Any) -> tuple[float | None, Any]:
    """(the fallback's threshold, the learned policy's spec) of a hybrid's spec
    (``hybrid:SPEC``), (None, ``spec``) of any other."""
    hybrid = hybrid_spec(str(spec)) if isinstance(spec, (str, Path)) else None
    return hybrid if hybrid is not None else (None, spec)


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
        spec = learned_part(spec)[1]  # a hybrid observes what its learned policy does
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
    node needs no access to this machine's files), a hybrid as ``(HYBRID, threshold, its
    learned part shippable)``, anything else as it is."""
    threshold, learned = learned_part(spec)
    if threshold is not None:
        return (HYBRID, threshold, _shippable(learned))
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


def _evaluate_job(name: str, spec: Any, *rest: Any, threshold: float | None = None) -> list:
    """:func:`_evaluate_chunk` wherever it runs: a saved model loaded once per process (an
    SB3 load builds the networks again: ~0.3 s, 1,200 times in the paper's grid), a model
    shipped to a cluster's node (:func:`_shippable`) written to a file of its own first; a
    hybrid's learned part loaded so, the hybrid made around it (``threshold``)."""
    if isinstance(spec, tuple) and spec[0] == HYBRID:
        return _evaluate_job(name, spec[2], *rest, threshold=spec[1])
    if isinstance(spec, tuple):
        prefix, data = spec
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "model.zip"
            path.write_bytes(data)
            return _evaluate_chunk(name, load_model(f"{prefix}{path}"), *rest, threshold)
    given, spec = learned_part(spec)
    threshold = given if given is not None else threshold
    if isinstance(spec, (str, Path)) and str(spec) not in BASELINES:
        if str(spec) not in _MODELS:
            _MODELS[str(spec)] = load_model(spec)
        spec = _MODELS[str(spec)]
    return _evaluate_chunk(name, spec, *rest, threshold)


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
    seeds, configs = plan(cfg, cells, episodes)
    return play_plan(cfg, policies, cells, seeds, configs, progress, chunk)


def plan(
    cfg: ExperimentConfig, cells: list[Cell], episodes: int | None = None
) -> tuple[list[int], list[dict[str, Any]]]:
    """What an evaluation plays: the episode seeds (``episodes``, default the profile's, from
    ``cfg.eval_seed``) and each cell's environment config, in ``cells``' order."""
    episodes = episodes or cfg.profile.eval_episodes
    return [cfg.eval_seed + k for k in range(episodes)], [cell_env_config(cfg, c) for c in cells]


def play_plan(
    cfg: ExperimentConfig,
    policies: dict[str, str],
    cells: list[Cell],
    seeds: list[int],
    configs: list[dict[str, Any]],
    progress: bool = True,
    chunk: int = 5,
) -> pd.DataFrame:
    """:func:`evaluate` on the seeds and cell configs :func:`plan` gave."""
    episodes = len(seeds)
    workers = cfg.workers
    if cfg.backend == "vector":  # one batch per cell and policy
        chunk = episodes
        named = all(isinstance(spec, (str, Path)) for spec in policies.values())
        if not named or len(cells) * len(policies) * episodes < PROCESS_EPISODES:
            workers = 1  # in-process: any policy object; no process start for a small run
    _MODELS.clear()  # models loaded by an earlier evaluation here: their files may be new
    needed = _check_densities(policies, cells, cfg)
    for spec in policies.values():  # a zoo policy plays only under the settings it trained for
        spec = learned_part(spec)[1]
        if isinstance(spec, (str, Path)) and zoo.card(Path(spec)):
            for config in configs:
                zoo.check_played_under(Path(spec), config, fix=EVALUATE_FIX)
    skipped = _own_density(needed, cells, configs)
    jobs = [
        (name, spec, cell, configs[k], seeds[i : i + chunk], cfg.backend, cfg.grid.overtakes)
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
    cfg: ExperimentConfig,
    jobs: list[tuple],
    chunk: int,
    workers: int,
    progress: bool,
    policies: dict[str, Any],
) -> list[dict]:
    """Every job of :func:`evaluate` (:func:`bgap.runner.jobs.run_jobs`: here, in worker
    processes of one thread each, or as Ray tasks). One thread: a process's kernels and its
    policies' forward passes alternate, so a process with threads leaves cores idle."""
    parts = run_jobs(
        _evaluate_job,
        jobs,
        workers=workers,
        numba_threads=1,
        cluster=cfg.cluster,
        for_cluster=lambda jobs: _shipped(jobs, policies),
        kept="no episode was written; the same command plays them again",
        bar=("evaluate", "ep", chunk) if progress else None,
    )
    return [row for part in parts for row in part]


def _shipped(jobs: list[tuple], policies: dict[str, Any]) -> list[tuple]:
    """The jobs as Ray tasks take them: a model travels as its file's bytes."""
    shipped = {name: _shippable(spec) for name, spec in policies.items()}
    return [(name, shipped[name], *rest) for name, _, *rest in jobs]


def default_out(cfg: ExperimentConfig) -> Path:
    """``<root>/results/evaluate-<grid>-<hash of the settings>``: evaluations of other models
    or settings never share (and so never refuse) a folder."""
    settings = as_before({k: v for k, v in asdict(cfg).items() if k not in VOLATILE})
    return Path(cfg.root) / "results" / f"evaluate-{cfg.grid.name}-{digest(settings)}"
