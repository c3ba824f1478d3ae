"""``python -m bgap.zoo``: export trained run folders into the zoo (:mod:`bgap.agents.zoo`).

    python -m bgap.zoo runs=outputs/pipeline/runs/main/sparse arm=main out=zoo/main/sparse

Every run folder below ``runs`` becomes ``<out>/<family>/s<seed>.zip`` (its ``checkpoint``'s
model in the zoo's compact form) and its card ``s<seed>.yaml``. The pipeline's ``zoo@<stage>``
stages run it after each training stage; their outputs are kept in git, so a fresh clone
plays, watches and re-evaluates the study's policies without DVC's cache. Exporting an
unchanged run folder again writes the same bytes.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from omegaconf import OmegaConf

from bgap.agents import zoo
from bgap.common.errors import ConfigError, check
from bgap.common.runs import CONFIG, MODEL, model_file, write_atomic
from bgap.common.tables import read_table
from bgap.common.vocab import FLOOR_BAND, SPEED_FLOOR
from bgap.experiments.config import CHECKPOINTS
from bgap.experiments.evaluate_policies import run_records, validation_block


@dataclass
class ZooConfig:
    """``python -m bgap.zoo``: export run folders into the zoo."""

    runs: str = "???"
    """A run folder, or a folder of them (a training stage's ``run_dir``)."""
    arm: str = "???"
    """The arm the policies belong to: the first part of their zoo names."""
    out: str = "???"
    """The zoo folder of this arm and density, e.g. ``zoo/main/sparse``."""
    checkpoint: str = "best"
    """Which model of each run: ``best`` (the one its validations chose) or ``last``."""

    def __post_init__(self) -> None:
        check(
            self.checkpoint in CHECKPOINTS,
            "checkpoint",
            self.checkpoint,
            f"use one of {CHECKPOINTS}",
        )
        check("/" not in self.arm and bool(self.arm), "arm", self.arm, "a name without '/'")


SCHEMAS = ((None, "base_zoo", ZooConfig),)


def card_of(run: Path, arm: str, checkpoint: str) -> dict[str, Any]:
    """The zoo card of run folder ``run`` (module docstring of :mod:`bgap.agents.zoo`)."""
    if not (run / CONFIG).exists():
        raise ConfigError(f"{run} has no {CONFIG}: not a run folder bgap.train wrote")
    cfg = OmegaConf.to_container(OmegaConf.load(run / CONFIG), resolve=True)
    env, agent, profile = cfg["env"], cfg["agent"], cfg["profile"]
    family, density, seed = cfg["policy"], env["name"], int(cfg["seed"])
    chosen = model_file(run, checkpoint)
    validation: dict[str, Any] = {}
    if chosen.name != MODEL and (run / "best.json").exists():
        best = json.loads((run / "best.json").read_text())
        keep = (
            "episodes",
            "steps",
            "collision_pct",
            "per_100km",
            "avg_speed",
            "lane_changes",
            "return",
        )
        validation = {k: best[k] for k in keep if k in best}
    validated = (
        int(read_table(run / "evaluations.csv").episodes.max())
        if (run / "evaluations.csv").exists()
        else 0
    )
    records = run_records(chosen)  # what bgap.evaluate's models.csv says of the run folder
    return {
        "name": f"{zoo.PREFIX}{arm}/{density}/{family}/s{seed}",
        "policy": f"{arm}/{density}/{run.name}",
        "arm": arm,
        "density": density,
        "family": family,
        "seed": seed,
        "algorithm": agent["algo"],
        "network": {"net_arch": agent["net_arch"], "extractor": agent["extractor"]},
        "observation": {
            "options": list(agent["observation"]),
            "observed_vehicles": env["observed_vehicles"],
        },
        "presets": {
            "reward": cfg["reward"]["name"],
            "agent": agent["name"],
            "behavior": cfg["behavior"]["name"],
            "profile": profile["name"],
            "traffic": cfg["traffic"]["name"],
            "mix_sampling": cfg["mix_sampling"],
        },
        "training": {
            "steps": profile["train_steps"],
            "episodes": profile["train_episodes"],
            "validated_episodes": validated,
        },
        "checkpoint": {
            "kept": checkpoint if chosen.name != MODEL else "last",
            "rule": _rule(cfg) if chosen.name != MODEL else "the training's final model",
            "validation": validation,
        },
        "played_under": {k: env[k] for k in zoo.PLAYED_UNDER},
        "watch": [
            f"env={density}",
            f"behavior={cfg['behavior']['name']}",
            f"reward={cfg['reward']['name']}",
            f"traffic={cfg['traffic']['name']}",
        ],
        "records": records,
    }


def _rule(cfg: dict[str, Any]) -> str:
    """How the run chose its checkpoint, with the validation episodes' seeds."""
    rule, first, n = validation_block(cfg)
    how = (
        f"the fewest collisions per 100 km at {SPEED_FLOOR} x the slower of the idle and "
        f"rule-based egos' speeds or more, within {FLOOR_BAND:.0%} below it (ties: the faster)"
        if rule == "per_km"
        else "the highest mean return"
    )
    every = cfg["profile"]["eval_every_episodes"]
    return (
        f"{how} on {n} validation episodes (seeds {first}-{first + n - 1}), validated "
        f"every {every} training episodes"
    )


def export(run: Path, arm: str, out: Path, checkpoint: str = "best") -> Path:
    """Write run folder ``run``'s policy and card into ``out/<family>/s<seed>``."""
    card = card_of(run, arm, checkpoint)
    target = out / card["family"] / f"s{card['seed']}.zip"
    target.parent.mkdir(parents=True, exist_ok=True)
    data = zoo.compact_archive(model_file(run, checkpoint))
    write_atomic(target, data)
    text = yaml.safe_dump(card, sort_keys=False, default_flow_style=None, width=100)
    write_atomic(target.with_suffix(".yaml"), text)
    return target
