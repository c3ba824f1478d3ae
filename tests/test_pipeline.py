"""The DVC pipeline end to end on a tiny profile, in a throwaway git repository."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parent.parent


def _run(args: list[str], cwd: Path) -> str:
    env = {**os.environ, "PYTHONPATH": str(cwd)}  # the copied package, with its own conf/
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env['PATH']}"
    done = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return done.stdout + done.stderr


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory) -> Path:
    repo = tmp_path_factory.mktemp("study")
    for name in ("bgap", "conf"):
        shutil.copytree(ROOT / name, repo / name, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("dvc.yaml", "params.yaml"):
        shutil.copy(ROOT / name, repo / name)
    (repo / "conf/behavior/calibrated.yaml").unlink(missing_ok=True)  # the stage makes it
    params = yaml.safe_load((repo / "params.yaml").read_text())
    params.update(profile="tiny", seeds=[0], densities=["sparse"], grid="tiny", eval_episodes=4)
    params["calibrate"]["trials"] = 2
    params["parity"] = {"episodes": 3, "duration": 3}
    (repo / "params.yaml").write_text(yaml.safe_dump(params))
    _run(["git", "init", "-q"], repo)
    _run(["git", "-c", "user.email=t@t", "-c", "user.name=t", "add", "-A"], repo)
    _run(["git", "-c", "user.email=t@t", "-c", "user.name=t", "commit", "-qm", "study"], repo)
    _run(["dvc", "init", "-q"], repo)
    _run(["dvc", "repro"], repo)
    return repo


def _png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", f"{path} is not a PNG"
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


def test_every_stage_writes_its_outputs(pipeline):
    for name in (
        "conf/behavior/calibrated.yaml",
        "results/calibration/table.md",
        "results/calibration/scores.json",
        "outputs/pipeline/runs/sparse-behavior_rich-s0/model.zip",
        "outputs/pipeline/runs/sparse-default-s0/model.zip",
        "outputs/pipeline/evaluation/episodes.csv",
        "results/README.md",
        "results/table2.md",
        "results/claims.csv",
        "results/metrics.json",
        "results/parity/parity.csv",
        "dvc.lock",
    ):
        assert (pipeline / name).stat().st_size > 0, name
    # Fig. 4: one row per density (sparse only here) and three metric panels of 4 x 3.3 in
    width, height = _png_size(pipeline / "results/figures/fig4.png")
    assert (width, height) == (12 * 120, int(3.3 * 120))
    width, height = _png_size(pipeline / "results/figures/fig6.png")
    assert (width, height) == (int(5.5 * 120), int(3.4 * 120))
    assert "B-GAP (paper)" in (pipeline / "results/table2.md").read_text()
    assert "| claim" in (pipeline / "results/README.md").read_text()


def test_a_second_repro_does_nothing_and_a_parameter_reruns_only_its_stages(pipeline):
    assert "up to date" in _run(["dvc", "repro"], pipeline)
    params = yaml.safe_load((pipeline / "params.yaml").read_text())
    params["eval_episodes"] = 5
    (pipeline / "params.yaml").write_text(yaml.safe_dump(params))
    out = _run(["dvc", "repro"], pipeline)
    ran = {line.split("'")[1] for line in out.splitlines() if line.startswith("Running stage")}
    assert ran == {"evaluate", "figures"}, out[-2000:]
