"""Keeping the DVC pipeline honest about its code: each stage's code dependencies, and
relocking stages whose code moved without changing what it computes.

``python tools/relock.py deps`` lists, per stage, the bgap modules its command imports
(directly or not, function-level imports included) that ``dvc.yaml`` does not list, and the
listed ones it no longer imports; ``--write`` makes ``dvc.yaml`` list exactly them.
``python tools/relock.py relock STAGE ...`` reruns the stages at a rehearsal budget from
the last commit and from the working tree and records their new lock only when both wrote
byte-identical outputs (see :func:`relock`).
"""

from __future__ import annotations

import ast
import contextlib
import csv
import filecmp
import json
import os
import pickle
import re
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from bgap.common.cli import run
from bgap.common.errors import ConfigError
from bgap.common.runs import CHECKPOINT_STATE, COMMAND, CONFIG

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run as a script: tools.*
from tools.cli import OneLineParser  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
"""The repository (this file is tools/relock.py)."""


def _module_file(root: Path, name: str) -> Path | None:
    base = root / Path(*name.split("."))
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path
    return None


def _imports(root: Path, path: Path) -> set[str]:
    """The bgap modules ``path`` imports, function-level imports included (ast, no import)."""
    package = ".".join(path.relative_to(root).with_suffix("").parts)
    if path.name == "__init__.py":
        package = package.rsplit(".", 1)[0] + ".__init__"
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")[: -node.level]
                base = ".".join([*parts, base] if base else parts)
            names.add(base)
            names.update(f"{base}.{a.name}" for a in node.names)
        elif _is_command_entry(node):  # a command's shim imports its module by name
            names.add(node.args[0].value)
    return {n for n in names if n == "bgap" or n.startswith("bgap.")}


def _is_command_entry(node: ast.AST) -> bool:
    """``command("bgap.x.y")`` (:func:`bgap.runner.numerics.command`): the module named is
    imported when the command runs."""
    return (
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Name)
        and node.func.id == "command"
        and len(node.args) == 1
        and isinstance(node.args[0], ast.Constant)
        and isinstance(node.args[0].value, str)
    )


def closure(module: str, root: Path = ROOT) -> list[str]:
    """Every file of bgap that running ``python -m <module>`` may execute: the module, what it
    imports, transitively, and each package's ``__init__.py`` on the way (repo-relative)."""
    todo, seen = [module], set()
    files: set[Path] = set()
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        parts = name.split(".")
        for k in range(1, len(parts)):  # the packages it lives in are imported first
            todo.append(".".join(parts[:k]))
        path = _module_file(root, name)
        if path is None:
            continue
        files.add(path)
        if (
            path.name == "__init__.py"
            and (path.parent / "__main__.py").is_file()
            and name == module
        ):
            files.add(path.parent / "__main__.py")
            todo.extend(_imports(root, path.parent / "__main__.py"))
        todo.extend(_imports(root, path))
    return sorted(str(p.relative_to(root)) for p in files)


def _stage_module(cmd: str) -> str | None:
    found = re.search(r"python -m (bgap[\w.]*)", cmd)
    return found.group(1) if found else None


def _is_code(dep: str) -> bool:
    """A Python module of the package: what :func:`closure` finds. Its data files (presets,
    the results page's template) are listed in ``dvc.yaml`` by hand and kept."""
    return dep.startswith("bgap/") and dep.endswith(".py")


def code_deps(dvc_yaml: Path = ROOT / "dvc.yaml") -> dict[str, tuple[list[str], list[str]]]:
    """Per stage of ``dvc_yaml``: (the code files its command runs, the code deps it lists)."""
    from ruamel.yaml import YAML  # DVC's own YAML library, which keeps dvc.yaml's comments

    stages = YAML().load(dvc_yaml.read_text())["stages"]
    out = {}
    for name, stage in stages.items():
        body = stage.get("do", stage)
        module = _stage_module(str(body.get("cmd", "")))
        if module is None:
            continue
        listed = [str(d) for d in body.get("deps", []) if _is_code(str(d))]
        out[name] = (closure(module, dvc_yaml.parent), listed)
    return out


