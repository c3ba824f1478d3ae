"""Policies by name or file: the scripted baselines and saved models of any SB3 algorithm.

A policy spec is any of: a baseline name (``idle``, ``random``, ``left``, ``rule``,
``rule_tuned``, ``idm``); the path of a saved Stable-Baselines3 model (``model.zip`` or its
run folder; DQN, QR-DQN, PPO, A2C, SAC and TD3 are recognised from the file, or named as
``ppo:path``), a zoo name (``zoo:main/sparse/behavior_rich/s0``, :mod:`bgap.agents.zoo`) or
a loaded model, played greedily; any of these as a hybrid with the rule-based ego's safety
fallback (``hybrid:SPEC``, ``hybrid-2.5:SPEC``: :mod:`bgap.agents.hybrid`); or a callable
(:func:`bgap.sim.rollout.as_callable`). :func:`rollout` plays any spec on seeded episodes
through the simulators' one rollout loop.
"""

from __future__ import annotations

import json
import zipfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from bgap.agents import zoo
from bgap.agents.hybrid import DEFAULT_THRESHOLD, Hybrid
from bgap.agents.observation import ObservationFeatures, model_features
from bgap.agents.rule_based import DEFAULT, rule_based, tuned
from bgap.common.errors import ConfigError
from bgap.common.runs import read_or_refuse
from bgap.common.vocab import BASELINES
from bgap.sim import rollout as sim_rollout
from bgap.sim.rollout import Policy, Rollout, as_callable, greedy
from bgap.traffic.road import IDLE, LANE_LEFT, N_ACTIONS

__all__ = ["as_policy", "baseline", "check_rows", "greedy", "load_model", "model_path", "rollout"]


def baseline(name: str, config: dict[str, Any] | None = None) -> Policy:
    """A scripted ego: ``idle`` holds lane and speed, ``left`` always asks for the left
    lane, ``random`` draws a meta-action uniformly from the episode's stream, ``rule`` drives
    by IDM and MOBIL with highway-env's parameters, ``rule_tuned`` with the ones tuned for
    the traffic of ``config``, ``idm`` by IDM in its lane (:mod:`bgap.agents.rule_based`, for
    the lanes and speeds of the environment ``config``)."""
    if name in ("rule", "rule_tuned", "idm"):
        params = tuned(config or {}) if name == "rule_tuned" else DEFAULT
        driver = rule_based(config, params, lane_changes=name != "idm")
        return lambda obs, rngs: driver(obs)
    if name == "idle":
        return lambda obs, rngs: np.full(len(obs), IDLE)
    if name == "left":
        return lambda obs, rngs: np.full(len(obs), LANE_LEFT)
    if name == "random":
        return lambda obs, rngs: np.array([r.integers(N_ACTIONS) for r in rngs])
    raise ConfigError(f"policy={name!r} is not a baseline; use one of {BASELINES}")


def model_path(spec: str | Path) -> Path:
    """``model.zip`` itself, inside the run folder ``spec``, or the zoo's archive ``spec``
    names."""
    if zoo.is_zoo(spec):
        return zoo.resolve_one(str(spec))
    path = Path(spec)
    if path.is_dir():
        path = path / "model.zip"
    if not path.exists():
        raise FileNotFoundError(f"no model at {path}; train it with python -m bgap.train")
    return path


# Stable-Baselines3 stores no algorithm name in a model file; each algorithm's own saved
# attributes tell them apart (A2C's and PPO's policies are the same class).
_ALGORITHM_KEYS = (
    ("qrdqn", "n_quantiles"),  # before dqn: QR-DQN saves target_update_interval too
    ("dqn", "target_update_interval"),
    ("ppo", "n_epochs"),
    ("a2c", "n_steps"),
    ("td3", "policy_delay"),
    ("sac", "target_entropy"),
)


ALGORITHMS = tuple(name for name, _ in _ALGORITHM_KEYS)
"""Algorithms a model file may be named with (``ppo:path``)."""


def load_model(spec: str | Path) -> Any:
    """A saved Stable-Baselines3 model of any algorithm: ``[algo:]path`` (``ppo:run/model.zip``
    names it; otherwise it is recognised from the attributes saved in the file). DQN models
    load as bgap's DQN (SB3's, with the paper's loss and schedules)."""
    # Here, not at the top: torch and Stable-Baselines3 take seconds to import, and the
    # baselines and callables need neither.
    import stable_baselines3 as sb3

    from bgap.agents.dqn import DQN

    classes = {
        "dqn": DQN,
        "ppo": sb3.PPO,
        "a2c": sb3.A2C,
        "sac": sb3.SAC,
        "td3": sb3.TD3,
        "qrdqn": _qrdqn,
    }
    algo, _, rest = str(spec).partition(":")
    named = bool(rest) and algo.lower() in classes
    path = model_path(rest if named else spec)
    fix = "give a model.zip saved by bgap.train or SB3"
    if zoo.is_zoo(spec):
        fix = "the zoo's file is damaged: restore it with `git checkout -- zoo`"

    def load() -> Any:
        name = algo.lower() if named else _algorithm_of(path)
        cls = classes[name]() if name == "qrdqn" else classes[name]
        return cls.load(path, device="cpu")

    return read_or_refuse(load, f"{path} is not a readable model", fix)


