"""Training's bookkeeping: episode statistics, the episode budget, periodic evaluation and
checkpoints that resume a run exactly.

:class:`TrainingMonitor` knows no learning algorithm: a learner reports each vector step
(:meth:`~TrainingMonitor.on_step`) and hands it functions that save itself. :class:`SB3Monitor`
is the adapter for Stable-Baselines3's learners, as a callback.

Why not SB3's own callbacks: ``StopTrainingOnMaxEpisodes`` counts ``max_episodes`` per
environment and restarts its count on resume, while the paper's budget is episodes in total;
``EvalCallback`` evaluates every N steps with ``evaluate_policy``, which neither seeds the
episodes (every policy must meet the same traffic) nor reports collisions; and
``CheckpointCallback(save_replay_buffer=True)`` keeps one model and one replay buffer per
checkpoint (hundreds of MB for a dense paper-scale run) and not the environments' or the
random streams' state, which an exact resume needs.
"""

from __future__ import annotations

import json
import os
import pickle
import shutil
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from stable_baselines3.common.callbacks import BaseCallback

from bgap.agents.policies import rollout
from bgap.common.plotting import pyplot
from bgap.common.runs import BEST_MODEL, CHECKPOINT_STATE, write_atomic
from bgap.common.scores import collisions_per_100km, constrained_score, episode_distance
from bgap.common.vocab import FLOOR_BAND, SPEED_FLOOR
from bgap.runner.interrupt import CtrlC
from bgap.sim.rollout import EpisodeStats

INFO_KEYS = ("ego_speed", "lane_change", "crashed", "contact_dx")