def write_code_deps(dvc_yaml: Path = ROOT / "dvc.yaml") -> list[str]:
    """Make every stage of ``dvc_yaml`` list exactly the code its command runs (conf files and
    other stages' outputs kept as they are); returns the stages changed."""
    # Imported here: ruamel (DVC's YAML library, keeps comments) for the deps rewrite only.
    from ruamel.yaml import YAML

    yaml = YAML()
    yaml.width = 4096
    yaml.indent(mapping=2, sequence=4, offset=2)
    doc = yaml.load(dvc_yaml.read_text())
    changed = []
    for name, (needed, listed) in code_deps(dvc_yaml).items():
        if sorted(listed) == needed:
            continue
        body = doc["stages"][name].get("do", doc["stages"][name])
        rest = [d for d in body.get("deps", []) if not _is_code(str(d))]
        body["deps"] = [*needed, *rest]
        changed.append(name)
    with dvc_yaml.open("w") as f:
        yaml.dump(doc, f)
    return changed


REHEARSAL_GRID = """defaults:
  - base_grid
name: rehearsal
mixes: [0.0, 1.0]
densities: [sparse, dense]
radii: [180.0, 30.0]
"""
"""The evaluation grid of a rehearsal: the tiny grid at both densities."""


REHEARSED = ".rehearsed"
"""Marks a finished rehearsal in its folder: ``--work`` of an earlier run reuses it."""

LAST = ("recipe", "recipe_learner", "calibrate")
"""Stages rehearsed after all others: they rewrite presets other stages read."""


def replay_cells(params: dict) -> str:
    """``replay.cells`` as params.yaml must hold it: every table of ``replay.tables`` as
    ``density:<root>/replay/<table>/trajectories.parquet`` (evaluate's ``grid.replays``;
    DVC builds no list from a dict, so params.yaml spells it out)."""
    tables = params["replay"]["tables"]
    return (
        "["
        + ",".join(
            f"{t['density']}:{params['root']}/replay/{k}/trajectories.parquet"
            for k, t in tables.items()
        )
        + "]"
    )


def rehearsal(params: dict) -> None:
    """Shrink ``params`` (params.yaml) in place to a rehearsal of every stage that finishes in
    minutes: the tiny profile and grid, one seed per training, a few trials and episodes.
    Every stage (and every ``foreach`` item) is kept, so each has a rehearsal."""
    # the tiny grid at both densities, since the study trains at both (REHEARSAL_GRID,
    # written into the rehearsal's copy only)
    params.update(profile="tiny", grid="rehearsal", eval_episodes=2)
    validate = " profile.eval_every_episodes=2 profile.eval_during_training=2"
    for item in params["study"].values():
        item.update(seeds="[0]", settings=item["settings"] + validate)
    for item in params.get("learner_arms", {}).values():  # (older commits have no learner arms)
        item.update(seeds="[0]", settings=item["settings"] + validate, profile="tiny")
    for item in params.get("selections", {}).values():  # one seed per arm: groups of one
        item.update(group=1, episodes=2)
    params["calibrate"]["trials"] = 2
    params["recipe"].update(profile="tiny", trials=2, candidates=1, check_episodes=10)
    params["recipe"].update(check_seeds="[0,1]", sweep_episodes=4)
    if "learner_recipe" in params:  # (older commits have no learner recipes)
        learner = params["learner_recipe"]
        learner.update(trials=2, candidates=1, check_episodes=10)
        learner.update(check_seeds="[0,1]", sweep_episodes=4)
        if "profile" in learner:  # (before each learner named its own profile)
            learner["profile"] = "tiny"
        for item in params["learners"].values():
            if "profile" in item:
                item["profile"] = "tiny"
    if "tune_rule" in params:  # (older commits have no tuned rule)
        params["tune_rule"].update(trials=2, episodes=2)
    params["parity"] = {"episodes": 2, "duration": 2}
    params["calibrate_sumo"].update(trials=2, episodes=1, warmup=2)
    if "replay" in params:  # (older commits have no replay cells)
        params["replay"].update(scenes=1, duration=30)
    search = params["cmetric_search"]
    search.update(trials=2, radii="[null]")
    for item in (*search["data"].values(), *search["sumo"].values()):
        item["episodes"] = 2 if "mix" in item else 1