def _qrdqn() -> type:
    # Imported here: sb3-contrib loads only for QR-DQN models.
    from bgap.agents.qrdqn import QRDQN

    return QRDQN


def _algorithm_of(path: Path) -> str:
    """The algorithm of a saved model, from the attributes SB3 saved in its ``data``."""
    with zipfile.ZipFile(path) as archive:
        data = json.loads(archive.read("data"))
    found = [name for name, key in _ALGORITHM_KEYS if key in data]
    if not found:
        raise ConfigError(f"{path}: cannot tell its algorithm; write it as <algo>:{path}")
    return found[0]


HYBRID = "hybrid"
"""The prefix of a hybrid's spec: ``hybrid:SPEC`` or ``hybrid-<threshold>:SPEC``."""


def hybrid_spec(spec: str) -> tuple[float, str] | None:
    """``(threshold, SPEC)`` of ``hybrid:SPEC`` (the fallback's default threshold) or
    ``hybrid-2.5:SPEC`` (2.5 s), None for any other spec (:mod:`bgap.agents.hybrid`)."""
    head, sep, rest = spec.partition(":")
    if not sep or not head.startswith(HYBRID):
        return None
    given = head[len(HYBRID) :]
    if not given:
        return DEFAULT_THRESHOLD, rest
    try:
        if not given.startswith("-"):
            raise ValueError(given)
        return float(given[1:]), rest
    except ValueError:
        raise ConfigError(
            f"{spec!r}: a hybrid is hybrid:SPEC or hybrid-<seconds>:SPEC (e.g. hybrid-2.5:"
            f"{rest}), the time to collision under which the rule-based ego acts"
        ) from None


def as_policy(spec: Any, config: dict[str, Any] | None = None) -> tuple[Policy, int | None]:
    """Any policy spec (module docstring) as a :data:`~bgap.sim.rollout.Policy`, with the
    number of observation rows it needs (None: any). ``config``: the environment a baseline
    drives in, or a model trained with observation options observes
    (:mod:`bgap.agents.observation`: their columns are added to each observation here)."""
    if isinstance(spec, (str, Path)):
        if str(spec) in BASELINES:
            return baseline(str(spec), config), None
        hybrid = hybrid_spec(str(spec))
        if hybrid is not None:  # the learned policy with the rule-based safety fallback
            threshold, learned = hybrid
            policy, rows = as_policy(learned, config)
            return Hybrid(policy, config, threshold), rows
        spec = load_model(spec)
    if hasattr(spec, "predict") and model_features(spec):
        features = ObservationFeatures(model_features(spec), config)
        rows, columns = spec.observation_space.shape
        if columns != 5 + features.columns:
            raise ConfigError(
                f"a model with observation options {features.features} should read "
                f"{5 + features.columns} columns, its network reads {columns}: the file is not "
                "one bgap.train wrote"
            )
        return greedy_on(spec, features), int(rows)
    return as_callable(spec)


def greedy_on(model: Any, features: ObservationFeatures) -> Policy:
    """``model``'s greedy actions on the observations with ``features``' columns added."""
    act = greedy(model)
    return lambda obs, rngs: act(features(obs), rngs)


def check_rows(name: Any, rows: int | None, config: dict[str, Any]) -> None:
    """Refuse, in one line naming both, to play a model that reads ``rows`` observed
    vehicles in an environment ``config`` that observes another number."""
    have = config.get("observation", {}).get("vehicles_count")
    if rows is not None and have is not None and int(have) != rows:
        raise ConfigError(
            f"policy {name} reads {rows} observed vehicles, this environment observes {have}: "
            f"play it at its own density (env.observed_vehicles={rows}, or the env preset it "
            "was trained in)"
        )


def rollout(config: dict[str, Any], policy: Any, seeds: Iterable[int], *args, **kwargs) -> Rollout:
    """:func:`bgap.sim.rollout.rollout` for any policy spec: names, paths and models' observation
    options resolved here; a model that observes another number of vehicles is refused."""
    if isinstance(policy, (str, Path)) or hasattr(policy, "predict"):
        name = policy if isinstance(policy, (str, Path)) else type(policy).__name__
        policy, rows = as_policy(policy, config)
        check_rows(name, rows, config)
    return sim_rollout.rollout(config, policy, seeds, *args, **kwargs)
