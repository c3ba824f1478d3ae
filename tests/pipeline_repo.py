"""A throwaway copy of the repository's DVC pipeline on tiny parameters, for the pipeline
tests. The pipeline is split among test files by stage so that pytest-xdist's workers
(one file each) build and run their parts at the same time."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parent.parent
MADE_BY_A_STAGE = ("behavior/calibrated", "reward/recipe", "agent/recipe", "cmetric/tuned")
"""Presets that stages write into ``results/presets``: left out of the copy so that the stages
must write them again (the copy keeps the pipeline's other presets)."""


def run(args: list[str], cwd: Path) -> str:
    """Run a command in the copy (its own package and conf/ first on the path); assert it
    succeeds and return what it printed."""
    env = {**os.environ, "PYTHONPATH": str(cwd)}
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env['PATH']}"
    done = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return done.stdout + done.stderr


def make_repo(repo: Path, stages: set[str], edit: Callable[[dict], None]) -> Path:
    """Copy the package and the pipeline into the empty folder ``repo``, keep only
    ``stages`` of dvc.yaml, let ``edit`` shrink params.yaml, make it a git and DVC
    repository and run ``dvc repro``. Returns ``repo``."""
    from tests.conftest import warm_compiled_kernels

    warm_compiled_kernels()  # the copy below keeps numba's cache: no compiling per stage
    shutil.copytree(ROOT / "bgap", repo / "bgap")
    shutil.copytree(ROOT / "results/presets", repo / "results/presets")
    shutil.copy(ROOT / ".dvcignore", repo / ".dvcignore")
    pipeline = yaml.safe_load((ROOT / "dvc.yaml").read_text())
    missing = stages - set(pipeline["stages"])
    assert not missing, f"no such stages in dvc.yaml: {sorted(missing)}"
    pipeline["stages"] = {k: v for k, v in pipeline["stages"].items() if k in stages}
    for stage in pipeline["stages"].values():
        stage.pop("frozen", None)  # the copy makes every preset afresh, the recipe's too
    (repo / "dvc.yaml").write_text(yaml.safe_dump(pipeline, sort_keys=False))
    for name in MADE_BY_A_STAGE:
        (repo / f"results/presets/{name}.yaml").unlink(missing_ok=True)
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    edit(params)
    (repo / "params.yaml").write_text(yaml.safe_dump(params))
    git = ["git", "-c", "user.email=t@t", "-c", "user.name=t"]
    run(["git", "init", "-q"], repo)
    run([*git, "add", "-A"], repo)
    run([*git, "commit", "-qm", "study"], repo)
    run(["dvc", "init", "-q"], repo)
    run(["dvc", "repro"], repo)
    return repo
