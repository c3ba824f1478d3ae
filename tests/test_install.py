"""A non-editable install works from any folder: the configuration ships inside the package."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PIPELINE = sorted((ROOT / "results/presets").rglob("*.yaml"))
"""The presets the pipeline's stages wrote."""


def _run(args: list[str], cwd: Path, env: dict) -> str:
    done = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return done.stdout + done.stderr


def _reuse_compiled_kernels(site: Path) -> None:
    """numba's cache of this checkout, for the installed copy: its index checks a source's
    size and modification time, so the copies get the originals' times (the wheel does not
    keep them). Only a shortcut: without it the installed copy compiles its kernels itself."""
    from tests.conftest import warm_compiled_kernels

    warm_compiled_kernels()
    for source in (ROOT / "bgap").rglob("*.py"):
        copy = site / source.relative_to(ROOT)
        os.utime(copy, ns=(source.stat().st_atime_ns, source.stat().st_mtime_ns))
        cache = source.parent / "__pycache__"
        for index in cache.glob(f"{source.stem}.*.nb[ic]"):
            (copy.parent / "__pycache__").mkdir(exist_ok=True)
            shutil.copy2(index, copy.parent / "__pycache__" / index.name)


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> tuple[Path, dict]:
    """The wheel built from a copy of this checkout, unpacked as an installed package ahead of
    the editable install on the path; returns (that site folder, the environment to run in)."""
    tmp_path = tmp_path_factory.mktemp("install")
    env = {**os.environ, "PYTHONPATH": ""}
    source = tmp_path / "source"  # setuptools builds in the source folder: use a copy
    shutil.copytree(ROOT / "bgap", source / "bgap", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(ROOT / "results/presets", source / "results/presets")  # the pipeline's
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, source / name)
    _run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "-q",
            "-w",
            str(tmp_path / "dist"),
            str(source),
        ],
        tmp_path,
        env,
    )
    (wheel,) = (tmp_path / "dist").glob("bgap-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert "bgap/conf/run.yaml" in names and "bgap/conf/behavior/paper.yaml" in names
    assert "bgap/experiments/sweeps/reward.yaml" in names
    assert "bgap/presets/behavior/calibrated.yaml" in names  # results/presets, shipped
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    _reuse_compiled_kernels(site)
    env["PYTHONPATH"] = str(site)  # ahead of the editable install of this checkout
    return site, env


def test_the_installed_package_ships_its_configuration(installed, tmp_path):
    """The fast half of the slow test below: every config file of the checkout is in the
    wheel, and a command composes and runs from another folder on the installed copy."""
    site, env = installed
    shipped = {p.relative_to(site) for p in (site / "bgap").rglob("*.yaml")}
    ours = {p.relative_to(ROOT) for p in (ROOT / "bgap").rglob("*.yaml")}
    ours |= {"bgap/presets" / p.relative_to(ROOT / "results/presets") for p in PIPELINE}
    assert ours <= shipped, sorted(ours - shipped)
    where = _run([sys.executable, "-c", "import bgap; print(bgap.__file__)"], tmp_path, env)
    assert str(site) in where
    args = ["episodes=1", "env.duration=2", "backend=vector", "out=sim"]
    _run([sys.executable, "-m", "bgap.simulate", *args], tmp_path, env)
    assert "name: paper" in (tmp_path / "sim/config.yaml").read_text()
    # a preset the pipeline wrote (results/presets in the checkout) is found in the wheel's
    calibrated = [*args[:-1], "out=sim_calibrated", "behavior=calibrated"]
    _run([sys.executable, "-m", "bgap.simulate", *calibrated], tmp_path, env)
    assert "name: calibrated" in (tmp_path / "sim_calibrated/config.yaml").read_text()


def test_the_wheel_lists_every_package():
    """pyproject.toml lists the packages (setuptools' finder cannot map results/presets into
    the wheel): every package under bgap/ is listed, and bgap.presets."""
    listed = set(
        tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    )
    found = {
        ".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "bgap").rglob("__init__.py")
    }
    assert listed == found | {"bgap.presets"}


@pytest.mark.slow
def test_the_built_wheel_runs_the_main_job_and_calibration_from_another_folder(installed, tmp_path):
    site, env = installed
    work = tmp_path
    out = _run([sys.executable, "-m", "bgap.run", "profile=tiny", "root=out"], work, env)
    assert "results in out/results/" in out
    assert list((work / "out/results").glob("*/summary.csv"))
    out = _run(
        [
            sys.executable,
            "-m",
            "bgap.calibrate",
            "calibrate.trials=2",
            "calibrate.rounds=1",
            "calibrate.episodes=1",
            "calibrate.duration=10",
            "root=cal",
        ],
        work,
        env,
    )
    preset = work / "cal/presets/behavior/user_calibrated.yaml"
    assert preset.exists() and (work / "cal/calibration/table.md").exists()
    assert "behavior=user_calibrated hydra.searchpath=[file://" in out
    # the written preset is found through the search path by a later command
    _run(
        [
            sys.executable,
            "-m",
            "bgap.simulate",
            "behavior=user_calibrated",
            "behavior.converged=true",  # 2 trials do not converge: used knowingly
            "episodes=1",
            "env.duration=3",
            "backend=vector",
            "out=sim",
            f"hydra.searchpath=[file://{work}/cal/presets]",
        ],
        work,
        env,
    )
    assert "name: user_calibrated" in (work / "sim/config.yaml").read_text()


def _pins() -> dict[str, str]:
    """``requirements/lock.txt``'s exact versions by normalised package name."""
    from packaging.utils import canonicalize_name

    pins = {}
    for line in (ROOT / "requirements/lock.txt").read_text().splitlines():
        if "==" in line and not line.lstrip().startswith("#"):
            name, version = line.split("==")
            pins[canonicalize_name(name.strip())] = version.split()[0].strip()
    return pins


def test_the_lock_file_pins_every_dependency_within_pyproject_and_is_what_is_installed():
    """Every requirement of pyproject.toml (core and the locked extras) has one exact
    version in the lock, inside the range pyproject.toml allows; the installed versions are
    the lock's (the README's commands install with ``-c requirements/lock.txt``)."""
    import tomllib
    from importlib.metadata import PackageNotFoundError, version

    from packaging.requirements import Requirement
    from packaging.utils import canonicalize_name
    from packaging.version import Version

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]
    locked = ("dev", "cluster", "docs", "sumo")
    wanted = [*project["dependencies"], *(r for e in locked for r in extras[e])]
    pins = _pins()
    for text in wanted:
        req = Requirement(text)
        name = canonicalize_name(req.name)
        assert name in pins, f"{req.name} is not in requirements/lock.txt: run tools/lock.sh"
        assert req.specifier.contains(Version(pins[name]), prereleases=True), (text, pins[name])
    for name in ("torch", "numpy", "numba", "gymnasium", "stable-baselines3", "highway-env"):
        try:
            installed = Version(version(name))
        except PackageNotFoundError:
            continue
        assert installed == Version(pins[name]), (name, str(installed), pins[name])


def test_ci_runs_the_readmes_test_command_and_both_set_up_commands_install_from_the_lock():
    import re

    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    setup = readme.split("## Set up")[1].split("\n## ")[0]
    commands = re.findall(r"```bash\n(.*?)\n```", setup, re.S)
    assert len(commands) == 2, commands
    assert all("-c requirements/lock.txt" in c for c in commands), commands
    assert commands[1] in (ROOT / ".ci/run").read_text(encoding="utf-8")
