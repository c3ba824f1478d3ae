"""Schemas of training, evaluation, the main job, sweeps and the recipe."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from omegaconf import DictConfig

from bgap.agents.config import AgentConfig
from bgap.analysis.stats import RULE_FLOOR, STOCK_MARGIN
from bgap.common import config as plumbing
from bgap.common.errors import check, check_apart
from bgap.common.vocab import (
    BASELINES,
    CHECKPOINT_RULES,
    CHECKPOINTS,
    LEARNERS,
    MIX_SAMPLING,
    POLICIES,
    SPEED_FLOOR,
)
from bgap.runner.cluster import ClusterConfig
from bgap.sim.config import SCHEMAS as SIM_SCHEMAS
from bgap.sim.config import BaseConfig
from bgap.traffic.replay import MODES, load_replay
from bgap.traffic.scenario import env_preset


@dataclass
class ProfileConfig:
    """Compute budget (config group ``profile``: ``quick`` or ``paper``)."""

    name: str = "quick"
    train_steps: int = 30_000
    """Environment steps of training (the cap when ``train_episodes`` is set)."""
    train_episodes: Optional[int] = None
    """Stop after this many training episodes (the paper: 3000)."""
    n_envs: int = 2
    """Parallel training environments (subprocesses when > 1)."""
    exploration_decay_steps: Optional[float] = None
    """Overrides ``agent.exploration_decay_steps`` (short budgets need a shorter decay)."""
    eval_every_episodes: int = 0
    """Periodic greedy evaluation during training every this many episodes; 0: off."""
    eval_during_training: int = 20
    """Episodes of each periodic evaluation (the paper: 20 every 50)."""
    eval_episodes: int = 100
    """Episodes per grid cell of the final evaluation."""
    checkpoint_every: int = 1000
    """Steps between checkpoints (model and replay buffer)."""
    checkpoint_rule: str = "return"
    """Which validation a training keeps as ``best_model.zip``: ``return``, the highest mean
    validation return (SB3's ``EvalCallback``), validated on ``val_seed + k``; ``per_km``, the
    fewest collisions per 100 km among validations at least ``SPEED_FLOOR`` x the slower of
    the idle and rule-based egos' speeds on the same episodes, within ``FLOOR_BAND`` below it
    (ties: the faster, then the later; :func:`bgap.agents.monitor.rank`),
    validated on :data:`CHECKPOINT_SEED` + k, with every validation's parameters kept in
    ``validations/``."""

    def __post_init__(self) -> None:
        check(self.train_steps >= 1, "profile.train_steps", self.train_steps, "must be >= 1")
        check(
            self.train_episodes is None or self.train_episodes >= 1,
            "profile.train_episodes",
            self.train_episodes,
            "must be >= 1 or null",
        )
        check(self.n_envs >= 1, "profile.n_envs", self.n_envs, "must be >= 1")
        check(self.eval_episodes >= 1, "profile.eval_episodes", self.eval_episodes, ">= 1")
        check(
            self.eval_every_episodes >= 0,
            "profile.eval_every_episodes",
            self.eval_every_episodes,
            "must be >= 0 (0: no validation during training)",
        )
        check(
            self.eval_during_training >= 1,
            "profile.eval_during_training",
            self.eval_during_training,
            "must be >= 1; profile.eval_every_episodes=0 turns validation off",
        )
        check(self.checkpoint_every >= 1, "profile.checkpoint_every", self.checkpoint_every, ">= 1")
        check(
            self.checkpoint_rule in CHECKPOINT_RULES,
            "profile.checkpoint_rule",
            self.checkpoint_rule,
            f"use one of {list(CHECKPOINT_RULES)}",
        )


CHECKPOINT_SEED = 60_000
"""The validation block of the ``per_km`` checkpoint rule (episode k: seed 60000 + k), apart
from the sweeps' and the selection's (``val_seed``, 50000 + k), the tuned rule's (70000 + k)
and the tests' (``eval_seed``, 100000 + k), so no other choice is made on these episodes."""


def first_validation_seed(checkpoint_rule: str, val_seed: int) -> int:
    """The first seed of a training's validations: the ``per_km`` checkpoint rule's own
    block (:data:`CHECKPOINT_SEED`), else ``val_seed``."""
    return CHECKPOINT_SEED if checkpoint_rule == "per_km" else val_seed


@dataclass
class GridConfig:
    """Evaluation grid (config group ``grid``). An empty list means the run's own value."""

    name: str = "single"
    mixes: list[float] = field(default_factory=list)
    densities: list[str] = field(default_factory=list)
    """Names of ``env`` presets (``sparse``, ``dense``)."""
    radii: list[float] = field(default_factory=list)
    simulated: bool = True
    """Whether the grid holds the simulated cells (mixes x densities x radii); ``false``:
    only its replays."""
    replays: list[str] = field(default_factory=list)
    """Cells of replayed traffic (:mod:`bgap.traffic.replay`): trajectory tables,
    each ``DENSITY:PATH`` (the ``env`` preset the cell runs: its observation, so the models of
    that density play it, and its duration) or ``PATH`` (the run's own density)."""
    modes: list[str] = field(default_factory=lambda: ["log"])
    """``traffic.mode`` of the replay cells: ``log``, ``reactive``, or both."""
    overtakes: bool = False
    """Also count each episode's overtakes (an ``overtakes`` column): the vehicles the ego
    passed (:mod:`bgap.sim.passing`)."""

    def __post_init__(self) -> None:
        self.mixes = [m + 0.0 for m in self.mixes]  # -0.0 is 0.0
        self.radii = [r + 0.0 for r in self.radii]
        for m in self.mixes:
            check(0 <= m <= 1, "grid.mixes", self.mixes, "every mix must lie in [0, 1]")
        for r in self.radii:
            check(r > 0, "grid.radii", self.radii, "every radius must be positive")
        for m in self.modes:
            check(m in MODES, "grid.modes", self.modes, f"each one of {MODES}")
        check(bool(self.modes), "grid.modes", self.modes, f"give at least one of {MODES}")
        check(
            self.simulated or bool(self.replays),
            "grid.replays",
            self.replays,
            "a grid without simulated cells (grid.simulated=false) needs replays: "
            "grid.replays=[dense:PATH,...]",
        )
        for density, table in self.replay_tables():
            if density is not None:
                env_preset(density)  # one line naming the presets when there is none
            check(Path(table).is_file(), "grid.replays", table, "no such trajectory table")

    def replay_tables(self) -> list[tuple[Optional[str], str]]:
        """``grid.replays`` as (density or None for the run's own, table path)."""
        out = []
        for entry in self.replays:
            density, sep, table = str(entry).partition(":")
            # a path with a colon of its own (C:/...) keeps it: a density is a preset name
            named = bool(sep) and "/" not in density and "\\" not in density and len(density) > 1
            out.append((density, table) if named else (None, str(entry)))
        return out


@dataclass
class ExperimentConfig(BaseConfig):
    """Training, evaluation and the main job (``bgap.train``, ``bgap.evaluate``, ``bgap.run``)."""

    agent: AgentConfig = field(default_factory=AgentConfig)
    profile: ProfileConfig = field(default_factory=ProfileConfig)
    grid: GridConfig = field(default_factory=GridConfig)
    backend: str = "vector"
    """Training and evaluation run on the vectorised backend by default (the same traffic,
    step for step, ~1000x faster on dense); ``backend=highway`` runs highway-env itself."""
    policy: str = "behavior_rich"
    """``behavior_rich`` trains in the enriched traffic; ``default`` in stock traffic."""
    mix_sampling: str = "fixed"
    """Training mix: ``fixed`` (= ``mix``), ``uniform`` in [0, 1] or ``paper`` (one of the
    paper's seven mixes) drawn anew each episode."""
    root: str = "outputs"
    """Every run folder and result lives under this output root."""
    run_dir: Optional[str] = None
    """Training run folder; default ``<root>/runs/<name derived from the config>``. With
    ``seeds=[...]`` or ``policies=[...]`` (the batched learner), the folder holding one run
    folder per training, ``<density>-<policy>-s<seed>``."""
    resume: bool = False
    """Continue an interrupted training run from its last checkpoint."""
    models: list[str] = field(default_factory=list)
    """``bgap.evaluate``: run folders (or model.zip files) to evaluate."""
    baselines: list[str] = field(default_factory=lambda: ["idle", "random", "rule"])
    """Scripted policies evaluated beside the models: idle, random, left, rule (IDM + MOBIL)."""
    eval_seed: int = 100_000
    """Test episodes: episode k of every cell uses seed eval_seed + k, for every policy."""
    seeds: list[int] = field(default_factory=list)
    """``bgap.run``: training seeds, each trained and evaluated, with intervals across them
    (training seeds are the independent units); empty: ``[seed]``."""
    val_seed: int = 50_000
    """Validation episodes (training's periodic evaluations, sweeps' scores) use seed
    val_seed + k: choices are made on these, never on the test episodes (ours)."""
    cluster: ClusterConfig = field(default_factory=ClusterConfig)
    """Where the work runs: here (the default) or on a Ray cluster (``cluster.address``,
    :mod:`bgap.runner.cluster`); never what it computes."""
    workers: int = 2
    """Worker processes: evaluation's, and ``bgap.train``'s and ``bgap.run``'s for several
    SB3 trainings side by side (one training per process)."""
    learner: str = "sb3"
    """``sb3``: Stable-Baselines3's DQN, one training per process (the reference);
    ``batched``: every training of the command in one batched learner
    (:mod:`bgap.agents.batched`; ``bgap.train seeds=[0,1,2]``), on CUDA when torch sees a
    GPU."""
    threads: int = 0
    """torch threads of the batched learner; 0: one per core. (The SB3 learner uses 1.)"""
    policies: list[str] = field(default_factory=list)
    """``bgap.train``: train these policy families (each with every seed); empty:
    ``[policy]``."""
    out: Optional[str] = None
    """``bgap.evaluate`` / ``bgap.run`` results folder; default under ``<root>/results``."""
    checkpoint: str = "best"
    """Which parameters of a training are evaluated: ``best``, the checkpoint its periodic
    validations chose (``best_model.zip``: the highest mean validation return, as SB3's
    ``EvalCallback``; ours, the paper keeps none), or ``last``, the final parameters
    (``model.zip``). A run without validations has only the last."""

    def __post_init__(self) -> None:
        super().__post_init__()
        check(self.policy in POLICIES, "policy", self.policy, f"use one of {POLICIES}")
        check(
            self.agent.converged,
            "agent",
            self.agent.name,
            "is from a sweep stopped before its trials were done (converged: false in the "
            "preset); rerun the sweep to finish it, or use it knowingly with "
            "agent.converged=true",
        )
        check(
            self.checkpoint in CHECKPOINTS,
            "checkpoint",
            self.checkpoint,
            f"use one of {CHECKPOINTS}",
        )
        check(
            self.mix_sampling in MIX_SAMPLING,
            "mix_sampling",
            self.mix_sampling,
            f"use one of {MIX_SAMPLING}",
        )
        for b in self.baselines:
            check(b in BASELINES, "baselines", self.baselines, f"each one of {BASELINES}")
        check(self.workers >= 1, "workers", self.workers, "must be >= 1")
        check(self.learner in LEARNERS, "learner", self.learner, f"use one of {LEARNERS}")
        check(
            self.learner == "sb3" or self.agent.algo == "dqn",
            "learner",
            self.learner,
            f"trains DQN only; agent.algo={self.agent.algo} trains with learner=sb3",
        )
        check(
            self.learner == "sb3" or self.agent.extractor == "flatten",
            "learner",
            self.learner,
            "stacks plain MLPs only; agent.extractor=attention trains with learner=sb3",
        )
        check(self.threads >= 0, "threads", self.threads, "must be >= 0 (0: one per core)")
        for p in self.policies:
            check(p in POLICIES, "policies", self.policies, f"each one of {POLICIES}")
        check(
            all(s >= 0 for s in self.seeds) and len(set(self.seeds)) == len(self.seeds),
            "seeds",
            self.seeds,
            "must be distinct non-negative training seeds, e.g. seeds=[0,1,2]",
        )
        apart = f"eval_seed={self.eval_seed} (validation and test episodes never share seeds)"
        check_apart("val_seed", self.val_seed, self.eval_seed, apart)
        if self.profile.checkpoint_rule == "per_km":
            apart = f"{CHECKPOINT_SEED} (the per_km checkpoint rule's validation episodes)"
            for key, seed in (("val_seed", self.val_seed), ("eval_seed", self.eval_seed)):
                check_apart(key, seed, CHECKPOINT_SEED, apart)

    def check_inputs(self) -> None:
        """:meth:`BaseConfig.check_inputs`, and the grid's replayed tables."""
        super().check_inputs()
        for density, table in self.grid.replay_tables():
            env = env_preset(density) if density else self.env
            load_replay(table, env.simulation_frequency, self.traffic.min_duration)


@dataclass
class SweepConfig(ExperimentConfig):
    """``python -m bgap.sweep``: the experiment every trial starts from, plus the search."""

    sweep: str = "reward"
    """Search space ``sweeps/<sweep>.yaml`` (``reward`` or ``dqn``)."""
    mode: str = "multi"
    """``multi``: minimise collisions and maximise speed (Pareto front); ``single``: the
    scalarisation collision % - speed_weight * speed, with pruning; ``constrained``:
    minimise collisions among policies at least ``speed_floor`` x idle's speed, with pruning;
    ``rule``: each trial trains both policies (behaviour-rich and default) and scores them
    against the rule-based ego (:func:`bgap.analysis.stats.rule_objective`), with pruning."""
    trials: int = 20
    """Finished trials wanted in the study, counted across workers and reruns."""
    speed_weight: float = 2.0
    """Collision percentage points one m/s of average speed is worth (single mode, and the
    choice of the written preset on a Pareto front)."""
    speed_floor: float = SPEED_FLOOR
    """Constrained mode: the fraction of idle's mean speed (same validation episodes) a
    policy must reach to count as feasible."""
    prune_every: int = 0
    """Single mode: steps between intermediate evaluations (0: a quarter of the budget)."""
    sweep_eval_episodes: int = 30
    """Greedy evaluation episodes per trial (fixed seeds, the same for every trial)."""
    storage: Optional[str] = None
    """Optuna URL (sqlite:///..., postgresql://..., journal:PATH); default SQLite under root."""
    study: Optional[str] = None
    """Study name; default ``<sweep>-<mode>-<env>``."""
    trial_log: Optional[str] = None
    """A trial log (``bgap.pipeline trials save``) to continue from when ``storage`` does not
    hold the study yet: a new machine resumes a search from what git kept."""
    write_preset: bool = True
    preset: Optional[str] = None
    """Where the chosen preset goes; default ``<root>/presets/<group>/user_tuned.yaml``
    (then ``reward=user_tuned``)."""
    overrides: list[str] = field(default_factory=list)
    """Extra overrides every trial composes with (e.g. ["profile.train_steps=5000"])."""
    rule_floor: float = RULE_FLOOR
    """Mode ``rule``: the fraction of the rule-based ego's mean speed each policy must keep."""
    stock_margin: float = STOCK_MARGIN
    """Mode ``rule``: collision percentage points the default policy may have beyond the
    rule-based ego's in stock traffic."""

    def __post_init__(self) -> None:
        super().__post_init__()
        modes = ("multi", "single", "constrained", "rule")
        check(self.mode in modes, "mode", self.mode, f"use one of {modes}")
        check(0 < self.speed_floor <= 2, "speed_floor", self.speed_floor, "a fraction in (0, 2]")
        check(0 < self.rule_floor <= 2, "rule_floor", self.rule_floor, "a fraction in (0, 2]")
        check(self.stock_margin >= 0, "stock_margin", self.stock_margin, "must be >= 0")
        check(self.trials >= 1, "trials", self.trials, "must be >= 1")
        check(
            self.sweep_eval_episodes >= 1,
            "sweep_eval_episodes",
            self.sweep_eval_episodes,
            "must be >= 1",
        )
        check(
            self.prune_every >= 0,
            "prune_every",
            self.prune_every,
            "must be >= 0 (0: a quarter of the training budget)",
        )
        check(
            self.mode != "rule" or self.policy == "behavior_rich",
            "policy",
            self.policy,
            "mode=rule trains both policies of each trial: leave policy=behavior_rich",
        )
        shared = self.storage and not self.storage.startswith("sqlite")
        check(
            self.cluster.address in ("", "local") or bool(shared),
            "storage",
            self.storage,
            f"cluster.address={self.cluster.address} runs the sweep's workers on several nodes, "
            "which cannot share a SQLite file: give storage=postgresql://... (or journal:PATH "
            "on a file system every node sees)",
        )


@dataclass
class RecipeConfig(SweepConfig):
    """``python -m bgap.recipe``: the recipe sweep, then its best trials rerun on more seeds."""

    sweep: str = "recipe"
    mode: str = "constrained"
    candidates: int = 4
    """Best sweep trials (by the constrained objective) rerun with ``check_seeds``."""
    check_seeds: list[int] = field(default_factory=lambda: [0, 1, 2])
    """Training seeds of each candidate's rerun."""
    check_episodes: int = 100
    """Validation episodes per candidate and seed (the same for the idle and rule egos)."""
    preset_dir: Optional[str] = None
    """Where the chosen ``reward/<preset_name>.yaml`` and ``agent/<preset_name>.yaml`` go;
    default ``<root>/presets`` (the pipeline's stage: ``results/presets``)."""
    preset_name: str = "user_recipe"
    """Name of the written presets (``reward=user_recipe agent=user_recipe``); the pipeline's
    stage writes the pipeline's ``recipe``, which a user's preset must not shadow."""
    stock_check: bool = False
    """Also train each candidate's default policy (highway-env's stock traffic) with every
    check seed, and rank the candidates whose default policy misses the stock rule (fewer
    than ``stock_max_collision_pct`` collisions at ``speed_floor`` x idle's speed, on stock
    validation episodes) after those that meet it: the recipe is shared by both policies."""
    stock_max_collision_pct: float = 50.0
    """The stock rule's collision bound (under half of the episodes)."""
    levers: list[str] = field(default_factory=list)
    """Mode ``rule``: settings of the chosen recipe switched one lever at a time (for example
    ``agent.extractor=flatten``, ``agent.observation=[]``, or several settings at once:
    ``'agent=recipe reward=recipe'``, a group bringing its preset back whole), each trained
    with every check seed and scored as the check is: ``levers.md`` says how far each moves
    the objective."""

    def __post_init__(self) -> None:
        super().__post_init__()
        check(self.mode != "multi", "mode", self.mode, "a recipe needs one objective")
        check(
            0 < self.stock_max_collision_pct <= 100,
            "stock_max_collision_pct",
            self.stock_max_collision_pct,
            "a percentage in (0, 100]",
        )
        check(self.candidates >= 1, "candidates", self.candidates, "must be >= 1")
        check(len(self.check_seeds) >= 2, "check_seeds", self.check_seeds, ">= 2 seeds")
        check(self.check_episodes >= 10, "check_episodes", self.check_episodes, ">= 10")
        for lever in self.levers:
            parts = lever.split()
            keys = [part.split("=", 1)[0] for part in parts]
            check(
                bool(keys) and all("=" in part and part[0] != "=" for part in parts),
                "levers",
                lever,
                "each lever is KEY=VALUE, several separated by spaces, e.g. agent.extractor="
                "flatten or 'agent=recipe reward=recipe'",
            )
            check(
                all(key.split(".")[0] in ("agent", "reward") for key in keys),
                "levers",
                lever,
                "a lever switches the recipe's settings: keys under agent or reward",
            )
            check(len(set(keys)) == len(keys), "levers", lever, "each key once")
        check(not self.levers or self.mode == "rule", "levers", self.levers, "need mode=rule")


SCHEMAS = (
    *SIM_SCHEMAS,
    ("agent", "base_agent", AgentConfig),
    ("profile", "base_profile", ProfileConfig),
    ("grid", "base_grid", GridConfig),
    (None, "base_experiment", ExperimentConfig),
    (None, "base_sweep", SweepConfig),
    (None, "base_recipe", RecipeConfig),
)
"""Hydra ConfigStore entries of ``train``, ``evaluate``, ``run``, ``sweep`` and ``recipe``."""


def compose(config_name: str, overrides: list[str] | None = None) -> DictConfig:
    """The packaged ``<config_name>.yaml`` of these commands with command-line style
    overrides, outside a Hydra app (Optuna trials, scripts, tests)."""
    return plumbing.compose(config_name, overrides, SCHEMAS)
