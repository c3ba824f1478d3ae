"""The README's and getting-started's sample of the main job is what ``python -m bgap.run``
prints today: the same table and verdict lines, number for number (slow: the main job
trains two policies, about a minute on 2 cores)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = ("README.md", "docs/getting-started.md")


def _sample(page: str) -> list[str]:
    """The result lines of the page's main-job sample: the table and the verdicts."""
    text = (ROOT / page).read_text(encoding="utf-8")
    block = next(b for b in re.findall(r"```text\n(.*?)```", text, re.S) if "beat idle" in b)
    return [line for line in block.splitlines() if _is_result(line)]


def _is_result(line: str) -> bool:
    return bool(re.match(r"(policy |behavior_rich|default|idle|idm|random|rule)", line))


@pytest.mark.slow
def test_the_pages_sample_of_the_main_job_is_what_it_prints(tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "bgap.run", f"root={tmp_path}"],
        cwd=tmp_path,
        env={**os.environ, "COLUMNS": "200"},
        capture_output=True,
        text=True,
        timeout=1800,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    printed = [line for line in done.stdout.splitlines() if _is_result(line)]
    for page in PAGES:
        assert _sample(page) == printed, f"{page}'s sample drifted: rerun python -m bgap.run"
