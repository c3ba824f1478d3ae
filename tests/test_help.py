"""Every command the README's commands table names answers ``--help`` briefly.

``python -m bgap.<command> --help`` must exit 0 and fit on a screen (at most 40 lines: what
the command does, its main options with their defaults, where the full config is
documented). The commands start in parallel, one process each, since most of the time is
each interpreter importing its command.
"""

from __future__ import annotations

import os
import subprocess
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
    "bgap.parity",
    "bgap.bench",
    "bgap.pipeline",
)
MAX_LINES = 40


@pytest.fixture(scope="module")
def answers(tmp_path_factory) -> dict[str, tuple[int, str]]:
    """Each command's exit status and output (stdout and stderr), all run at once, from an
    empty folder so that nothing a command might write lands in the repository."""
    cwd = tmp_path_factory.mktemp("help")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "COLUMNS": "100"}
    running = {
        cmd: subprocess.Popen(
            [sys.executable, "-m", cmd, "--help"],
            cwd=cwd,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        for cmd in COMMANDS
    }
    done = {}
    for cmd, proc in running.items():
        try:
            out, _ = proc.communicate(timeout=300)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, _ = proc.communicate()
            out = f"(no answer within 300 s)\n{out}"
        done[cmd] = (proc.returncode, out)
    return done


@pytest.mark.parametrize("command", COMMANDS)
def test_help_exits_0_in_at_most_40_lines(command, answers):
    status, out = answers[command]
    lines = out.rstrip("\n").splitlines()
    assert status == 0, f"python -m {command} --help exited {status}:\n{out[-3000:]}"
    assert lines, f"python -m {command} --help printed nothing"
    assert len(lines) <= MAX_LINES, (
        f"python -m {command} --help printed {len(lines)} lines (at most {MAX_LINES}):\n"
        + "\n".join(lines[:60])
    )


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
