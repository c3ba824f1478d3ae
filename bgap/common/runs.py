"""Run folders: every run saves its resolved config and the command that made it.

Written by hand rather than by Hydra's output handling (``hydra.run.dir`` and ``.hydra/``,
switched off in the packaged configs): a training's run folder is named from the validated
config itself (a hash of everything that changes what is learnt), which Hydra's
interpolations cannot compute before the config exists, and one command writes several run
folders (``bgap.run``: both policies and the results).
"""

from __future__ import annotations

import hashlib
import json
import shlex
import sys
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf

from bgap.common.errors import ConfigError

VOLATILE = ("resume", "workers", "root", "out", "run_dir")
"""Settings that do not change what a folder holds (where it is, how fast it is made)."""


UNNAMED = ("reward.converged", "agent.converged")
"""Settings left out of folder and study names: they change nothing a run computes (and
the names of runs made before they existed stay the same)."""


def digest(values: Any) -> str:
    """A short, stable hash of JSON-able ``values`` (folder and study names); the
    :data:`UNNAMED` settings of a config tree are left out."""
    values = json.loads(json.dumps(values, default=str))  # a copy to prune
    for key in UNNAMED:
        *path, leaf = key.split(".")
        node = values
        for part in path:
            node = node.get(part) if isinstance(node, dict) else None
        if isinstance(node, dict):
            node.pop(leaf, None)
    return hashlib.sha1(json.dumps(values, sort_keys=True, default=str).encode()).hexdigest()[:8]


def _flat(tree: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(tree, dict):
        out: dict[str, Any] = {}
        for key, value in tree.items():
            out.update(_flat(value, f"{prefix}{key}."))
        return out
    return {prefix[:-1]: tree}


MODEL, BEST_MODEL = "model.zip", "best_model.zip"
"""A training's final parameters, and the checkpoint its periodic validations chose
(:class:`bgap.agents.monitor.TrainingMonitor`)."""


def model_file(run_dir: str | Path, checkpoint: str = "best") -> Path:
    """The model of a run folder that ``checkpoint`` names: ``best`` is the validation-chosen
    one where the training validated (else the final one), ``last`` the final one."""
    best = Path(run_dir) / BEST_MODEL
    return best if checkpoint == "best" and best.exists() else Path(run_dir) / MODEL


ADDED_LATER = {
    "learner": "sb3",
    "threads": 0,
    "policies": [],
    "checkpoint": "last",
    "reward.converged": True,
    "agent.converged": True,
}
"""Settings added after run folders were first written, with the value those runs used: a
stored config without the key is read as having it."""


def differing_keys(stored: dict, current: dict, ignore: tuple[str, ...] = VOLATILE) -> list[str]:
    """Dotted keys whose values differ between two config trees, ``ignore``d ones aside."""
    a, b = _flat(stored), _flat(current)
    a.update({k: v for k, v in ADDED_LATER.items() if k in b and k not in a})
    return sorted(k for k in {*a, *b} if a.get(k) != b.get(k) and k.split(".")[0] not in ignore)


def save_run_metadata(out_dir: str | Path, cfg: Any, ignore: tuple[str, ...] = VOLATILE) -> Path:
    """Write ``config.yaml`` (resolved) and ``command.txt`` into ``out_dir``.

    A folder that already holds a ``config.yaml`` of other settings is refused with a
    :class:`ConfigError` naming the differing keys: a rerun resumes or repeats the same
    work, it never overwrites or mixes in a result of other settings."""
    out = Path(out_dir)
    conf = cfg if OmegaConf.is_config(cfg) else OmegaConf.structured(cfg)
    current = OmegaConf.to_container(conf, resolve=True)
    stored_path = out / "config.yaml"
    if stored_path.exists():
        stored = OmegaConf.to_container(OmegaConf.load(stored_path), resolve=True)
        keys = differing_keys(stored, current, ignore)
        if keys:
            shown = ", ".join(
                f"{k} ({_flat(stored).get(k)!r} there, {_flat(current).get(k)!r} now)"
                for k in keys[:4]
            )
            more = f" and {len(keys) - 4} more" if len(keys) > 4 else ""
            raise ConfigError(
                f"{out} holds a result of other settings: {shown}{more}; choose another "
                "output folder (or delete that one)"
            )
    out.mkdir(parents=True, exist_ok=True)
    stored_path.write_text(OmegaConf.to_yaml(conf, resolve=True))
    # orig_argv keeps "-m bgap.x"; argv[0] would be the module's file path.
    command = " ".join(shlex.quote(a) for a in ["python", *sys.orig_argv[1:]])
    (out / "command.txt").write_text(command + "\n")
    return out
