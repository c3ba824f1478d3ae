"""Every command the README's commands table names answers ``--help`` briefly.

``python -m bgap.<command> --help`` must exit 0 and fit on a screen (at most 40 lines: what
the command does, its main options with their defaults, where the full config is
documented). Each command runs as ``python -m`` runs it (``runpy``, its module as
``__main__``), in this process: a process per command spent most of its time importing torch
again (15 commands, 90 s of CPU). ``tests/test_layout.py`` runs commands in processes of
their own.
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

import pytest

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
    "bgap.bench",
    "bgap.pipeline",
    "bgap.zoo",
    "bgap.watch",
)
MAX_LINES = 40


ARGPARSE_COMMANDS = (
    "bgap.cmetric.boundary",
    "bgap.figures",
    "bgap.select",
    "bgap.parity",
    "bgap.bench",
    "bgap.pipeline",
)
HYDRA_COMMANDS = tuple(c for c in COMMANDS if c not in ARGPARSE_COMMANDS)
"""The commands whose ``--help`` Hydra would answer (the others parse with argparse)."""


def _help(command: str, capsys, monkeypatch) -> tuple[int, str]:
    """``python -m <command> --help``'s exit status and output (stdout and stderr)."""
    monkeypatch.setattr(sys, "argv", [command, "--help"])
    try:
        runpy.run_module(command, run_name="__main__", alter_sys=True)
        status = 0
    except SystemExit as done:
        status = done.code if isinstance(done.code, int) else (0 if done.code is None else 1)
    out = capsys.readouterr()
    return status, out.out + out.err


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
