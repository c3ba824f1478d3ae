"""Preset files: the configuration shipped inside the package, the presets the pipeline
writes, and presets users write.

Hydra composes every command from ``bgap/conf`` (package data, so a non-editable install
finds it). The presets the pipeline's DVC stages write (the calibrated drivers, the recipes,
the tuned CMetric and rule-based ego) live outside the package, in ``results/presets`` of
the checkout (:data:`PIPELINE_DIR`; a wheel ships them as ``bgap/presets``), so that an
installed bgap never changes. Presets written by a user's run of ``bgap.calibrate`` or
``bgap.sweep`` go under that run's output folder, ``<root>/presets/<group>/<name>.yaml``.
Hydra finds both through its search path, which every command's primary config extends with
``${bgap.presets:}`` (the pipeline's) and then ``${oc.env:BGAP_PRESETS,outputs/presets}``
(the default root needs nothing more; another folder: ``BGAP_PRESETS=/path/presets`` or
``hydra.searchpath=[file:///path/presets]``). A packaged or pipeline preset of the same name
comes first, so the pipeline's presets cannot be shadowed.
"""

from __future__ import annotations

import copy
import functools
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf

from bgap.common.errors import ConfigError
from bgap.common.runs import write_atomic

CONF_DIR = str(Path(__file__).resolve().parent.parent / "conf")
"""The packaged configuration: Hydra's primary config folder."""


def _pipeline_dir() -> Path:
    shipped = Path(CONF_DIR).parent / "presets"  # a wheel (pyproject.toml: package-dir)
    return shipped if shipped.is_dir() else Path(CONF_DIR).parents[1] / "results" / "presets"


PIPELINE_DIR = str(_pipeline_dir())
"""The presets the pipeline's stages write: ``results/presets`` of the checkout, or the copy
a wheel ships as ``bgap/presets``. On Hydra's search path after the packaged ones."""


SHIPPED = (CONF_DIR, PIPELINE_DIR)
"""The shipped preset folders in Hydra's order: a name in the first wins."""


def preset_path(group: str, name: str) -> Path:
    """The shipped preset ``<group>/<name>.yaml`` Hydra would select (:data:`SHIPPED`'s
    first that holds it; the packaged path where none does)."""
    found = (Path(d, group, f"{name}.yaml") for d in SHIPPED)
    return next((p for p in found if p.exists()), Path(CONF_DIR, group, f"{name}.yaml"))


def user_preset(root: str | Path, group: str, name: str) -> Path:
    """Where a user's run under ``root`` writes preset ``group=name`` by default:
    ``<root>/presets/<group>/<name>.yaml``, on the search path with the default root."""
    return Path(root) / "presets" / group / f"{name}.yaml"


def group_options(group: str) -> list[str]:
    """The shipped presets of config group ``group`` (packaged and the pipeline's)."""
    return sorted({p.stem for d in SHIPPED for p in Path(d, group).glob("*.yaml")})


def is_group(key: str) -> bool:
    """Whether ``key`` names a shipped preset group (``env``, ``behavior``, ``rule``)."""
    return "." not in key and any(Path(d, key).is_dir() for d in SHIPPED)


def load_preset(schema: type, path: str | Path) -> Any:
    """A config-group preset file as a validated ``schema`` object, without Hydra's search
    path (its ``defaults`` list, naming the schema, is ignored)."""
    values = OmegaConf.load(path)
    values.pop("defaults", None)
    return OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(schema), values))


def shipped(schema: type, group: str, name: str, missing: str | None = None) -> Any:
    """The shipped preset ``<group>/<name>.yaml`` (:func:`preset_path`) read through
    ``schema``: a fresh copy of a file read once per version (a validated load costs ~25 ms,
    and every environment built reads Table I). Missing: None, or, given ``missing`` (what
    is wrong and its fix), one line of it and the group's presets."""
    path = preset_path(group, name)
    if not path.exists():
        if missing is None:
            return None
        raise ConfigError(f"{missing}; use one of {group_options(group)}")
    stat = path.stat()
    return copy.deepcopy(_read(schema, str(path), stat.st_mtime_ns, stat.st_size))


@functools.lru_cache(maxsize=32)
def _read(schema: type, path: str, mtime_ns: int, size: int) -> Any:
    return load_preset(schema, path)


def write_preset(node: Any, group: str, path: str | Path, note: str, owner: str) -> Path:
    """Write dataclass ``node`` as a preset of config group ``group`` (``group=<stem>`` then
    selects it when ``path`` is ``<search path>/<group>/<stem>.yaml``), headed by the comment
    ``note``, whole or not at all. Null values are left out: the groups written so (behavior,
    reward, agent) default every optional field to null.

    ``owner``, part of ``note``, names the run that writes it (its study or report): an
    existing file whose first line does not hold it is another run's preset or a user's file,
    and is refused rather than replaced (the same run, resumed, rewrites its own)."""
    path = Path(path)
    if owner not in note:
        raise ValueError(f"the note must name the owner {owner!r}")  # a caller's bug
    check_owner(path, owner)
    path.parent.mkdir(parents=True, exist_ok=True)
    body = OmegaConf.to_yaml(OmegaConf.structured(node))
    body = "\n".join(line for line in body.splitlines() if not line.endswith(": null"))
    return write_atomic(path, f"# {note}\ndefaults:\n  - base_{group}\n{body}\n")


def check_owner(path: str | Path, owner: str) -> None:
    """Refuse a preset file at ``path`` whose first line does not name ``owner``: another
    run's preset or a user's file (:func:`write_preset`; a search checks before it starts)."""
    path = Path(path)
    if not path.exists():
        return
    try:
        first = path.read_text().partition("\n")[0]
    except (OSError, UnicodeDecodeError):
        first = ""
    if owner not in first:
        raise ConfigError(
            f"{path} holds a preset this run did not write ({first[:80] or 'not a preset'}"
            "); give the preset another path (preset=... or a new root), or remove that file"
        )


def selection_hint(group: str, path: str | Path) -> str:
    """How to use a preset written to ``path``: the override, and the search path it needs
    when it is not under the default presets folder."""
    path = Path(path).resolve()
    name = path.stem
    hint = f"{group}={name}"
    if preset_path(group, name).resolve() == path:
        return hint
    if preset_path(group, name).exists():
        return (
            f"{hint} selects the shipped preset of that name (packaged or the pipeline's), "
            "which shadows this file: write it under another name"
        )
    folder = path.parent.parent
    default = (Path.cwd() / "outputs" / "presets").resolve()
    if folder != default:
        hint += f" hydra.searchpath=[file://{folder}]"
    return hint
