"""The history of the experiments' settings: how configs saved by earlier versions read.

Settings added after run folders were first written keep those folders usable: a stored
config without such a key is read as having the value every earlier run used (resuming,
refusing a folder of other settings, the zoo's cards and ``models.csv``), and a setting at
that value is left out of the names hashed from a config, so folders and studies named
before keep their names. The one place that knows this history; the run-folder plumbing
(:mod:`bgap.common.runs`) takes it as a reader.
"""

from __future__ import annotations

import copy
from typing import Any

ADDED_LATER = {
    "learner": "sb3",
    "threads": 0,
    "policies": [],
    "checkpoint": "last",
    "reward.converged": True,
    "agent.converged": True,
    "profile.checkpoint_rule": "return",
    "traffic.scenes": "all",
    "traffic.mixture": None,
}
"""Settings added after run folders were first written, with the value those runs used: a
stored config without the key is read as having it."""
ADDED_WITH_ALGOS = {
    "algo": "dqn",
    "extractor": "flatten",
    "attention_dim": 64,
    "attention_heads": 2,
    "n_quantiles": 25,
    "n_steps": 128,
    "n_epochs": 10,
    "gae_lambda": 0.95,
    "clip_range": 0.2,
    "ent_coef": 0.0,
    "vf_coef": 0.5,
    "observation": [],
}
"""The ``agent`` settings that came with the algorithms beside DQN and the observation
options (the learner arms), at the values every earlier training had: read into configs saved
before them, and left out of a training's identity at these values (its run folder keeps
its name)."""
ADDED_LATER |= {f"agent.{k}": v for k, v in ADDED_WITH_ALGOS.items()}


def upgrade(stored: dict[str, Any], current: dict[str, Any]) -> dict[str, Any]:
    """``stored`` (a saved config tree) with every :data:`ADDED_LATER` key that ``current``
    has and ``stored`` lacks, at its earlier value (a :data:`bgap.common.runs.Upgrade`)."""
    stored = copy.deepcopy(stored)
    for key, value in ADDED_LATER.items():
        *path, leaf = key.split(".")
        mine, theirs = stored, current
        for part in path:
            mine = mine.get(part) if isinstance(mine, dict) else None
            theirs = theirs.get(part) if isinstance(theirs, dict) else None
        if isinstance(mine, dict) and isinstance(theirs, dict) and leaf in theirs:
            mine.setdefault(leaf, copy.deepcopy(value))
    return stored


def as_before(settings: dict[str, Any]) -> dict[str, Any]:
    """A config's ``settings`` (``asdict``) without what was added later at the value every
    earlier config had (the ``agent`` settings of :data:`ADDED_WITH_ALGOS`, simulated
    ``traffic``, a replay's ``scenes`` at ``all`` and ``mixture`` unset, the grid's
    ``overtakes`` off), for the names hashed from them: folders and studies named before
    keep their names."""
    settings = dict(settings)
    if isinstance(settings.get("agent"), dict):
        settings["agent"] = {
            k: v
            for k, v in settings["agent"].items()
            if k not in ADDED_WITH_ALGOS or ADDED_WITH_ALGOS[k] != v
        }
    traffic = settings.get("traffic") or {}
    if traffic.get("source", "simulated") == "simulated":
        settings.pop("traffic", None)
    elif isinstance(traffic, dict):  # replayed: every scene, no mixture, as before either
        settings["traffic"] = {
            k: v for k, v in traffic.items() if (k, v) not in (("scenes", "all"), ("mixture", None))
        }
    grid = settings.get("grid")
    if isinstance(grid, dict) and grid.get("overtakes") is False:  # not counted, as before
        settings["grid"] = {k: v for k, v in grid.items() if k != "overtakes"}
    return settings
