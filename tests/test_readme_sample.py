"""The README's and getting-started's sample of the main job is what ``python -m bgap.run``
prints today (slow: the main job trains two policies, about a minute on 2 cores).

The baselines' lines are scripted and must match number for number on every machine. The two
trained policies' lines are the same run after run on one machine, but three machines gave
three trainings with the kernels pinned (PyTorch promises the same numbers only on the same
platform), so for them the sample must match in every word but the numbers and the verdict
they lead to."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = ("README.md", "docs/getting-started.md")
LEARNED = ("behavior_rich", "default")
NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?")


def _sample(page: str) -> list[str]:
    """The result lines of the page's main-job sample: the table and the verdicts."""
    text = (ROOT / page).read_text(encoding="utf-8")
    block = next(b for b in re.findall(r"```text\n(.*?)```", text, re.S) if "beat idle" in b)
    return [line for line in block.splitlines() if _is_result(line)]


def _is_result(line: str) -> bool:
    return bool(re.match(r"(policy |behavior_rich|default|idle|idm|random|rule)", line))


def _machine_free(line: str) -> str:
    """The line as every machine prints it: a trained policy's numbers and verdict masked."""
    if not line.startswith(LEARNED):
        return line
    if " collisions" in line and ": " in line[line.index(" collisions") :]:
        line = line.rpartition(": ")[0] + ": <verdict>"
    return re.sub(r"\s+", " ", NUMBER.sub("#", line))


def test_masking_keeps_the_baselines_and_the_words():
    rule = "rule 0.50 sparse 180 100 1.0 [ 0.2, 5.4]"
    assert _machine_free(rule) == rule
    learned = "behavior_rich against IDM (mix 0.5): 4.9 collisions at 29.41 m/s: beaten by it"
    masked = "behavior_rich against IDM (mix #): # collisions at # m/s: <verdict>"
    assert _machine_free(learned) == masked


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
    printed = [_machine_free(line) for line in done.stdout.splitlines() if _is_result(line)]
    for page in PAGES:
        sample = [_machine_free(line) for line in _sample(page)]
        assert sample == printed, f"{page}'s sample drifted: rerun python -m bgap.run"
