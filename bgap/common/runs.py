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
import os
import pickle
import re
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from omegaconf import OmegaConf

from bgap.common.cli import command
from bgap.common.errors import ConfigError

T = TypeVar("T")

LOCK = ".lock"
"""The advisory lock file of a folder a command is writing (:mod:`bgap.runner.locks`)."""

CHECKPOINT_STATE = "state.pkl"
"""A training checkpoint's counters and states (:mod:`bgap.agents.monitor`), written last:
a checkpoint folder that holds it is whole."""

VOLATILE = ("resume", "workers", "root", "out", "run_dir", "cluster")
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


def file_digest(path: str | Path, algorithm: str = "sha256") -> str:
    """The hex digest of a file's bytes, read in blocks: an input is compared by what it
    holds, not by its path (a rehearsal writes other tables to the same path)."""
    h = hashlib.new(algorithm)
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


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
CONFIG = "config.yaml"
"""Every run folder's resolved settings, written by :func:`save_run_metadata`."""


def model_file(run_dir: str | Path, checkpoint: str = "best") -> Path:
    """The model of a run folder that ``checkpoint`` names: ``best`` is the validation-chosen
    one where the training validated (else the final one), ``last`` the final one."""
    best = Path(run_dir) / BEST_MODEL
    return best if checkpoint == "best" and best.exists() else Path(run_dir) / MODEL


def run_folders(root: str | Path) -> list[Path]:
    """Every run folder below ``root`` (one holding ``model.zip``; a training's
    ``checkpoints*`` folders are not runs), sorted by path."""
    found = Path(root).rglob(MODEL)
    return sorted(p.parent for p in found if not p.parent.name.startswith("checkpoints"))


Upgrade = Callable[[dict, dict], dict]
"""Reads a stored config (first argument) saved by an earlier version as the current one's
schema (second) has it: a command's own history of its settings
(:func:`bgap.experiments.compat.upgrade`)."""


def differing_keys(stored: dict, current: dict, ignore: tuple[str, ...] = VOLATILE) -> list[str]:
    """Dotted keys whose values differ between two config trees, ``ignore``d ones aside."""
    a, b = _flat(stored), _flat(current)
    return sorted(k for k in {*a, *b} if a.get(k) != b.get(k) and k.split(".")[0] not in ignore)


DAMAGED = (
    pickle.UnpicklingError,
    EOFError,
    zipfile.BadZipFile,
    KeyError,
    ValueError,
    OSError,
    RuntimeError,
    AttributeError,
)
"""What reading a truncated or corrupt model or checkpoint raises (pickle, zip, torch; a
model read as another algorithm's: AttributeError)."""


def read_or_refuse(read: Callable[[], T], what: str, fix: str) -> T:
    """``read()`` of a model or checkpoint file; a damaged one is a :class:`ConfigError`
    naming ``what`` is damaged and the ``fix``, one line instead of a traceback."""
    try:
        return read()
    except DAMAGED as err:
        if isinstance(err, ConfigError):  # a known mistake of the reader's own
            raise
        reason = str(err).splitlines()[0][:120] if str(err) else "truncated"
        raise ConfigError(f"{what} ({type(err).__name__}: {reason}); {fix}") from None


def other_settings(
    stored_path: Path, current: dict, ignore: tuple[str, ...], upgrade: Upgrade | None = None
) -> str | None:
    """How the settings saved at ``stored_path`` (read through ``upgrade``) differ from
    ``current`` (the first keys, with both values), or None when they do not."""
    try:
        stored = OmegaConf.to_container(OmegaConf.load(stored_path), resolve=True)
    except Exception as err:  # noqa: BLE001 - YAML's, OmegaConf's and decoding errors alike
        raise ConfigError(
            f"{stored_path} is not a settings file bgap can read ({type(err).__name__}); "
            "choose another output folder, or remove that file if the folder is yours"
        ) from None
    if not isinstance(stored, dict):
        raise ConfigError(
            f"{stored_path} is not a settings file bgap wrote (it holds no settings); choose "
            "another output folder, or remove that file if the folder is yours"
        )
    if upgrade is not None:
        stored = upgrade(stored, current)
    keys = differing_keys(stored, current, ignore)
    if not keys:
        return None
    shown = ", ".join(
        f"{k} ({_flat(stored).get(k)!r} there, {_flat(current).get(k)!r} now)" for k in keys[:4]
    )
    return shown + (f" and {len(keys) - 4} more" if len(keys) > 4 else "")


