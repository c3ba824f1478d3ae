"""The package's shape: the environment registers on ``import bgap``, one ``bgap`` command
reaches every command, the layering holds, and the pipeline lists the code it runs."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _python(code: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120
    )


def test_import_bgap_registers_the_environment_and_loads_no_simulator_learner_or_hydra():
    done = _python(
        "import sys, bgap, gymnasium as gym;"
        "heavy = [m for m in ('highway_env', 'torch', 'hydra', 'bgap.envs', 'bgap.sim')"
        " if m in sys.modules]; assert not heavy, heavy;"
        "assert 'bgap/BehaviorHighway-v0' in gym.registry;"
        "env = gym.make('bgap/BehaviorHighway-v0');"
        "print(type(env.unwrapped).__module__)"
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "bgap.envs.highway"


def test_cmetric_and_the_vocabulary_load_no_simulator():
    """CMetric knows no simulator: its command's modules and the shared vocabulary import
    neither highway-env nor bgap's simulators (the road's constants are bgap.traffic.road's)."""
    done = _python(
        "import sys, bgap.common.vocab, bgap.cmetric.boundary, bgap.cmetric.score;"
        "print([m for m in ('highway_env', 'bgap.sim', 'bgap.envs', 'bgap.traffic.road')"
        " if m in sys.modules])"
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_gymnasium_module_prefixed_id_works_without_an_import():
    done = _python(
        "import gymnasium as gym; env = gym.make('bgap:bgap/BehaviorHighway-v0');"
        "obs, _ = env.reset(seed=0); print(obs.shape)"
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().startswith("(")


def test_bgap_alone_lists_every_command_and_an_unknown_one_is_refused():
    from bgap.__main__ import COMMANDS

    done = subprocess.run(
        [sys.executable, "-m", "bgap"], cwd=ROOT, capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0, done.stderr
    commands = done.stdout.split("commands:\n", 1)[1]
    listed = {line.split()[0] for line in commands.splitlines() if line.startswith("  ")}
    assert listed == set(COMMANDS)
    for module, _ in COMMANDS.values():  # every command's module exists
        assert (ROOT / Path(*module.split("."))).with_suffix(".py").exists() or (
            ROOT / Path(*module.split(".")) / "__main__.py"
        ).exists(), module
    bad = subprocess.run(
        [sys.executable, "-m", "bgap", "trian"], cwd=ROOT, capture_output=True, text=True
    )
    assert bad.returncode == 2 and "unknown command 'trian'" in bad.stderr
    assert bad.stderr.count("\n") == 1, bad.stderr  # one line, no usage dump


def test_bgap_command_runs_the_same_program_as_python_m():
    """``bgap simulate ...`` and ``python -m bgap.simulate ...`` refuse a bad value alike."""
    outs = [
        subprocess.run(
            [sys.executable, "-m", *prog, "mix=2"], cwd=ROOT, capture_output=True, text=True
        )
        for prog in (["bgap", "simulate"], ["bgap.simulate"])
    ]
    assert [o.returncode for o in outs] == [2, 2]
    assert outs[0].stderr == outs[1].stderr and "mix" in outs[0].stderr


def test_top_level_holds_ten_domain_packages_two_floors_and_short_shims():
    """Ten packages named after the domain (traffic, simulators, agents, CMetric, ...) and
    two floors that are no domain: ``runner``, the plumbing of where work runs, between
    ``common`` and the agents (whose training monitor needs its Ctrl-C flag), which neither
    fits in the ground floor (it needs Ray, process pools and torch's threads) nor in a
    domain package; and ``commands``, the top floor, one module per command, so that no
    library module carries a command line."""
    entries = [p for p in (ROOT / "bgap").iterdir() if p.name != "__pycache__"]
    floors = ("conf", "runner", "commands")
    packages = [p.name for p in entries if p.is_dir() and p.name not in floors]
    assert len(packages) <= 10, packages
    for module in entries:
        if module.suffix == ".py" and module.name not in ("__init__.py", "__main__.py"):
            assert len(module.read_text().splitlines()) <= 5, module.name


def test_only_the_commands_have_a_command_line():
    """Every Hydra app (``@app``) and every ``main`` lives in :mod:`bgap.commands`, one module
    per command of ``bgap``'s table; a library module has neither, and every other entry
    (``bgap/<command>.py``, a package's ``__main__.py``) is a shim that names its command."""
    import ast

    from bgap.__main__ import COMMANDS

    shims = {"__main__.py"} | {f"{m.rsplit('.', 1)[-1]}.py" for m, _ in COMMANDS.values()}
    lines = []
    for path in sorted((ROOT / "bgap").rglob("*.py")):
        name = path.relative_to(ROOT / "bgap").as_posix()
        if name.startswith("commands/") or name == "__main__.py":
            continue
        tree = ast.parse(path.read_text())
        for node in tree.body:
            decorators = getattr(node, "decorator_list", [])
            apps = [
                d for d in decorators if isinstance(d, ast.Call) and ast.unparse(d.func) == "app"
            ]
            if getattr(node, "name", None) == "main" or apps:
                lines.append(f"{name}:{node.lineno}")
        if path.name == "__main__.py" or (path.parent == ROOT / "bgap" and path.name in shims):
            assert 'main = command("bgap.commands.' in path.read_text(), name
    assert not lines, lines
    commands = {p.stem for p in (ROOT / "bgap/commands").glob("*.py")} - {"__init__"}
    assert commands == {name.replace(".", "_") for name in COMMANDS}


KERNELS = {"bgap/sim/core.py"}
"""Modules exempt from the size limit: the simulator's compiled kernels, one model in one
place (split, each piece would lose the loop it belongs to)."""


def test_modules_stay_under_500_lines_and_functions_under_80():
    """The sizes a reader takes in at one sitting: every module of the package at most 500
    lines but the kernels, every function at most 80 (the limits the package was brought
    back under when they had crept over)."""
    import ast

    over = []
    for path in sorted((ROOT / "bgap").rglob("*.py")):
        name = path.relative_to(ROOT).as_posix()
        text = path.read_text()
        if name not in KERNELS and len(text.splitlines()) > 500:
            over.append(f"{name}: {len(text.splitlines())} lines")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                length = node.end_lineno - node.lineno + 1
                if length > 80:
                    over.append(f"{name}:{node.lineno} {node.name}: {length} lines")
    assert not over, over


def _lint_imports(root: Path, pythonpath: Path | None = None) -> set[str]:
    """The ids of the contracts in ``root/pyproject.toml`` that lint-imports (import-linter)
    finds broken in the ``bgap`` package first on ``pythonpath`` (the installed one without)."""
    env = {**os.environ, "COLUMNS": "300"}  # one contract a line, unwrapped
    if pythonpath is not None:
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(pythonpath), env.get("PYTHONPATH")]))
    done = subprocess.run(
        [sys.executable, "-c", "from importlinter.cli import lint_imports_command; "
         "lint_imports_command()", "--no-cache", "--no-logo"],
        cwd=root, env=env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    contracts = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["importlinter"]
    lines = done.stdout.splitlines()
    verdicts = {
        c["id"]: next((w for line in lines if line.startswith(c["name"] + " ")
                       for w in ("KEPT", "BROKEN") if w in line.split()), None)
        for c in contracts["contracts"]
    }  # fmt: skip
    report = done.stdout[-3000:] + done.stderr[-3000:]
    assert None not in verdicts.values(), report  # every contract was checked
    broken = {name for name, verdict in verdicts.items() if verdict == "BROKEN"}
    assert done.returncode == (1 if broken else 0), report
    return broken


def test_no_import_cycle_and_no_forbidden_edge():
    """The layering written in pyproject.toml ([tool.importlinter]): its floors, the imports
    forbidden beside them and no cycle between packages, function-level imports counted."""
    assert _lint_imports(ROOT) == set()


def _copy_of_the_project(tmp_path: Path) -> Path:
    copy = tmp_path / "project"
    shutil.copytree(ROOT / "bgap", copy / "bgap", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", copy / "pyproject.toml")
    return copy


# Each case adds imports to a copy of the package (module: line, the module made where it is
# missing); a chain of imports breaks a contract too (common -> sim: analysis -> common -> sim).
FLOORS, CYCLES = "floors", "no-cycles"
FORBIDDEN_IMPORTS = [
    ({"common/errors.py": "import bgap.experiments"}, {FLOORS, "experiments-on-top", CYCLES}),
    ({"common/errors.py": "from bgap.sim import rollout"},
     {FLOORS, "analysis-without-simulators", CYCLES}),
    ({"analysis/stats.py": "import bgap.agents.zoo"}, {"analysis-without-simulators"}),
    ({"sim/core.py": "from bgap import calibration"}, {"calibration-above-datasets", CYCLES}),
    ({"traffic/behaviors.py": "import bgap.cmetric"}, {FLOORS}),
    ({"traffic/scenario.py": "import bgap.analysis.episodes"}, {"analysis-apart", CYCLES}),
    ({"common/errors.py": "import bgap.common.runs"}, {CYCLES}),  # two modules of common
    # two new packages, no module cycle: a.x -> b.y and b.z -> a.w, a cycle of packages
    ({"a/__init__.py": "", "a/w.py": "", "a/x.py": "import bgap.b.y",
      "b/__init__.py": "", "b/y.py": "", "b/z.py": "import bgap.a.w"}, {CYCLES}),
    ({"runner/__init__.py": "import bgap.agents", "agents/__init__.py": "import bgap.runner"},
     {FLOORS, CYCLES}),
    ({"cmetric/score.py": "import bgap.runner"}, {FLOORS}),
    ({"cmetric/__main__.py": "import bgap.runner.numerics"}, set()),  # its entry may
    ({"cmetric/__main__.py": "import bgap.runner.jobs"}, {FLOORS}),  # nothing more
    ({"experiments/run.py": "import bgap.commands.run"}, {FLOORS, "commands-on-top", CYCLES}),
]  # fmt: skip


@pytest.mark.parametrize(("edits", "broken"), FORBIDDEN_IMPORTS)
def test_lint_imports_catches_a_forbidden_import(tmp_path, edits, broken):
    """A copy of the package with imports added: lint-imports finds exactly the contracts they
    break."""
    copy = _copy_of_the_project(tmp_path)
    for module, line in edits.items():
        target = copy / "bgap" / module
        target.parent.mkdir(exist_ok=True)
        target.write_text((target.read_text() if target.exists() else "") + f"\n{line}\n")
    assert _lint_imports(copy, pythonpath=copy) == broken


def test_every_stage_lists_exactly_the_code_its_command_runs(tmp_path):
    """dvc.yaml's code deps are the import closure of each stage's command, so a change to
    any module a stage runs reruns (or relocks) it, and no other change does."""
    from tools.relock import closure, code_deps

    stale = {
        name: (sorted(set(needed) - set(listed)), sorted(set(listed) - set(needed)))
        for name, (needed, listed) in code_deps().items()
        if sorted(listed) != needed
    }
    assert not stale, stale
    # the closure follows imports: a hand-made package where b imports c inside a function
    pkg = tmp_path / "bgap"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from bgap.sub import b\n")
    (pkg / "sub" / "b.py").write_text("def f():\n    from . import c\n")
    (pkg / "sub" / "c.py").write_text("import os\n")
    (pkg / "unused.py").write_text("")
    assert closure("bgap.a", tmp_path) == [
        "bgap/__init__.py", "bgap/a.py", "bgap/sub/__init__.py", "bgap/sub/b.py", "bgap/sub/c.py"
    ]  # fmt: skip


@pytest.mark.slow
def test_relock_refuses_a_stage_whose_rehearsal_outputs_changed(tmp_path):
    """A change that alters what the parity stage writes is refused (the lock untouched);
    the unchanged code is relocked. About two minutes: two rehearsals per case."""
    from tools.relock import relock

    repo = tmp_path / "repo"
    subprocess.run(["git", "clone", "-q", str(ROOT), str(repo)], check=True)
    lock = (repo / "dvc.lock").read_text()
    assert relock(["parity"], "HEAD", tmp_path / "same", repo) == {"parity": []}
    parity = repo / "bgap/commands/parity.py"
    text = parity.read_text()
    changed = text.replace(
        "lambda p: table.to_csv(p, index=False)", "lambda p: table.round(2).to_csv(p, index=False)"
    )
    assert changed != text
    parity.write_text(changed)  # the same stage, other numbers in parity.csv
    relocked = (repo / "dvc.lock").read_text()
    differs = relock(["parity"], "HEAD", tmp_path / "changed", repo)
    assert differs["parity"], "a changed output went unnoticed"
    assert (repo / "dvc.lock").read_text() == relocked  # refused: nothing written
    assert differs["parity"] == ["results/parity/parity.csv"]
    # the first relock rewrote the stage's code deps only: its outputs' hashes are the same
    import yaml

    def outs(text: str) -> list:
        return yaml.safe_load(text)["stages"]["parity"]["outs"]

    assert outs(lock) == outs(relocked)


def test_relock_compares_a_runs_settings_by_what_the_base_had(tmp_path):
    """A run's config.yaml may gain a setting (new code, its default); a setting of the base
    that is gone or holds another value makes the outputs differ. Other files: bytes."""
    from tools.relock import _same

    def write(name: str, text: str) -> Path:
        (tmp_path / name).mkdir(exist_ok=True)
        (tmp_path / name / "config.yaml").write_text(text)
        return tmp_path / name / "config.yaml"

    base = write("base", "seed: 0\nagent:\n  gamma: 0.9\n  net_arch: [256, 256]\n")
    added = write("added", "seed: 0\nalgo: dqn\nagent:\n  gamma: 0.9\n  net_arch: [256, 256]\n")
    other = write("other", "seed: 0\nagent:\n  gamma: 0.8\n  net_arch: [256, 256]\n")
    gone = write("gone", "seed: 0\nagent:\n  net_arch: [256, 256]\n")
    shorter = write("shorter", "seed: 0\nagent:\n  gamma: 0.9\n  net_arch: [256]\n")
    assert _same(base, added)
    assert not _same(base, other) and not _same(base, gone) and not _same(base, shorter)
    (tmp_path / "a.csv").write_text("x\n1\n")
    (tmp_path / "b.csv").write_text("x\n1\nseed: 0\n")
    assert not _same(tmp_path / "a.csv", tmp_path / "b.csv")


def test_relock_reads_the_settings_an_evaluation_and_a_card_copy_as_config_yaml(tmp_path):
    """models.csv's settings column and a zoo card's records copy a run's config.yaml as JSON:
    they may gain a setting; any other change (a value, a row, a card field) differs."""
    import csv
    import json

    import yaml

    from tools.relock import _same

    old = {"profile": {"checkpoint_every": 150, "name": "tiny"}, "agent": {"gamma": 0.9}}
    new = {"profile": {**old["profile"], "checkpoint_rule": "return"}, "agent": {"gamma": 0.9}}
    changed = {"profile": old["profile"], "agent": {"gamma": 0.8}}

    def models(name: str, settings: dict, chosen: int = 4) -> Path:
        path = tmp_path / name / "models.csv"
        path.parent.mkdir()
        with path.open("w", newline="") as f:
            rows = csv.DictWriter(f, ["policy", "chosen_episodes", "settings"])
            rows.writeheader()
            rows.writerow({"policy": "main/s0", "chosen_episodes": chosen,
                           "settings": json.dumps(settings, sort_keys=True)})  # fmt: skip
        return path

    base = models("base", old)
    assert _same(base, models("added", new))
    assert not _same(base, models("changed", changed))
    assert not _same(base, models("chosen", new, chosen=5))

    def card(name: str, settings: dict, **extra: object) -> Path:
        path = tmp_path / "zoo" / name / "s0.yaml"
        path.parent.mkdir(parents=True)
        records = {"model": "best_model.zip", "settings": json.dumps(settings)}
        path.write_text(yaml.safe_dump({"arm": "main", "records": records, **extra}))
        return path

    base = card("base", old)
    assert _same(base, card("added", new))
    assert not _same(base, card("changed", changed)) and not _same(base, card("field", new, x=1))


def test_relock_compares_a_checkpoints_state_by_content(tmp_path):
    """A training checkpoint's state.pkl may gain fields (new running statistics at their
    initial value); a changed array, counter or random stream makes it differ."""
    import pickle

    import numpy as np

    from tools.relock import _same

    def write(name: str, state: dict) -> Path:
        (tmp_path / name).mkdir()
        (tmp_path / name / "state.pkl").write_bytes(pickle.dumps(state))
        return tmp_path / name / "state.pkl"

    def state(**more):
        stats = {"speed": np.array([1.5, 2.0]), "steps": np.array([3, 4]), **more}
        return {"monitor": {"episodes": 7}, "stats": stats, "env": {"rngs": [{"s": 11}]}}

    base = write("base", state())
    assert _same(base, write("gained", state(log_contact=np.zeros(2, dtype=bool))))
    changed = state()
    changed["stats"]["speed"] = np.array([1.5, 2.5])
    assert not _same(base, write("speed", changed))
    other_stream = state()
    other_stream["env"]["rngs"][0]["s"] = 12
    assert not _same(base, write("stream", other_stream))
    # the batched learner's state holds tensors (Adam's moments): compared exactly
    import torch

    moments = {"exp_avg": torch.tensor([0.5, 0.25])}
    with_t = write("tensors", state(adam=moments))
    assert _same(with_t, write("tensors2", state(adam={"exp_avg": torch.tensor([0.5, 0.25])})))
    assert not _same(with_t, write("tensors3", state(adam={"exp_avg": torch.tensor([0.5, 0.3])})))
    assert not _same(with_t, write("tensors4", state(adam={"exp_avg": np.array([0.5, 0.25])})))


def test_sb3_models_and_replay_buffers_compare_without_wall_clocks(tmp_path):
    """Two SB3 trainings of one seed differ in their archives' start time, their episodes'
    wall times and their spaces' unseeded samplers, and are the same result; a changed
    weight or replay buffer is not."""
    import pickle

    import gymnasium as gym
    import torch
    from stable_baselines3 import DQN
    from stable_baselines3.common.monitor import Monitor

    from tools.relock import _same

    def trained(name: str) -> DQN:
        env = Monitor(gym.make("CartPole-v1"))
        model = DQN("MlpPolicy", env, seed=3, learning_starts=20, buffer_size=200,
                    policy_kwargs={"net_arch": [8]})  # fmt: skip
        model.learn(60)
        model.observation_space.sample()  # the sampler moves: not part of the result
        model.save(tmp_path / name)
        return model

    # (buffers pickled after both saves: pickling caches __slotnames__ on the buffer's
    # class, which the next archive's readable class description would then print)
    a, b = trained("a"), trained("b")
    for name, model in (("a", a), ("b", b)):
        (tmp_path / f"{name}.pkl").write_bytes(pickle.dumps(model.replay_buffer))
    assert (tmp_path / "a.zip").read_bytes() != (tmp_path / "b.zip").read_bytes()
    assert _same(tmp_path / "a.zip", tmp_path / "b.zip")
    for name in ("a", "b"):  # compared as the checkpoint's replay.pkl is
        (tmp_path / name).mkdir()
        (tmp_path / f"{name}.pkl").rename(tmp_path / name / "replay.pkl")
    assert _same(tmp_path / "a" / "replay.pkl", tmp_path / "b" / "replay.pkl")
    b.replay_buffer.rewards[0] += 1.0
    (tmp_path / "b" / "replay.pkl").write_bytes(pickle.dumps(b.replay_buffer))
    assert not _same(tmp_path / "a" / "replay.pkl", tmp_path / "b" / "replay.pkl")
    with torch.no_grad():
        next(b.policy.parameters())[0, 0] += 1.0
    b.save(tmp_path / "c")
    assert not _same(tmp_path / "a.zip", tmp_path / "c.zip")


def test_the_replay_cells_in_params_name_every_replayed_table():
    """params.yaml spells out evaluate's grid.replays (DVC builds no list from a dict): it
    must name each table replay_data writes, at its density, under the pipeline's root."""
    import yaml

    from tools.relock import replay_cells

    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    assert params["replay"]["cells"] == replay_cells(params)


def test_a_rehearsal_trains_every_arm_at_the_tiny_profile():
    """The rehearsal's budget reaches every training stage: the main study follows the
    top-level profile, each learner arm names its own (issue 32), and both become tiny with
    one seed, so that a relock never trains at a real budget."""
    import yaml

    from tools.relock import rehearsal

    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    assert params["learner_arms"]  # the arms this checks
    # a learner that keeps the best of each group of seeds: one seed each, groups of one
    params["selections"] = {"learner-x-k3": {"runs": "learner-x-all", "group": 3, "episodes": 200}}
    rehearsal(params)
    assert params["selections"]["learner-x-k3"] == {
        "runs": "learner-x-all",
        "group": 1,
        "episodes": 2,
    }
    assert params["profile"] == "tiny"
    for entry in (*params["study"].values(), *params["learner_arms"].values()):
        assert entry["seeds"] == "[0]" and entry.get("profile", "tiny") == "tiny"
    assert all(item["profile"] == "tiny" for item in params["learners"].values())
    assert params["tune_rule"] == {"trials": 2, "episodes": 2}  # the tuned rule's search too


def test_a_rehearsal_runs_each_stage_after_the_stages_it_reads(tmp_path):
    """dvc.yaml lists a reader before the stage that writes what it reads (as replay_data
    after evaluate_baselines): the rehearsal's order puts the writer first anyway, and a
    rehearsal of the reader alone runs the writer too where the copy lacks its outputs, and
    no stage that the reader does not read from."""
    import yaml

    from tools.relock import _upstream_first

    stages = {
        "reader": {"cmd": "cat data/table > read", "deps": ["data"], "outs": ["read"]},
        "writer": {"cmd": "mkdir -p data && echo 1 > data/table", "outs": ["data"]},
        "other": {"cmd": "echo 2 > other", "outs": ["other"]},
    }
    (tmp_path / "dvc.yaml").write_text(yaml.safe_dump({"stages": stages}, sort_keys=False))
    subprocess.run(["git", "init", "-q"], cwd=tmp_path, check=True)
    subprocess.run([sys.executable, "-m", "dvc", "init", "-q"], cwd=tmp_path, check=True)
    rank, needed = _upstream_first(tmp_path, ["reader"])
    assert rank["writer"] < rank["reader"]
    assert needed == {"reader", "writer"}
    # a writer whose outputs the copy holds (committed with cache: false) is not run again:
    # the reader reads the committed file, as recipe_learner's presets are read
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "table").write_text("1\n")
    assert _upstream_first(tmp_path, ["reader"])[1] == {"reader"}


def test_tensorboard_scalars_compare_without_the_clocks_own(tmp_path):
    """SB3 logs its speed (time/fps) beside the training's scalars: a rehearsal compares
    the training's, not the machine's."""
    from torch.utils.tensorboard import SummaryWriter

    from tools.relock import _scalars

    for name, fps in (("a", 100.0), ("b", 140.0)):
        with SummaryWriter(tmp_path / name) as writer:
            writer.add_scalar("rollout/ep_rew_mean", 2.5, 10)
            writer.add_scalar("time/fps", fps, 10)
    assert (
        _scalars(tmp_path / "a") == _scalars(tmp_path / "b") == [("rollout/ep_rew_mean", 10, 2.5)]
    )
