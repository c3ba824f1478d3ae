"""Which policies an evaluation plays (``models=``: run folders, model files, zoo names;
``baselines=``) under which names, and the records of the trainings behind its models
(``models.csv``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pandas as pd
from omegaconf import OmegaConf

from bgap.agents import zoo
from bgap.common.errors import ConfigError
from bgap.common.runs import CONFIG, MODEL, model_file, run_folders
from bgap.common.tables import read_table
from bgap.common.vocab import BASELINES
from bgap.experiments.config import ExperimentConfig, first_validation_seed


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
        rule, first, n = validation_block(settings)
        row |= {"checkpoint_rule": rule, "validation_seeds": f"{first}-{first + n - 1}"}
        kept = {g: settings.get(g) for g in ("reward", "agent", "profile")}
        row["settings"] = json.dumps(kept, sort_keys=True)
    return row


def validation_block(settings: dict[str, Any]) -> tuple[str, int, int]:
    """A training's checkpoint rule and the seeds its validations played (first, count),
    from its saved settings (run folders from before the rule was a setting chose by
    return)."""
    profile = settings["profile"]
    rule = profile.get("checkpoint_rule", "return")
    first = first_validation_seed(rule, int(settings["val_seed"]))
    return rule, first, int(profile["eval_during_training"])
