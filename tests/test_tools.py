"""The developer tools (benchmarks, the pipeline's code deps and relock) run from a checkout
as the docs say, outside the installed library, with the commands' one-line errors."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _tool(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)  # fmt: skip


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["tools/bench.py", "fly"], "invalid choice: 'fly'"),
        (["tools/bench.py", "sim", "--seconds", "-1"], "--seconds: '-1' must be a finite number"),
        (["tools/relock.py", "relock"], "the following arguments are required: stages"),
    ],
)
def test_a_tools_bad_option_is_one_line_and_status_2(args, says):
    done = _tool(*args)
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert says in done.stderr and done.stderr.startswith(args[0])


def test_the_pipelines_code_deps_are_current_and_the_library_ships_no_tool():
    done = _tool("tools/relock.py", "deps")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "0 stage(s) whose code deps differ" in done.stdout
    for module in ("bgap.bench", "bgap.experiments.bench"):
        assert importlib.util.find_spec(module) is None


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["-m", "bgap", "bench", "sim"], "python tools/bench.py in a checkout"),
        (["-m", "bgap.pipeline", "relock", "train"], "python tools/relock.py deps|relock"),
    ],
)
def test_the_commands_that_became_tools_say_where_they_went(args, says):
    done = _tool(*args)
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert says in done.stderr