def save_run_metadata(
    out_dir: str | Path,
    cfg: Any,
    ignore: tuple[str, ...] = VOLATILE,
    upgrade: Upgrade | None = None,
) -> Path:
    """Write ``config.yaml`` (resolved) and ``command.txt`` into ``out_dir``.

    A folder that already holds a ``config.yaml`` of other settings (read through
    ``upgrade``, where its command's settings have a history) is refused with a
    :class:`ConfigError` naming the differing keys: a rerun resumes or repeats the same
    work, it never overwrites or mixes in a result of other settings."""
    out = Path(out_dir)
    conf = cfg if OmegaConf.is_config(cfg) else OmegaConf.structured(cfg)
    current = OmegaConf.to_container(conf, resolve=True)
    stored_path = out / CONFIG
    refuse_foreign(out)
    if stored_path.exists() and not only_metadata(out):
        differs = other_settings(stored_path, current, ignore, upgrade)
        if differs:
            raise ConfigError(
                f"{out} holds a result of other settings: {differs}; choose another "
                "output folder (or delete that one)"
            )
    out.mkdir(parents=True, exist_ok=True)
    # The command first: a config.yaml with no command.txt beside it is not bgap's.
    write_atomic(out / COMMAND, command() + "\n")
    write_atomic(stored_path, OmegaConf.to_yaml(conf, resolve=True))
    return out


COMMAND = "command.txt"
"""The command line a run folder's outputs came from (:func:`save_run_metadata`)."""

METADATA = (CONFIG, COMMAND, LOCK)


def only_metadata(folder: Path) -> bool:
    """Whether ``folder`` holds nothing but a command's metadata (an interrupted command's
    before it wrote anything): another command may take it over, nothing is lost. A lone
    ``config.yaml`` is not that (bgap writes ``command.txt`` before it): it may be a user's."""
    names = {p.name for p in folder.iterdir()}
    return names <= set(METADATA) and COMMAND in names


def _written_by_bgap(file: Path) -> bool:
    """A ``command.txt`` that :func:`save_run_metadata` wrote (a kill before its
    ``config.yaml`` leaves it alone in the folder), or the temporary file of a
    :func:`write_atomic` a kill stopped before its rename (metadata included)."""
    if _TEMPORARY.fullmatch(file.name):
        return True
    try:
        return file.name == COMMAND and file.read_text().startswith("python ")
    except (OSError, UnicodeDecodeError):
        return False


def refuse_foreign(folder: Path) -> None:
    """Refuse an output folder that holds files no bgap command wrote (no ``config.yaml``
    beside them): they are the user's, and a command would overwrite them."""
    if not folder.is_dir() or (folder / CONFIG).exists():
        return
    files = sorted(
        p.name
        for p in folder.iterdir()
        if p.is_file() and p.name != LOCK and not _written_by_bgap(p)
    )
    if files:
        shown = ", ".join(files[:3]) + (f" and {len(files) - 3} more" if len(files) > 3 else "")
        raise ConfigError(
            f"{folder} holds files no bgap command wrote ({shown}); choose a new or empty "
            "output folder"
        )


_TEMPORARY = re.compile(r"\..+\.\d+\.tmp(\.[^.]+)?")
"""The name :func:`write_atomic` writes into before its rename: ``.<stem>.<pid>.tmp<suffix>``."""


def write_atomic(path: Path, data: str | bytes | Callable[[Path], Any]) -> Path:
    """Write ``path`` whole or not at all: into a temporary name beside it, then renamed
    (a kill leaves the previous file or none, never half of one). ``data``: text, bytes,
    or a function that writes the file at the path it is given."""
    path = Path(path)
    # the same suffix: writers such as SB3's save add theirs to a name without it
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")  # see _TEMPORARY
    try:
        if callable(data):
            data(tmp)
        elif isinstance(data, bytes):
            tmp.write_bytes(data)
        else:
            tmp.write_text(data)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path
