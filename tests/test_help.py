"""Every command the README's commands table names answers ``--help`` briefly.

``python -m bgap.<command> --help`` must exit 0 and fit on a screen (at most 40 lines: what
the command does, its main options with their defaults, where the full config is
documented). Each command runs as ``python -m`` runs it (``runpy``, its module as
``__main__``), in this process: a process per command spent most of its time importing torch
again (15 commands, 90 s of CPU). ``tests/test_layout.py`` runs commands in processes of
their own.

The defaults a help text states are the composed config's (``--cfg job``), so the text
cannot drift from the config; ``bgap --version`` prints the installed version.
"""

from __future__ import annotations

import re
import runpy
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

ROOT = Path(__file__).resolve().parent.parent

COMMANDS = (
    "bgap.simulate",
    "bgap.train",
    "bgap.evaluate",
    "bgap.run",
    "bgap.sweep",
    "bgap.recipe",
    "bgap.calibrate",
    "bgap.cmetric",
    "bgap.cmetric.search",
    "bgap.cmetric.boundary",
    "bgap.datasets",
    "bgap.figures",
    "bgap.select",
    "bgap.parity",
    "bgap.pipeline",
    "bgap.zoo",
    "bgap.watch",
    "bgap.tune_rule",
)
MAX_LINES = 40


HYDRA_COMMANDS = COMMANDS
"""The commands whose ``--help`` Hydra would answer: every one (one dialect)."""


def _run(command: str, args: list[str], capsys, monkeypatch) -> tuple[int, str]:
    """``python -m <command> ARGS``'s exit status and output (stdout and stderr)."""
    monkeypatch.setattr(sys, "argv", [command, *args])
    try:
        runpy.run_module(command, run_name="__main__", alter_sys=True)
        status = 0
    except SystemExit as done:
        status = done.code if isinstance(done.code, int) else (0 if done.code is None else 1)
    out = capsys.readouterr()
    return status, out.out + out.err


def _help(command: str, capsys, monkeypatch) -> tuple[int, str]:
    """``python -m <command> --help``'s exit status and output (stdout and stderr)."""
    return _run(command, ["--help"], capsys, monkeypatch)


def _composed(command: str, capsys, monkeypatch) -> dict[str, Any]:
    """The config ``python -m <command>`` composes with no overrides (``--cfg job``)."""
    status, out = _run(command, ["--cfg", "job"], capsys, monkeypatch)
    assert status == 0, f"python -m {command} --cfg job exited {status}:\n{out[-3000:]}"
    return yaml.safe_load(out)


# runpy's note when a command's package imported the command's module first (bgap.cmetric
# imports bgap.cmetric.boundary): python -m runs it afresh all the same
@pytest.mark.filterwarnings("ignore:.*found in sys.modules after import of package")
@pytest.mark.parametrize("command", COMMANDS)
def test_help_exits_0_in_at_most_40_lines(command, capsys, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)  # nothing a command might write lands in the repository
    monkeypatch.setenv("COLUMNS", "100")
    status, out = _help(command, capsys, monkeypatch)
    lines = out.rstrip("\n").splitlines()
    assert status == 0, f"python -m {command} --help exited {status}:\n{out[-3000:]}"
    assert lines, f"python -m {command} --help printed nothing"
    assert len(lines) <= MAX_LINES, (
        f"python -m {command} --help printed {len(lines)} lines (at most {MAX_LINES}):\n"
        + "\n".join(lines[:60])
    )
    assert not any(tmp_path.iterdir()), f"{command} --help wrote {list(tmp_path.iterdir())}"


@pytest.mark.filterwarnings("ignore:.*found in sys.modules after import of package")
@pytest.mark.parametrize(
    "command",
    [c if c == "bgap.run" else pytest.param(c, marks=pytest.mark.slow) for c in HYDRA_COMMANDS],
)
def test_help_is_hydras_own_text(command, capsys, monkeypatch, tmp_path):
    """``--help`` read from the config's template (``bgap.common.config._help_text``) prints
    what Hydra prints when it composes the config and fills the same template."""
    from bgap.common import config

    monkeypatch.chdir(tmp_path)
    texts = []
    read = config._help_text
    monkeypatch.setattr(config, "_help_text", lambda name: texts.append(read(name)) or texts[-1])
    fast = _help(command, capsys, monkeypatch)
    assert texts and texts[-1] is not None, f"{command} --help was not read from its template"
    monkeypatch.setattr(config, "_help_text", lambda config_name: None)
    assert fast == _help(command, capsys, monkeypatch)


def test_the_list_is_the_readmes_commands_table():
    """The commands above are exactly those the README's commands table names."""
    import re

    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    named = {
        cmd
        for line in readme.splitlines()
        if line.startswith("| `bgap.")
        for cmd in re.findall(r"`(bgap\.[a-z_.]+)`", line.split("|")[1])
    }
    assert named == set(COMMANDS), (sorted(named - set(COMMANDS)), sorted(set(COMMANDS) - named))


