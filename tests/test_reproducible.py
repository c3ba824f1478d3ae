"""The committed results are the pipeline's outputs for the committed code and parameters."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


_ARMS = ["main", "authors", "mix0", "mix50", "mix100"]
_LEARNERS = ["learner-dqn", "learner-qrdqn", "learner-ppo"]
_DONE = {
    "evaluate_baselines",
    "evaluate@main",
    "evaluate@mix0",
    "evaluate@mix50",
    "evaluate@mix100",
    "train@main-dense",
    "zoo@main-dense",
    "train@main-sparse",
    "zoo@main-sparse",
    "train@mix0-sparse",
    "zoo@mix0-sparse",
    "train@mix0-dense",
    "zoo@mix0-dense",
    "train@mix50-sparse",
    "zoo@mix50-sparse",
    "train@mix50-dense",
    "zoo@mix50-dense",
    "train@mix100-sparse",
    "zoo@mix100-sparse",
    "train@mix100-dense",
    "zoo@mix100-dense",
    "train_learner@learner-ppo-sparse",
    "train_learner@learner-ppo-dense",
    "train_learner@learner-dqn-sparse",
    "zoo@learner-dqn-sparse",
    "train_learner@learner-dqn-dense",
    "zoo@learner-dqn-dense",
    "train_learner@learner-qrdqn-sparse",
    "zoo@learner-qrdqn-sparse",
    "zoo@learner-ppo-dense",
    "zoo@learner-ppo-sparse",
}
"""Rerun stages whose new lock is committed."""
RERUNNING: set[str] = (
    {f"train@{a}-{d}" for a in _ARMS for d in ("sparse", "dense")}
    | {f"train_learner@{a}-{d}" for a in _LEARNERS for d in ("sparse", "dense")}
    | {f"zoo@{a}-{d}" for a in _ARMS + _LEARNERS for d in ("sparse", "dense")}
    | {f"evaluate@{a}" for a in _ARMS + _LEARNERS}
    | {"evaluate_baselines", "figures"}
) - _DONE
"""Stages whose committed lock predates a change to what they compute, being rerun, or not
run yet: the study retrained with the per-kilometre checkpoint rule on 100 validation
episodes, each stage's policies exported to the zoo and evaluated from it, every
evaluation recording its traffic inputs (the baselines' too), on the 30-scene replay
tables; ``figures`` once every evaluation is rerun (until then it refuses the older arms'
replay cells, which played the 10-scene tables). Each must still
be stale (a rerun stage leaves this set in the same commit); no other stage may be."""


def test_a_fresh_clone_reports_no_changed_dependency_parameter_or_command(tmp_path):
    """``dvc status`` in a clone of the committed tree: outputs not pulled yet are fine
    (models and episodes live in the DVC cache), changed code, parameters or commands are
    not (they mean the committed results came from other code)."""
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("needs a git checkout")
    clone = tmp_path / "clone"
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
    dvc = Path(sys.executable).parent / "dvc"
    done = subprocess.run(
        [str(dvc), "status", "--json"], cwd=clone, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    stale = {}
    for stage, changes in json.loads(done.stdout or "{}").items():
        for change in changes:
            if change in ("changed command", "always changed"):
                stale[stage] = change
            elif isinstance(change, dict):
                # a dependency that is another stage's output not pulled yet reads "deleted"
                deps = {k: v for k, v in change.get("changed deps", {}).items() if v != "deleted"}
                if deps or "changed command" in change:
                    stale[stage] = deps or change
    unexpected = {k: v for k, v in stale.items() if k not in RERUNNING}
    assert not unexpected, json.dumps(unexpected, indent=1)[:3000]
    assert RERUNNING <= set(stale), f"rerun, remove from RERUNNING: {RERUNNING - set(stale)}"