def stack_infos(infos: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """SB3's list of per-env info dicts as the vector info (a dict of arrays) both simulators
    return, for :class:`~bgap.sim.rollout.EpisodeStats`."""
    stacked: dict[str, Any] = {
        k: np.array([info[k] for info in infos]) for k in INFO_KEYS if k in infos[0]
    }
    if all("rewards" in info for info in infos):
        terms = infos[0]["rewards"].keys()
        stacked["rewards"] = {t: np.array([info["rewards"][t] for info in infos]) for t in terms}
    return stacked


def _checkpoint_folders(run_dir: Path) -> tuple[Path, Path, Path]:
    return tuple(
        Path(run_dir) / name for name in ("checkpoints", "checkpoints.next", "checkpoints.old")
    )


def recover_checkpoint(run_dir: Path) -> None:
    """Finish a checkpoint swap a kill interrupted (:meth:`TrainingMonitor.checkpoint`):
    without ``checkpoints/``, the complete new one (written before the swap began) or else the
    previous one takes its place; leftovers are removed."""
    final, new, old = _checkpoint_folders(run_dir)
    if not final.exists():
        for candidate in (new, old):
            if (candidate / CHECKPOINT_STATE).exists():
                os.replace(candidate, final)
                break
    for leftover in (new, old):
        shutil.rmtree(leftover, ignore_errors=True)


class TrainingMonitor:
    """Counts episodes (the paper's budget unit), logs their statistics, evaluates the greedy
    policy every ``eval_every`` episodes on seeded episodes of its own training traffic, keeps
    the best of those checkpoints, and writes checkpoints for resuming.

    The best checkpoint (``best_model.zip``, described in ``best.json``) is chosen by
    ``checkpoint_rule`` (:func:`rank`). ``return``: the evaluation with the highest mean
    validation return (ties: the later), the rule of SB3's ``EvalCallback``: the training's
    own reward weighs crashes against speed. ``per_km``: the study's own reading, the fewest
    collisions per 100 km among evaluations at least ``SPEED_FLOOR`` x the slower of the idle
    and rule-based egos' speeds on the same episodes (:func:`rank`), with every evaluation's
    parameters kept in ``validations/`` so that the choice can be checked, or made again by
    another rule, without retraining. The paper keeps no checkpoint selection; the authors'
    code keeps the last model. Ours: one rule for every policy, on validation episodes only,
    so a training that ends in a bad stretch (seen in dense traffic) is not judged by its
    last parameters.

    Args:
        run_dir: the run folder (``evaluations.csv``, ``checkpoints/``).
        num_envs: training environments stepped together.
        env_config: the training environment's config dictionary (evaluation plays it with
            a fixed mix: ``mix_sampling`` is switched off).
        backend: simulator of the evaluations.
        max_episodes: stop after this many episodes in total (None: no episode budget).
        eval_every, eval_episodes, eval_seed: evaluate every ``eval_every`` episodes (0: never)
            on ``eval_episodes`` episodes seeded ``eval_seed + k``.
        state: counters restored from a checkpoint (``episodes``, ``steps``, ``best``).
        checkpoint_rule: ``return`` or ``per_km`` (:data:`~bgap.common.vocab.CHECKPOINT_RULES`).
        log: ``log(key, value)`` records a scalar (TensorBoard).

    The evaluated policy must have SB3's ``predict`` and ``save(path)`` (the best one is
    saved through it).
    """

    def __init__(
        self,
        run_dir: Path,
        num_envs: int,
        env_config: dict[str, Any],
        backend: str,
        max_episodes: int | None,
        eval_every: int,
        eval_episodes: int,
        eval_seed: int,
        state: dict[str, Any] | None = None,
        checkpoint_rule: str = "return",
        log: Callable[[str, float], None] = lambda key, value: None,
    ) -> None:
        self.run_dir = Path(run_dir)
        self.env_config = {**env_config, "mix_sampling": "fixed"}
        self.backend, self.max_episodes = backend, max_episodes
        self.eval_every, self.eval_episodes, self.eval_seed = eval_every, eval_episodes, eval_seed
        self.state = {"episodes": 0, "steps": 0, **(state or {})}
        self.stats = EpisodeStats(num_envs, env_config.get("policy_frequency", 1))
        self.recent: list[dict[str, Any]] = []
        self.log = log
        self.references: dict[str, dict[str, float]] | None = None
        self.rule = checkpoint_rule

    def on_step(
        self, rewards: np.ndarray, infos: dict[str, Any], dones: np.ndarray, policy: Any
    ) -> bool:
        """Account one vector step; False once the episode budget is spent. ``policy`` (with
        SB3's ``predict``) is what a periodic evaluation plays."""
        self.stats.add(np.arange(len(dones)), rewards, infos)
        for i in np.flatnonzero(dones):
            self.state["episodes"] += 1
            self.recent = (self.recent + [self.stats.row(i)])[-20:]
            self.stats.clear(i)
            for key, name in (
                ("crashed", "collision_rate"),
                ("avg_speed", "avg_speed"),
                ("lane_changes", "lane_changes"),
                ("return", "return"),
            ):
                self.log(f"episode/{name}", float(np.mean([r[key] for r in self.recent])))
            self.log("episode/count", self.state["episodes"])
            if self.eval_every and self.state["episodes"] % self.eval_every == 0:
                self.evaluate(policy)
        return self.max_episodes is None or self.state["episodes"] < self.max_episodes

    def evaluate(self, policy: Any) -> dict[str, float]:
        """Greedy episodes of ``policy`` in its own traffic; appended to evaluations.csv with
        the gradient updates made so far and, for reference, the idle and rule-based egos'
        figures on the same episodes."""
        seeds = range(self.eval_seed, self.eval_seed + self.eval_episodes)
        per_km = self.rule == "per_km"
        frequency = self.env_config.get("policy_frequency", 1)

        def figures(played: Any) -> dict[str, float]:
            episodes = rollout(self.env_config, played, seeds, self.backend).episodes
            return _figures(episodes, frequency if per_km else None)

        if self.references is None:  # the same episodes every time: played once
            self.references = {name: figures(name) for name in REFERENCES}
        record = {
            "episodes": self.state["episodes"],
            "steps": self.state["steps"],
            "gradient_updates": int(getattr(policy, "_n_updates", 0)),
            **figures(policy),
            **{f"{name}_{k}": v for name, row in self.references.items() for k, v in row.items()},
        }
        for key in ("collision_pct", "avg_speed", "lane_changes", "return"):
            self.log(f"eval/{key}", float(record[key]))
        self.log("eval/gradient_updates", record["gradient_updates"])
        path = self.run_dir / "evaluations.csv"
        pd.DataFrame([record]).to_csv(path, mode="a", header=not path.exists(), index=False)
        if per_km:  # every validation's parameters, small next to the replay buffer
            kept = self.run_dir / validation_model(record["episodes"])
            kept.parent.mkdir(exist_ok=True)
            write_atomic(kept, policy.save)
        self._keep_if_best(policy, record)
        return record

    def _keep_if_best(self, policy: Any, record: dict[str, Any]) -> None:
        """Save ``policy`` as the best checkpoint if this evaluation ranks first so far."""
        best = self.state.get("best")
        if best is not None and rank(best, self.rule) < rank(record, self.rule):
            return  # ties: the later evaluation, which has trained longer
        self.state["best"] = dict(record)
        keep_best(self.run_dir, policy.save, self.state["best"])
        self.log("eval/best_episodes", record["episodes"])

    def checkpoint(self, save: dict[str, Callable[[Path], Any]], extra: dict[str, Any]) -> None:
        """Write ``checkpoints/``: each ``save[name](path)`` (the learner's model, replay
        buffer, ...) and ``state.pkl`` (counters, running episode statistics, ``extra``: the
        environments' and random streams' state).

        A kill at any moment leaves one whole checkpoint (:func:`recover_checkpoint`): the
        new one is written into ``checkpoints.next/`` and swapped in by renaming folders.
        (Replacing the files one by one could pair a new model and replay buffer with the
        previous state and random streams, and the resumed run would differ.)"""
        final, new, old = _checkpoint_folders(self.run_dir)
        shutil.rmtree(new, ignore_errors=True)
        new.mkdir(parents=True)
        for name, write in save.items():
            write(new / name)
        state = {"monitor": self.state, "stats": self.stats.__dict__, "recent": self.recent}
        # whole or absent: its presence marks the folder complete (recover_checkpoint)
        write_atomic(new / CHECKPOINT_STATE, pickle.dumps({**state, **extra}))
        shutil.rmtree(old, ignore_errors=True)
        if final.exists():
            os.replace(final, old)
        os.replace(new, final)
        shutil.rmtree(old, ignore_errors=True)

    def restore(self, state: dict[str, Any]) -> None:
        """The counters and running statistics of a checkpoint's ``state.pkl``. Evaluations
        the run recorded after that checkpoint (a kill before the next one) are dropped from
        ``evaluations.csv``: the resumed run plays them again."""
        self.state.update(state["monitor"])
        self.stats.__dict__.update(state["stats"])
        self.recent = state["recent"]
        path = self.run_dir / "evaluations.csv"
        if path.exists():
            evaluations = pd.read_csv(path)
            kept = evaluations[evaluations.steps <= self.state["steps"]]
            if len(kept) < len(evaluations):
                write_atomic(path, kept.to_csv(index=False))


REFERENCES = ("idle", "rule")
"""Baselines whose validation figures each evaluation records beside the policy's."""


def validation_model(episodes: int) -> str:
    """The run folder's file of the parameters validated after ``episodes`` episodes."""
    return f"validations/episode-{episodes:07d}.zip"


def rank(record: dict[str, Any], rule: str) -> tuple[float, ...]:
    """A validation's place under ``rule``, lower first: ``return``, the mean validation
    return; ``per_km``, the constrained score on kilometres
    (:func:`~bgap.common.scores.constrained_score`: collisions per 100 km where the mean
    speed reaches ``SPEED_FLOOR`` x the reference speed within :data:`FLOOR_BAND` below it,
    else 100 + the shortfall), then the faster. Equal ranks go to the later validation.

    The reference is the slower of the idle and the rule-based egos on the same episodes
    (idle's alone where a record lacks the rule's). The floor is there to keep out a crawl,
    a policy safe only by being slow; a reference that does not brake sets one no safe
    driver reaches: in stock traffic idle crashes in 99% of dense validation episodes at
    24.3 m/s, where the rule-based ego crashes in none at 22.0, and under idle's floor every
    stock-trained checkpoint ranked by its shortfall alone, the fastest kept whatever it
    crashed. In bgap's traffic idle is the slower of the two and the floor is idle's."""
    if rule == "return":
        return (-record["return"],)
    reference = min(record["idle_avg_speed"], record.get("rule_avg_speed", np.inf))
    floor = SPEED_FLOOR * (1 - FLOOR_BAND)
    score = constrained_score(record["per_100km"], record["avg_speed"], reference, floor)
    return (score, -record["avg_speed"])


def choose_again(run_dir: Path, rule: str) -> bool:
    """Rank a training's recorded validations (``evaluations.csv``) by ``rule`` once more, as
    it ranks them today, and keep the first: its parameters (kept in ``validations/``) as
    ``best_model.zip``, its record as ``best.json``. A finished training is reused as it is,
    so a change to the rule reaches it only so; True where the kept checkpoint changed.
    Only ``per_km`` keeps every validation's parameters."""
    run_dir = Path(run_dir)
    path, best = run_dir / "evaluations.csv", run_dir / "best.json"
    if rule != "per_km" or not path.exists() or not best.exists():
        return False
    records = pd.read_csv(path).to_dict(orient="records")
    first = min(reversed(records), key=lambda r: rank(r, rule))  # ties: the later, as in training
    if first["episodes"] == json.loads(best.read_text())["episodes"]:
        return False
    keep_best(run_dir, (run_dir / validation_model(first["episodes"])).read_bytes(), first)
    return True


def keep_best(run_dir: Path, model: bytes | Callable[[Path], Any], record: dict[str, Any]) -> None:
    """Write the kept checkpoint: ``model`` (its bytes, or a writer such as SB3's ``save``) as
    ``best_model.zip`` and its validation ``record`` as ``best.json``, each whole or not at
    all."""
    write_atomic(run_dir / BEST_MODEL, model)
    write_atomic(run_dir / "best.json", json.dumps(record, indent=1))


def _figures(episodes: pd.DataFrame, policy_frequency: int | None = None) -> dict[str, float]:
    """The validation's means; with ``policy_frequency``, collisions per 100 km too (each
    episode's distance: its mean speed x its duration)."""
    figures = {
        "collision_pct": 100 * float(episodes.crashed.mean()),
        "avg_speed": float(episodes.avg_speed.mean()),
        "lane_changes": float(episodes.lane_changes.mean()),
        "return": float(episodes["return"].mean()),
    }
    if policy_frequency is not None:
        distance = episode_distance(episodes, policy_frequency)
        figures["per_100km"] = collisions_per_100km(episodes.crashed, distance)
    return figures


def plot_learning_curves(run_dir: Path) -> Path | None:
    """``learning_curves.png`` of a run folder: validation collision %, mean speed and return
    against gradient updates, with the idle and rule-based egos on the same episodes (None
    when the run made no periodic evaluation)."""
    path = Path(run_dir) / "evaluations.csv"
    if not path.exists():
        return None
    plt = pyplot()

    ev = pd.read_csv(path)
    x = ev["gradient_updates"] if "gradient_updates" in ev else ev["steps"]
    fig, axes = plt.subplots(1, 3, figsize=(11, 3.2))
    for ax, (key, label) in zip(
        axes,
        [
            ("collision_pct", "collisions [% episodes]"),
            ("avg_speed", "mean speed [m/s]"),
            ("return", "return"),
        ],
        strict=True,
    ):
        ax.plot(x, ev[key], "o-", ms=3, label="policy")
        # a running mean over five evaluations: single evaluations are noisy
        ax.plot(x, ev[key].rolling(5, min_periods=1).mean(), color="k", lw=1, label="mean of 5")
        for name, style in zip(REFERENCES, ("--", ":"), strict=True):
            if f"{name}_{key}" in ev:
                ax.axhline(ev[f"{name}_{key}"].iloc[-1], ls=style, color="gray", label=name)
        ax.set_xlabel("gradient updates" if "gradient_updates" in ev else "environment steps")
        ax.set_ylabel(label)
    axes[0].legend(fontsize=7)
    fig.suptitle(f"validation during training: {Path(run_dir).name}", fontsize=9)
    fig.tight_layout()
    out = Path(run_dir) / "learning_curves.png"
    write_atomic(out, lambda p: fig.savefig(p, dpi=110))
    plt.close(fig)
    return out


class SB3Monitor(BaseCallback):
    """:class:`TrainingMonitor` as a Stable-Baselines3 callback.

    Checkpoints are taken where the learner's state is whole: when a new rollout starts,
    after the previous iteration stored its transition and made its gradient steps (inside a
    step callback the environments have moved on but the transition is not stored yet). The
    first Ctrl-C asks for a checkpoint at that point and then raises ``KeyboardInterrupt``; a
    second one interrupts at once. ``extra_state()`` returns what the checkpoint keeps beside
    the model and the replay buffer (environments, random streams)."""

    def __init__(
        self,
        monitor: TrainingMonitor,
        checkpoint_every: int,
        extra_state: Callable[[], dict[str, Any]],
    ) -> None:
        super().__init__()
        self.monitor, self.every, self.extra_state = monitor, checkpoint_every, extra_state
        self.ctrl_c = CtrlC()
        self.saved_at: int | None = None
        """Environment steps of the last checkpoint written (None: none yet)."""
        monitor.log = lambda key, value: self.logger.record(key, value)

    def _on_training_start(self) -> None:
        self._last_ckpt = self.num_timesteps
        self.ctrl_c.start()

    def _on_training_end(self) -> None:
        self.ctrl_c.stop()

    def _on_rollout_start(self) -> None:
        if self.ctrl_c.requested:
            self.checkpoint()
            self.ctrl_c.stop()
            raise KeyboardInterrupt
        if self.num_timesteps - self._last_ckpt >= self.every:
            self.checkpoint()

    def _on_step(self) -> bool:
        self.monitor.state["steps"] = int(self.num_timesteps)
        return self.monitor.on_step(
            np.asarray(self.locals["rewards"]),
            stack_infos(self.locals["infos"]),
            np.asarray(self.locals["dones"]),
            self.model,
        )

    def checkpoint(self) -> None:
        """Model, replay buffer (off-policy algorithms; PPO checkpoints between rollouts,
        where it holds none) and state, as they are now."""
        self.monitor.state["steps"] = int(self.model.num_timesteps)
        save = {"model.zip": self.model.save}
        if hasattr(self.model, "save_replay_buffer"):
            save["replay.pkl"] = self.model.save_replay_buffer
        self.monitor.checkpoint(save, self.extra_state())
        self._last_ckpt = self.saved_at = self.num_timesteps


class ReportSteps(BaseCallback):
    """Sends an SB3 training's step count to ``report`` (a
    :class:`~bgap.runner.progress.Reporter`: the parent's progress bars) every ``every``
    steps; it reads nothing and changes nothing the training learns."""

    def __init__(self, report: Callable[..., None], every: int = 500) -> None:
        super().__init__()
        self.report, self.every = report, every

    def _on_training_start(self) -> None:
        self._sent = self.num_timesteps
        self.report(self.num_timesteps, start=True)

    def _on_step(self) -> bool:
        if self.num_timesteps - self._sent >= self.every:
            self._sent = self.num_timesteps
            self.report(self.num_timesteps)
        return True
