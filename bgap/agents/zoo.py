"""The zoo: the study's trained policies in the repository, by name.

    zoo:main/sparse/behavior_rich/s0        one policy
    zoo:main/*/behavior_rich/*              a glob over arm, density, family and seed

Each policy is ``zoo/<arm>/<density>/<family>/s<seed>.zip`` with its card ``s<seed>.yaml``
beside it. The archive is the model file Stable-Baselines3 (or sb3-contrib) wrote, in the
smallest form its own ``load`` still reads strictly and that acts exactly as the trained
model: the optimizer's moment estimates are dropped (its hyperparameters stay, so the
optimizer loads), the networks (the target network included, which SB3's strict load needs)
are kept bit for bit, and the archive is written with fixed timestamps, order and
compression, so that exporting an unchanged policy again gives the same bytes.

The card says what the policy is and how it was chosen: arm, family, density and seed; its
algorithm, network and observation; its reward, agent and profile presets; the checkpoint
kept and by what rule, with that checkpoint's validation; and the settings the policy must be
played under (:data:`PLAYED_UNDER`). The evaluation's test episodes of a zoo policy are under
``results/evaluation/<arm>/`` (the card cannot hold them: the evaluation reads the zoo).

Where the zoo is: the ``BGAP_ZOO`` environment variable, else ``zoo/`` beside the package
(an editable install or a clone), else ``zoo/`` in the working folder.
"""

from __future__ import annotations

import fnmatch
import io
import os
import zipfile
from pathlib import Path
from typing import Any

import yaml

from bgap.common.errors import ConfigError
from bgap.common.runs import read_or_refuse

PREFIX = "zoo:"
ENV_ZOO = "BGAP_ZOO"
ARCHIVE_TIME = (1980, 1, 1, 0, 0, 0)
"""Every archive entry's timestamp (zip's earliest): the bytes depend on the policy only."""
KEPT_ENTRIES = (
    "data",
    "policy.pth",
    "policy.optimizer.pth",
    "pytorch_variables.pth",
    "_stable_baselines3_version",
)
"""The SB3 archive entries a zoo policy keeps, in this order. ``system_info.txt`` (the
training machine's OS and versions, printed by ``load(print_system_info=True)``) is dropped:
it differs between machines and the card records the versions."""
PLAYED_UNDER = ("observed_vehicles", "ego_speeds", "policy_frequency", "simulation_frequency")
"""Environment settings a policy's network was trained for: playing it under others is
refused unless the user overrides (traffic, mix and radius may differ: the study tests
exactly that)."""


def is_zoo(spec: Any) -> bool:
    """Whether ``spec`` is a zoo name (``zoo:...``)."""
    return isinstance(spec, str) and spec.startswith(PREFIX)


def root() -> Path:
    """The zoo folder (module docstring)."""
    if os.environ.get(ENV_ZOO):
        return Path(os.environ[ENV_ZOO])
    beside = Path(__file__).resolve().parents[2] / "zoo"
    return beside if beside.is_dir() else Path("zoo")


def name_of(path: Path, zoo: Path | None = None) -> str:
    """``zoo:<arm>/<density>/<family>/s<seed>`` of the archive ``path``."""
    rel = path.resolve().relative_to((zoo or root()).resolve()).with_suffix("")
    return PREFIX + rel.as_posix()


def entries(zoo: Path | None = None) -> list[Path]:
    """Every policy archive of the zoo, sorted."""
    zoo = zoo or root()
    return sorted(zoo.glob("*/*/*/s*.zip")) if zoo.is_dir() else []


def resolve(spec: str, zoo: Path | None = None) -> list[Path]:
    """The archives a zoo name or glob names: one line and :class:`ConfigError` for a name
    that is not in the zoo or a glob that matches nothing."""
    zoo = zoo or root()
    pattern = spec[len(PREFIX) :].strip("/")
    if pattern.count("/") != 3:
        raise ConfigError(
            f"{spec!r} is not a zoo name: write zoo:<arm>/<density>/<family>/s<seed> "
            "(globs allowed, e.g. zoo:main/dense/behavior_rich/*)"
        )
    found = [
        p for p in entries(zoo) if fnmatch.fnmatchcase(name_of(p, zoo)[len(PREFIX) :], pattern)
    ]
    if found:
        return found
    known = sorted({"/".join(name_of(p, zoo)[len(PREFIX) :].split("/")[:3]) for p in entries(zoo)})
    what = "glob matches nothing" if any(c in pattern for c in "*?[") else "is not in the zoo"
    raise ConfigError(
        f"{spec!r} {what} ({zoo}); the zoo holds {', '.join(known) or 'no policy'}: "
        "list it with `ls zoo/*/*/*`"
    )