def _rehearse(tree: Path, stages: list[str], log: Path) -> None:
    """Run ``stages`` (and what they depend on) at the rehearsal budget in ``tree``, a copy
    of a checkout: its own git and DVC repository, so nothing outside it is touched."""

    params = yaml.safe_load((tree / "params.yaml").read_text())
    rehearsal(params)
    (tree / "bgap/conf/grid/rehearsal.yaml").write_text(REHEARSAL_GRID)
    (tree / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    env = {**os.environ, "PYTHONPATH": str(tree)}
    git = ["git", "-c", "user.email=relock@bgap", "-c", "user.name=relock"]
    with log.open("w") as out:
        for cmd in (
            ["rm", "-rf", ".git", ".dvc"],
            ["git", "init", "-q"],
            [*git, "add", "-A"],
            [*git, "commit", "-qm", "rehearsal"],
            [sys.executable, "-m", "dvc", "init", "-q"],
        ):
            done = subprocess.run(cmd, cwd=tree, env=env, stdout=out, stderr=subprocess.STDOUT)
            if done.returncode != 0:
                raise ConfigError(
                    f"setting up the rehearsal in {tree} failed ({' '.join(cmd[:3])}): see {log}"
                )
        # one stage at a time, each after the stages it reads (the pipeline's graph), on the
        # committed presets: a stage that writes a preset (the recipe's unseeded sweep) runs
        # last, so that no other stage reads a rehearsal's preset instead of the checkout's
        # a copy holds no outputs (no DVC cache): the stages the named ones read from are
        # rehearsed too, before them (only the named stages are compared and relocked)
        rank, needed = _upstream_first(tree, stages)
        for stage in sorted(needed, key=lambda s: (s.split("@")[0] in LAST, rank[s])):
            cmd = [sys.executable, "-m", "dvc", "repro", "--force", "--single-item", stage]
            done = subprocess.run(cmd, cwd=tree, env=env, stdout=out, stderr=subprocess.STDOUT)
            if done.returncode != 0:
                raise ConfigError(
                    f"the rehearsal of {stage} failed in {tree}: its log is {log}; fix what it "
                    "says and rerun (finished rehearsals are kept)"
                )


def _upstream_first(tree: Path, stages: list[str]) -> tuple[dict[str, int], set[str]]:
    """Every stage of ``tree``'s pipeline ranked so that each comes after those whose
    outputs it reads (dvc.yaml's own order may put a data stage after its reader), and the
    names of ``stages`` (a ``foreach`` stage's name stands for all its items) with every
    stage they read from, directly or not, whose outputs the copy lacks (the DVC cache's:
    models, episodes)."""
    # Imported here: DVC's Python API takes ~1 s to import; only relocking needs it.
    import networkx as nx
    from dvc.repo import Repo

    graph = Repo(str(tree)).index.graph  # an edge runs from a stage to one it reads from
    order = reversed(list(nx.lexicographical_topological_sort(graph, key=str)))
    rank = {stage.name: k for k, stage in enumerate(order)}  # (addressing is relative to cwd)
    named = [n for n in graph if n.name in stages or n.name.split("@")[0] in stages]
    # an upstream stage whose outputs the copy holds (committed presets, tables) is not run:
    # the named stages read the checkout's files, as in the study
    missing = {n for n in graph if any(not (tree / str(o.def_path)).exists() for o in n.outs)}
    needed = {n.name for n in named} | {
        n.name for stage in named for n in nx.descendants(graph, stage) if n in missing
    }
    return rank, needed


def _outputs(tree: Path, stage: str) -> list[Path]:
    """Every file a stage writes (its outs, metrics and plots), relative to ``tree``."""
    # Imported here: DVC's Python API takes ~1 s to import; only relocking needs it.
    from dvc.repo import Repo

    # DVC resolves a stage's name against the dvc.yaml of the working folder, not the
    # repository's: from another folder it would read that folder's pipeline.
    with contextlib.chdir(tree), Repo(str(tree)) as repo:
        (found,) = repo.stage.collect(stage)
        paths = [tree / str(out.def_path) for out in found.outs]
    files: list[Path] = []
    for path in paths:
        files += sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    return [p.relative_to(tree) for p in files]


def _checkout(rev: str | None, into: Path, root: Path = ROOT) -> None:
    """The files of commit ``rev`` (None: the working tree, untracked files too, ignored ones
    not) copied into ``into``."""

    if rev is not None:
        archive = subprocess.run(["git", "archive", rev], cwd=root, capture_output=True, check=True)
        into.mkdir(parents=True)
        subprocess.run(["tar", "-x", "-C", str(into)], input=archive.stdout, check=True)
        return
    listed = (
        subprocess.run(
            ["git", "ls-files", "-co", "--exclude-standard", "-z"], cwd=root, capture_output=True
        )
        .stdout.decode()
        .split("\0")
    )
    for name in filter(None, listed):
        if (root / name).is_file():
            (into / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(root / name, into / name)


TB_EVENTS = "events.out.tfevents"
"""TensorBoard's event files: named by wall time, host and process, and holding wall times."""


def _same(a: Path, b: Path, moved: dict[str, str] | None = None) -> bool:
    """Whether two output files hold the same result. Byte for byte, but for zip archives
    (Stable-Baselines3's models), whose members are compared rather than the archives: each
    entry carries the time it was written, and SB3's ``data`` holds what no seed fixes
    (:func:`_sb3_data`). And for a run's resolved settings (``config.yaml``), where ``b``
    may hold settings that ``a``'s code did not have: every setting of ``a`` must be in
    ``b`` with the same value (a setting added with a default that reproduces the old
    results; the other outputs show whether it does), and the same for the settings that
    ``models.csv`` and the zoo's cards copy from it (:func:`_records_kept`). Likewise a
    training checkpoint's ``state.pkl`` (counters, running statistics, the environments'
    state), which may gain fields that later code keeps, and SB3's replay buffer
    (``replay.pkl``), compared by its fields (:func:`_kept`). A ``command.txt`` names the
    same program: its arguments follow the stage's command, which the lock records. A path
    that ``moved`` moved, as a setting's value, may be read at its new place (a frozen
    stage's record keeps the old one)."""
    if a.name == b.name == COMMAND:  # the command that made it: the stage's cmd, whose
        # form may change with the code (the lock records it); the program must be the same
        return a.read_text().split()[:3] == b.read_text().split()[:3]
    if a.name == CONFIG and b.name == CONFIG:
        old, new = yaml.safe_load(a.read_text()), yaml.safe_load(b.read_text())
        return _kept(old, new) or _kept(_moved_values(old, moved or {}), new)
    if a.name == b.name == MODELS:
        with a.open(newline="") as fa, b.open(newline="") as fb:
            return _records_kept(list(csv.DictReader(fa)), list(csv.DictReader(fb)))
    if a.suffix == b.suffix == ".yaml" and "zoo" in a.parts and "zoo" in b.parts:
        return _records_kept(yaml.safe_load(a.read_text()), yaml.safe_load(b.read_text()))
    if a.name == b.name and a.name in (CHECKPOINT_STATE, REPLAY):
        return _kept(pickle.loads(a.read_bytes()), pickle.loads(b.read_bytes()))
    if a.suffix != ".zip":
        return filecmp.cmp(a, b, shallow=False)
    with zipfile.ZipFile(a) as za, zipfile.ZipFile(b) as zb:
        if za.namelist() != zb.namelist():
            return False
        return all(
            _sb3_data(za.read(n)) == _sb3_data(zb.read(n))
            if n == "data"
            else za.read(n) == zb.read(n)
            for n in za.namelist()
        )


MODELS = "models.csv"
"""An evaluation's record of the run folders it played (each one's settings as JSON)."""


def _records_kept(old: Any, new: Any) -> bool:
    """Equal, except that a run's settings copied as a JSON object (``models.csv``'s
    ``settings`` column, a zoo card's records) may gain settings, as ``config.yaml`` may."""
    if isinstance(old, str) and isinstance(new, str) and old[:1] == new[:1] == "{":
        try:
            return _kept(json.loads(old), json.loads(new))
        except json.JSONDecodeError:
            return old == new
    if isinstance(old, dict) and isinstance(new, dict):
        return old.keys() == new.keys() and all(_records_kept(v, new[k]) for k, v in old.items())
    if isinstance(old, list) and isinstance(new, list):
        return len(old) == len(new) and all(map(_records_kept, old, new))
    return bool(old == new)


REPLAY = "replay.pkl"
"""An SB3 checkpoint's replay buffer (:mod:`bgap.experiments.training`)."""


def _sb3_data(data: bytes) -> dict[str, Any]:
    """SB3's ``data`` member without what no seed fixes: object addresses in its readable
    part (``<function ... at 0x7f...>``), the training's start (``start_time``, wall clock),
    its episodes' wall times (``ep_info_buffer``'s ``t``; returns and lengths are kept), and
    the spaces' pickled sampler (unseeded, never used in training; the spaces' readable
    fields are kept). The weights and optimiser state are separate members."""
    import base64

    import cloudpickle  # SB3's own serialiser (a dependency of SB3)

    found = json.loads(_unaddressed(data))
    found.pop("start_time", None)
    for key in ("observation_space", "action_space"):
        if isinstance(found.get(key), dict):
            found[key].pop(":serialized:", None)
    if isinstance(found.get("ep_info_buffer"), dict):
        episodes = cloudpickle.loads(base64.b64decode(found["ep_info_buffer"][":serialized:"]))
        found["ep_info_buffer"] = [{k: v for k, v in e.items() if k != "t"} for e in episodes]
    return found


def _kept(old: Any, new: Any) -> bool:
    """Whether ``new`` holds every setting of ``old`` with the same value (dicts may gain
    keys; sequences, arrays and tensors must be equal item by item, as anything else)."""
    if isinstance(old, dict) and isinstance(new, dict):
        return all(k in new and _kept(v, new[k]) for k, v in old.items())
    if type(old).__module__.startswith("torch") or type(new).__module__.startswith("torch"):
        import torch  # a checkpoint's optimiser or learner state: tensors, compared exactly

        if isinstance(old, torch.Tensor) or isinstance(new, torch.Tensor):
            tensors = isinstance(old, torch.Tensor) and isinstance(new, torch.Tensor)
            return tensors and old.dtype == new.dtype and torch.equal(old, new)
    if isinstance(old, np.ndarray) or isinstance(new, np.ndarray):
        arrays = isinstance(old, np.ndarray) and isinstance(new, np.ndarray)
        return arrays and old.dtype == new.dtype and np.array_equal(old, new, equal_nan=True)
    if type(old) is type(new) and type(old).__eq__ is object.__eq__ and hasattr(old, "__dict__"):
        # an object without its own equality (a replay buffer): by its fields
        return _kept(vars(old), vars(new))
    if isinstance(old, (list, tuple)) and isinstance(new, (list, tuple)):
        return len(old) == len(new) and all(_kept(x, y) for x, y in zip(old, new, strict=True))
    return bool(old == new)


def _moved_values(tree: Any, moved: dict[str, str]) -> Any:
    """``tree`` (a run's settings) with every string that names a path ``moved`` moved
    replaced by its new place (:func:`moved_to`)."""
    if isinstance(tree, dict):
        return {k: _moved_values(v, moved) for k, v in tree.items()}
    if isinstance(tree, list):
        return [_moved_values(v, moved) for v in tree]
    if isinstance(tree, str) and (new := moved_to(Path(tree), moved)) != Path(tree):
        return new.as_posix()  # other strings as they were (Path would normalise them)
    return tree


def _unaddressed(data: bytes) -> bytes:
    return re.sub(rb" at 0x[0-9a-f]+", b" at 0x", data)


def _scalars(folder: Path) -> list[tuple[str, int, float]]:
    """Every scalar (tag, step, value) TensorBoard logged in ``folder``, wall times aside:
    event times and the clock's own scalars (SB3's ``time/fps``, ``time/time_elapsed``)."""
    # Imported here: TensorBoard's reader loads only when a rehearsal is compared.
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    found = []
    for events in sorted(folder.glob(f"{TB_EVENTS}*")):
        acc = EventAccumulator(str(events), size_guidance={"scalars": 0})
        acc.Reload()
        tags = [tag for tag in acc.Tags()["scalars"] if tag not in WALL_CLOCK_TAGS]
        found += [(tag, e.step, e.value) for tag in tags for e in acc.Scalars(tag)]
    return sorted(found)


WALL_CLOCK_TAGS = ("time/fps", "time/time_elapsed")
"""SB3's logged scalars that measure the machine, not the training."""


def _code_files(root: Path, stages: list[str]) -> list[str]:
    """Every code file the ``stages`` run (``train`` or ``train@main-dense``): only those
    are recorded in their locks, so other stages' code may change meanwhile."""
    names = {s.split("@")[0] for s in stages}
    deps = code_deps(root / "dvc.yaml")
    return sorted({f for name in names if name in deps for f in deps[name][0]})


def _record_lock(repo: Any, stage: str) -> None:
    """``dvc commit --force`` of ``stage`` with its outputs, and the outputs of other stages
    it depends on, allowed to be missing (their lock entries are kept as they are). DVC's
    own commit also saves the run cache, which needs every dependency present."""
    with repo.lock:
        for found in repo.stage.collect(stage):
            found.save(allow_missing=True, run_cache=False)
            found.commit(allow_missing=True)
            found.dvcfile.dump(found, update_pipeline=False)


def moved_to(path: Path, moved: dict[str, str]) -> Path:
    """``path`` (relative to a tree) where the moves ``moved`` (old -> new: a file, or a
    folder and everything in it) put it; unmoved paths are returned as they are."""
    text = path.as_posix()
    for old, new in moved.items():
        old = old.rstrip("/")
        if text == old or text.startswith(old + "/"):
            return Path(new.rstrip("/") + text[len(old) :])
    return path


def differing(
    trees: dict[str, Path],
    base_files: list[Path],
    head_files: list[Path],
    moved: dict | None = None,
) -> list[str]:
    """The files of one stage that differ between the rehearsals in ``trees`` (``base``,
    ``head``, and ``again``: the base rehearsed once more, for stages that do not reproduce
    themselves, whose files that differ between its two runs are not compared): a file
    only one side wrote, or whose bytes differ (TensorBoard events: whose scalars differ).
    Each base file is compared at the path ``moved`` gives it in the head; the files are
    named by their head path."""
    moved = moved or {}
    base = {moved_to(Path(f), moved): Path(f) for f in base_files}  # head path -> base path
    files = sorted(set(base) | {Path(f) for f in head_files})
    events = {f.parent for f in files if f.name.startswith(TB_EVENTS)}
    files = [f for f in files if not f.name.startswith(TB_EVENTS)]
    again = trees.get("again")
    if again is not None:  # a file the base's two runs wrote differently is not compared
        files = [
            f
            for f in files
            if f not in base
            or ((again / base[f]).is_file() and _same(trees["base"] / base[f], again / base[f]))
        ]
    out = [
        str(f)
        for f in files
        if f not in base
        or not (trees["base"] / base[f]).is_file()
        or not (trees["head"] / f).is_file()
        or not _same(trees["base"] / base[f], trees["head"] / f, moved)
    ]
    for d in sorted(events):
        old = next((b.parent for h, b in base.items() if h.parent == d), d)
        if _scalars(trees["base"] / old) != _scalars(trees["head"] / d):
            out.append(str(d / TB_EVENTS))
    return out


def relock(
    stages: list[str],
    base: str = "HEAD",
    work: Path | None = None,
    root: Path = ROOT,
    unreproducible: bool = False,
    moved: dict[str, str] | None = None,
) -> dict[str, list]:
    """Record the new lock of ``stages`` whose code moved without changing what it computes.

    Both the commit ``base`` and the working tree run the stages at the rehearsal budget
    (:func:`rehearsal`) in copies of their own; only when every file each stage writes is
    byte-identical in both is the stage's lock rewritten (DVC's ``commit`` with the outputs
    allowed to be missing: the study's models are not on this machine); a stage whose files
    differ keeps its lock. Returns, per stage, the files that differ (empty: relocked). A
    stage whose outputs differ must be rerun (``dvc repro STAGE``), not relocked.

    ``unreproducible``: for stages that do not reproduce themselves (the recipe's sweep
    draws its trials unseeded, so that parallel workers never repeat one), the commit
    ``base`` is rehearsed twice; files that already differ between those two runs are not
    compared, every other file must still be identical.

    ``moved``: paths the change moved (old -> new, a file or a folder and everything in it,
    e.g. presets moved out of the package): a file the base wrote at an old path is
    compared with the head's at the new one (:func:`differing`).
    """

    # Imported here: DVC's Python API takes ~1 s to import; only relocking needs it.
    from dvc.repo import Repo

    work = Path(tempfile.mkdtemp(prefix="bgap-relock-")) if work is None else work
    trees = {"base": work / "base", "head": work / "head"}
    if unreproducible:
        trees["again"] = work / "again"
    for name, tree in trees.items():
        if (tree / REHEARSED).exists():  # a finished rehearsal of these stages, kept
            continue
        if tree.exists():  # an interrupted rehearsal: start it again
            shutil.rmtree(tree)
        _checkout(None if name == "head" else base, tree, root)
        print(
            f"rehearsing {', '.join(stages)} from {'the working tree' if name == 'head' else base}"
            f" in {tree} (log: {work / name}.log)",
            flush=True,
        )
        _rehearse(tree, stages, work / f"{name}.log")
        (tree / REHEARSED).write_text("\n".join(stages) + "\n")
    differs: dict[str, list] = {}
    with Repo(str(trees["head"])) as repo:
        expanded = [s.addressing for name in stages for s in repo.stage.collect(name)]
    for stage in expanded:
        base_files = _outputs(trees["base"], stage)
        differs[stage] = differing(trees, base_files, _outputs(trees["head"], stage), moved)
    changed = [
        f
        for f in _code_files(root, stages)
        if not filecmp.cmp(root / f, trees["head"] / f, shallow=False)
    ]
    if changed:  # the lock records the files as they are now, not as rehearsed
        raise ConfigError(f"code changed during the rehearsal: {', '.join(changed[:5])}; rerun")
    with Repo(str(root)) as repo:
        for stage in expanded:
            if not differs[stage]:  # only the stages whose every output is identical
                _record_lock(repo, stage)
    return differs


def main(argv: list[str] | None = None) -> None:

    parser = OneLineParser(prog="tools/relock.py", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    deps = sub.add_parser("deps", help="compare each stage's code deps with what it imports")
    deps.add_argument("--write", action="store_true", help="rewrite dvc.yaml's code deps")
    lock = sub.add_parser("relock", help="rewrite stages' locks after a result-neutral change")
    lock.add_argument(
        "stages", nargs="+", help="stage names as in dvc.yaml (train, train@main-dense)"
    )
    lock.add_argument("--base", default="HEAD", help="the commit to compare with (default HEAD)")
    lock.add_argument(
        "--work", type=Path, help="folder for the two rehearsals (default: a new temp folder)"
    )
    lock.add_argument(
        "--unreproducible",
        action="store_true",
        help="rehearse the base twice and compare only what reproduces (the recipe's sweep)",
    )
    lock.add_argument(
        "--moved",
        action="append",
        default=[],
        metavar="OLD=NEW",
        help="a path the change moved (a file or a folder), compared at its new place",
    )
    args = parser.parse_args(argv)
    if args.command == "relock":
        moved = dict(m.split("=", 1) for m in args.moved if "=" in m)
        if len(moved) != len(args.moved):
            bad = next(m for m in args.moved if "=" not in m)
            parser.error(f"--moved {bad!r} must be OLD=NEW (a path before and after the move)")
        differs = run(
            "tools/relock.py",
            lambda: relock(
                args.stages, args.base, args.work, unreproducible=args.unreproducible, moved=moved
            ),
            "no lock was rewritten; rerun with the same --work to reuse finished rehearsals",
        )
        bad = {s: f for s, f in differs.items() if f}
        for stage, files in bad.items():
            print(f"{stage}: outputs differ from {args.base}'s: {', '.join(files[:5])}")
        done = [s for s, f in differs.items() if not f]
        print(f"relocked {len(done)} stage(s) in dvc.lock: {', '.join(done) or 'none'}")
        if bad:
            print(f"refused {len(bad)}: their locks are unchanged; rerun them (dvc repro STAGE)")
            sys.exit(1)
        return
    if args.command == "deps":
        if args.write:
            print("dvc.yaml: code deps rewritten for", ", ".join(write_code_deps()) or "no stage")
            return
        stale = 0
        for name, (needed, listed) in code_deps().items():
            missing = sorted(set(needed) - set(listed))
            extra = sorted(set(listed) - set(needed))
            if missing or extra:
                stale += 1
                print(f"{name}: missing {missing}; not run {extra}")
        print(f"{stale} stage(s) whose code deps differ from what their command runs")
        sys.exit(1 if stale else 0)


if __name__ == "__main__":
    main()
