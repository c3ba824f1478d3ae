"""Hydra plumbing shared by every command: registering schemas, composing, validating.

YAML files under ``bgap/conf`` (package data) hold values; dataclasses are their schema,
each beside its concern or its command (``bgap.sim.config``, ``bgap.experiments.config``,
...), and each command hands its schemas (``SCHEMAS``: ConfigStore entries) to :func:`app`
or :func:`compose`, which register them in Hydra's ConfigStore when the command starts,
never at import. A wrong type or an unknown key fails when Hydra composes the config;
ranges are checked in ``__post_init__``, which runs when :func:`validate` turns the
composed config into objects, first thing in every entry point, before any work starts.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import sys
import warnings
from collections.abc import Callable, Iterable
from typing import Any

import hydra
from hydra import compose as hydra_compose
from hydra import initialize_config_dir
from hydra.core.config_store import ConfigStore
from hydra.core.global_hydra import GlobalHydra
from omegaconf import DictConfig, OmegaConf

from bgap.common.cli import run
from bgap.common.errors import ConfigError, check
from bgap.common.presets import CONF_DIR, PIPELINE_DIR, group_options, is_group

Schema = tuple[Any, str, type]
"""A ConfigStore entry: (group or None, name, dataclass)."""

NOT_SAVED = "nothing was saved; rerun the command"


def register_configs(schemas: Iterable[Schema]) -> None:
    """Register ``schemas``; YAML files name them in their defaults list. Idempotent."""
    # The presets folder on the search path (bgap.presets) need not exist yet.
    warnings.filterwarnings(
        "ignore", message=r"provider=hydra\.searchpath in main, path=.* is not available"
    )
    if not OmegaConf.has_resolver("bgap.presets"):  # the search path's ${bgap.presets:}
        OmegaConf.register_new_resolver("bgap.presets", lambda: PIPELINE_DIR)
    _store_schemas(tuple(schemas))


@functools.cache
def _store_schemas(schemas: tuple[Schema, ...]) -> None:
    """Once per process and set: Hydra's ConfigStore is a process-wide singleton, and storing
    the schemas again (each converted to an OmegaConf node) was half the time of every
    :func:`compose`."""
    cs = ConfigStore.instance()
    for group, name, node in schemas:
        cs.store(group=group, name=name, node=node)


SEED_MAX = 2**32 - 1
"""The largest seed numpy's and SB3's generators accept."""


def _check_numbers(node: Any, prefix: str = "") -> None:
    """Every number of a config finite, and every ``*seed`` within :data:`SEED_MAX`: checked
    here once for all commands, before anything is written (a NaN duration or a seed numpy
    refuses would otherwise fail mid-run, after the run folder was made)."""
    items = node.items() if isinstance(node, dict) else enumerate(node)
    for key, value in items:
        name = f"{prefix}{key}" if isinstance(node, dict) else f"{prefix[:-1]}[{key}]"
        if isinstance(value, (dict, list)):
            _check_numbers(value, f"{name}.")
        elif isinstance(value, float) and not math.isfinite(value):
            check(False, name, value, "must be a finite number")
        elif isinstance(value, int) and not isinstance(value, bool) and "seed" in name:
            check(value >= 0, name, value, "must be >= 0 (numpy seeds are non-negative)")
            check(value <= SEED_MAX, name, value, f"must be <= {SEED_MAX} (numpy's largest seed)")


def validate(cfg: DictConfig) -> Any:
    """Instantiate the composed config as dataclasses, running every range check.

    Raises :class:`ConfigError` naming the offending key.
    """
    _check_numbers(OmegaConf.to_container(cfg, resolve=True))
    return OmegaConf.to_object(cfg)


def compose(config_name: str, overrides: list[str] | None, schemas: Iterable[Schema]) -> DictConfig:
    """Compose a config from the packaged ``conf/`` with command-line style overrides,
    outside any Hydra app (tests, Optuna trials). Unknown keys and wrong types raise here."""
    register_configs(schemas)
    overrides = keep_pipeline_presets(list(overrides or []))
    if GlobalHydra.instance().is_initialized():  # inside a Hydra app (its search path: conf/)
        return hydra_compose(config_name=config_name, overrides=list(overrides or []))
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        return hydra_compose(config_name=config_name, overrides=list(overrides or []))


def keep_pipeline_presets(overrides: list[str]) -> list[str]:
    """``overrides`` with the pipeline's presets kept first on a search path that one of
    them sets (``hydra.searchpath=[file://...]`` replaces the primary config's list, and
    the main job's defaults, ``reward=recipe agent=recipe``, live there)."""
    key = "hydra.searchpath=["
    return [
        f"{key}file://{PIPELINE_DIR}," + o[len(key) :]
        if o.startswith(key) and PIPELINE_DIR not in o and o != f"{key}]"
        else o
        for o in overrides
    ]


def load(cfg: DictConfig) -> Any:
    """:func:`validate` for command-line entry points; a bad value raises
    :class:`ConfigError`, which :func:`app` reports in one line. A key the schema does not
    know (Hydra's ``+key=value``, which the schema's objects would drop without a word) and a
    setting removed with ``~key`` (which its default would silently replace, while the saved
    config lacks it) are refused, so that a run records exactly what it used. Then the checks
    that read files (a schema's ``check_inputs``: replayed tables), which a config built
    anywhere else (a worker, a trial, a test) does not repeat."""
    obj = validate(cfg)
    if dataclasses.is_dataclass(obj):
        given = OmegaConf.to_container(cfg, resolve=True)
        _same_keys(given, dataclasses.asdict(obj), "")
    if hasattr(obj, "check_inputs"):  # the checks that read files: once, at the command
        obj.check_inputs()
    return obj


def _same_keys(given: Any, used: Any, prefix: str) -> None:
    """Refuse keys of the composed config ``given`` that the schema's objects ``used`` lack,
    and keys they have that ``given`` lacks, naming the first."""
    if not isinstance(given, dict) or not isinstance(used, dict):
        return
    for key in given:
        if key not in used:
            close = difflib.get_close_matches(str(key), [str(k) for k in used], n=1)
            hint = f"did you mean {prefix}{close[0]}?" if close else "drop it"
            raise ConfigError(
                f"+{prefix}{key}={given[key]!r} is not a setting of this command ({hint}); "
                "`--cfg job` lists every key"
            )
    for key in used:
        if key not in given:
            raise ConfigError(
                f"~{prefix}{key} removes a setting this command needs: set it instead "
                f"({prefix}{key}=...; `--cfg job` shows its default)"
            )
        _same_keys(given[key], used[key], f"{prefix}{key}.")


IGNORED_BY_HYDRA = ("hydra.run.dir", "hydra.sweep.dir", "hydra.output_subdir")
"""Hydra's output settings, which bgap's commands do not use (:mod:`bgap.common.runs`)."""


def _refuse_ignored(arg: str) -> None:
    raise ConfigError(
        f"{arg} is not used: bgap writes no Hydra output folder; give the command's own "
        "output setting (out=, run_dir= or root=) instead"
    )


def _refuse_removed(arg: str) -> None:
    group = arg[1:].split("=")[0]
    names = group_options(group)
    raise ConfigError(
        f"{arg} removes the {group} preset, which this command needs: choose one instead "
        f"({group}={'|'.join(names)})"
    )


def _help_text(config_name: str) -> str | None:
    """``--help``'s text read from ``<config_name>.yaml``'s ``hydra.help`` when its template
    names only other ``hydra.help`` keys, or None (Hydra answers then).

    Written by hand because Hydra composes the whole config and lists every config group,
    loading each preset through the schemas, before filling the template (5 s per
    ``--help``), although bgap's templates print none of it. Hydra's ``string.Template``
    placeholders (``$CONFIG``, ``$APP_CONFIG_GROUPS``, ...) send the command to Hydra.
    """
    node = OmegaConf.load(f"{CONF_DIR}/{config_name}.yaml")
    help_cfg = OmegaConf.select(node, "hydra.help")
    if help_cfg is None or "template" not in help_cfg:
        return None
    try:  # resolved alone: an interpolation outside hydra.help fails here
        text = OmegaConf.to_container(OmegaConf.create({"hydra": {"help": help_cfg}}), resolve=True)
    except Exception:  # noqa: BLE001 - any failure to resolve alone: Hydra answers
        return None
    template = text["hydra"]["help"]["template"]
    return None if "$" in template else template


def app(
    config_name: str, prog: str, schemas: Iterable[Schema], on_interrupt: str = NOT_SAVED
) -> Callable[[Callable[[DictConfig], Any]], Callable[[], Any]]:
    """``@app("train", "bgap.train", SCHEMAS)``: a command's ``main(dcfg)`` as a command-line
    program over the packaged config ``<config_name>.yaml``, with the schemas registered first (not
    as an import side effect).

    Plain ``key=value`` overrides are composed here, so that every known mistake ends in one
    line and exit status 2 (:mod:`bgap.common.cli`); options (``--help``, ``--cfg job``, ``-m`` for
    multirun) and ``hydra.*`` overrides go to Hydra's own command line.
    """

    def decorator(task: Callable[[DictConfig], Any]) -> Callable[[], Any]:
        @functools.wraps(task)
        def reported(dcfg: DictConfig) -> Any:  # Hydra's own reporting would print a trace
            return run(prog, lambda: task(dcfg), on_interrupt)

        hydra_task = hydra.main(version_base="1.3", config_path=CONF_DIR, config_name=config_name)(
            reported
        )

        @functools.wraps(task)
        def main() -> Any:
            register_configs(schemas)
            args = sys.argv[1:]
            ignored = [a for a in args if a.split("=")[0].lstrip("+~") in IGNORED_BY_HYDRA]
            if ignored:  # switched off in every config: bgap names its folders itself
                return run(prog, lambda: _refuse_ignored(ignored[0]), on_interrupt)
            removed = [a for a in args if a.startswith("~") and is_group(a[1:].split("=")[0])]
            if removed:  # the schema's default would stand in for the preset, unsaid
                return run(prog, lambda: _refuse_removed(removed[0]), on_interrupt)
            if args in (["--help"], ["-h"]) and (text := _help_text(config_name)) is not None:
                print(text)
                raise SystemExit(0)
            if any(a.startswith(("-", "hydra.", "hydra/", "+hydra", "~hydra")) for a in args):
                sys.argv[1:] = keep_pipeline_presets(args)
                return hydra_task()
            return run(prog, lambda: task(compose(config_name, args, schemas)), on_interrupt)

        return main

    return decorator