def resolve_one(spec: str, zoo: Path | None = None) -> Path:
    """The one archive ``spec`` names; a glob of several is refused in one line."""
    found = resolve(spec, zoo)
    if len(found) > 1:
        names = ", ".join(name_of(p, zoo) for p in found[:3])
        raise ConfigError(
            f"{spec!r} names {len(found)} policies ({names}, ...) where one is played: "
            "name one seed, e.g. .../s0"
        )
    return found[0]


def card(archive: Path) -> dict[str, Any]:
    """The card of a zoo archive (``{}`` for a model file that is not in the zoo)."""
    path = Path(archive).with_suffix(".yaml")
    if not path.exists():
        return {}
    return read_or_refuse(
        lambda: yaml.safe_load(path.read_text()) or {},
        f"{path} is not a readable zoo card",
        "restore it with `git checkout -- zoo`",
    )


def policy_name(archive: Path) -> str:
    """The name the study's tables give the policy (``<arm>/<density>/<density>-<family>-
    s<seed>``), from its card; the zoo name's path for an archive without one."""
    c = card(archive)
    if "policy" in c:
        return str(c["policy"])
    return name_of(archive)[len(PREFIX) :]


def compact_archive(model_zip: Path) -> bytes:
    """The zoo's form of an SB3 ``model.zip`` (module docstring), as bytes."""
    # Imported here: torch loads only where a policy is exported.
    import torch

    with zipfile.ZipFile(model_zip) as source:
        present = set(source.namelist())
        missing = {"data", "policy.pth"} - present
        if missing:
            raise ConfigError(f"{model_zip} has no {sorted(missing)}: not an SB3 model file")
        parts = {name: source.read(name) for name in KEPT_ENTRIES if name in present}
    for name in [n for n in parts if n.endswith("optimizer.pth")]:
        state = torch.load(io.BytesIO(parts[name]), map_location="cpu", weights_only=False)
        state["state"] = {}  # Adam's moment estimates: only training reads them
        buffer = io.BytesIO()
        torch.save(state, buffer)
        parts[name] = buffer.getvalue()
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as archive:
        for name in KEPT_ENTRIES:
            if name in parts:
                info = zipfile.ZipInfo(name, ARCHIVE_TIME)
                info.compress_type = zipfile.ZIP_DEFLATED
                info.external_attr = 0o644 << 16
                archive.writestr(info, parts[name], compresslevel=9)
    return out.getvalue()


def played_under(archive: Path) -> dict[str, Any]:
    """The settings of :data:`PLAYED_UNDER` the card records (``{}`` without a card)."""
    return dict(card(archive).get("played_under", {}))


OVERRIDE_FIX = "add zoo_override=true to play it anyway"


def check_played_under(
    archive: Path, env: dict[str, Any], override: bool = False, fix: str = OVERRIDE_FIX
) -> None:
    """Refuse, in one line naming both values and ``fix``, to play a zoo policy under other
    settings of :data:`PLAYED_UNDER` than it was trained for, unless ``override``."""
    keys = {"ego_speeds": ("action", "target_speeds")}
    for key, wanted in played_under(archive).items():
        if key == "observed_vehicles":  # the network's input: check_rows refuses it, always
            continue
        path = keys.get(key, (key,))
        have: Any = env
        for part in path:
            have = have.get(part) if isinstance(have, dict) else None
        if have is None or override:
            continue
        if _as_plain(have) != _as_plain(wanted):
            raise ConfigError(
                f"{name_of(archive)} was trained with {key}={_shown(wanted)}, this "
                f"environment has {key}={_shown(have)}: play it in the environment it was "
                f"trained for, or {fix}"
            )


def _shown(value: Any) -> str:
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(f"{float(v):g}" for v in value) + "]"
    return f"{float(value):g}" if isinstance(value, (int, float)) else str(value)


def _as_plain(value: Any) -> Any:
    if isinstance(value, (list, tuple)):
        return [float(v) for v in value]
    return float(value) if isinstance(value, (int, float)) else value