STATED = re.compile(r"(?:^\s*|\s{2})([a-z_][a-z0-9_.]*)=(\S+)")
"""An option with its default as a help text states it: ``key=value`` at the start of a line
or after two spaces (an example inside a sentence, ``(the paper's setting: reward=highway
agent=dqn)``, follows one space)."""
LITERAL = re.compile(r"^(?:[a-z0-9_./-]*[a-z0-9_/-][a-z0-9_./-]*|\[[a-z0-9_.,/-]*\])$")
"""A default spelled out (``0.5``, ``false``, ``outputs/simulate``, ``[idle,random,rule]``,
``[]``), not a placeholder (``DIR``, ``URL``, ``...``) or a choice (``sparse|dense``)."""


def _stated_defaults(text: str) -> dict[str, str]:
    """Every ``key=value`` whose value is a literal default, as the help text spells it."""
    stated = {}
    for line in text.splitlines():
        for key, value in STATED.findall(line):
            if LITERAL.match(value):
                stated[key] = value
    return stated


def _same(value: str, actual: Any) -> bool:
    """Whether the stated ``value`` is the composed ``actual``: a group by its preset's name,
    a number to the decimals the text gives (``mu=80.35`` for 80.354...)."""
    stated = yaml.safe_load(value)
    if isinstance(actual, dict):
        actual = actual.get("name")
    numbers = (int, float)
    if isinstance(stated, numbers) and isinstance(actual, numbers):
        if isinstance(stated, bool) or isinstance(actual, bool):
            return stated is actual
        decimals = len(value.partition(".")[2])
        return round(float(actual), decimals) == float(stated)
    return stated == actual


@pytest.mark.filterwarnings("ignore:.*found in sys.modules after import of package")
@pytest.mark.parametrize(
    "command",
    [c if c == "bgap.run" else pytest.param(c, marks=pytest.mark.slow) for c in HYDRA_COMMANDS],
)
def test_help_states_the_composed_defaults(command, capsys, monkeypatch, tmp_path):
    """Each default the help text states (``mix=0.5``, ``seeds=[]``, ``resume=false``) is the
    composed config's, key for key."""
    monkeypatch.chdir(tmp_path)
    status, text = _help(command, capsys, monkeypatch)
    assert status == 0, text[-3000:]
    stated = _stated_defaults(text)
    assert stated, f"python -m {command} --help states no default"
    composed = _composed(command, capsys, monkeypatch)
    wrong = {}
    for key, value in stated.items():
        node: Any = composed
        for part in key.split("."):
            assert isinstance(node, dict) and part in node, f"{command} --help: no key {key}"
            node = node[part]
        if not _same(value, node):
            wrong[key] = (value, node)
    assert not wrong, f"{command} --help states defaults the config does not have: {wrong}"


@pytest.mark.filterwarnings("ignore:.*found in sys.modules after import of package")
def test_run_help_states_the_seeds_default(capsys, monkeypatch, tmp_path):
    """``bgap.run``'s training seeds: the help once said ``seeds=[0,1,2]`` where the config
    trains ``[seed]`` (``seeds: []``)."""
    monkeypatch.chdir(tmp_path)
    _, text = _help("bgap.run", capsys, monkeypatch)
    stated = re.search(r"(?<![\w.])seeds=(\[[^\]]*\])", text)
    assert stated, f"bgap.run --help states no seeds default:\n{text}"
    assert yaml.safe_load(stated.group(1)) == _composed("bgap.run", capsys, monkeypatch)["seeds"]


def test_version(capsys):
    """``bgap --version`` and ``bgap -V`` print ``bgap <version>``, the installed one."""
    from importlib.metadata import version

    from bgap.__main__ import main

    for flag in ("--version", "-V"):
        main([flag])
        assert capsys.readouterr().out == f"bgap {version('bgap')}\n"


def test_version_of_a_source_tree_never_installed(capsys, monkeypatch):
    """Without the distribution's metadata, the package's own ``__version__``."""
    import importlib.metadata

    import bgap
    from bgap.__main__ import main

    def missing(name: str) -> str:
        raise importlib.metadata.PackageNotFoundError(name)

    monkeypatch.setattr(importlib.metadata, "version", missing)
    main(["--version"])
    assert capsys.readouterr().out == f"bgap {bgap.__version__}\n"


def test_version_exits_0_and_bgap_alone_names_it(capsys):
    """As a user runs it: exit status 0; ``bgap`` alone lists the commands and ``--version``."""
    done = subprocess.run(
        [sys.executable, "-m", "bgap", "--version"], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert re.fullmatch(r"bgap \S+\n", done.stdout), done.stdout

    from bgap.__main__ import COMMANDS, main

    main([])
    usage = capsys.readouterr().out
    assert "--version" in usage.split("commands:")[0]
    assert all(f"  {name} " in usage for name in COMMANDS)
