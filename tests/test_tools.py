"""The developer tools (benchmarks, the pipeline's code deps and relock) run from a checkout
as the docs say, outside the installed library, with the commands' one-line errors."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from bgap.analysis.paper import HEADLINE

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


def _early_crashes():
    spec = importlib.util.spec_from_file_location("early_crashes", ROOT / "tools/early_crashes.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_early_crash_rates_are_the_hand_computed_ones():
    """Four episodes of 60 steps at most: one crashes at step 2 (early), one at step 9
    (later); the later windows are (0 + 57 + 57 + 6) / 3 = 40, so the early share 1/4 is 10
    times the later rate per window, 1/40."""
    tool = _early_crashes()
    df = pd.DataFrame({"policy": "rule", "density": "dense", "steps": [2, 60, 60, 9],
                       "crashed": [True, False, False, True]})  # fmt: skip
    (row,) = tool.rates(df).to_dict(orient="records")
    assert row["early share %"] == pytest.approx(25.0)
    assert row["later rate per 3-step window %"] == pytest.approx(2.5)
    assert row["ratio"] == pytest.approx(10.0)


@pytest.mark.slow
def test_every_early_crash_of_the_committed_baselines_replays_and_was_avoidable():
    """The simulator, from the evaluation's stored settings and seeds, crashes each
    hand-built ego at the recorded step of every early crash, and on each of those episodes
    some meta-action held through the early steps survives them: the starts were feasible."""
    folder = ROOT / "results/evaluation/baselines/paper"
    tool = _early_crashes()
    df = pd.read_parquet(folder / "episodes.parquet")
    checked = tool.check_episodes(df[df.policy.isin([*tool.EGOS, "idm"])], folder)
    assert len(checked) > 50
    assert checked.replayed.all()
    assert (checked["actions that survive"] > 0).all()


@pytest.mark.slow
def test_stages_resumes_a_training_the_sessions_end_cut(tmp_path):
    """A DVC training stage killed after its first checkpoint (as a session's end kills
    it): tools/stages.sh, run again, resumes it from the checkpoint, records it with DVC and
    leaves the pipeline up to date; a stage already done is then skipped."""
    import os
    import signal
    import time

    bin_dir = str(Path(sys.executable).parent)  # dvc and python of this environment
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}"}

    def sh(*cmd: str) -> subprocess.CompletedProcess:
        return subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True,
                              timeout=600)  # fmt: skip

    sh("git", "init", "-q")
    sh("dvc", "init", "-q")
    (tmp_path / "dvc.yaml").write_text(
        "stages:\n  train:\n    foreach: [a]\n    do:\n"
        "      cmd: python -m bgap.train env=sparse seeds=[0] policies=[behavior_rich] "
        "profile=tiny profile.train_steps=2400 profile.checkpoint_every=300 "
        "run_dir=runs/${item}\n"
        "      outs:\n        - runs/${item}\n"
    )
    sh("git", "add", "-A")
    sh("git", "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "init")
    cut = subprocess.Popen(["dvc", "repro", "--single-item", "train@a"], cwd=tmp_path, env=env,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                           start_new_session=True)  # fmt: skip
    deadline = time.time() + 300
    while not list(tmp_path.glob("runs/a/*/checkpoints/state.pkl")) and time.time() < deadline:
        assert cut.poll() is None, "the stage ended before its first checkpoint"
        time.sleep(0.5)
    os.killpg(cut.pid, signal.SIGKILL)
    cut.wait()
    assert list(tmp_path.glob("runs/a/*/checkpoints/state.pkl")), "no checkpoint was written"
    log = tmp_path / "stages.log"
    done = sh("bash", str(ROOT / "tools/stages.sh"), str(log), "train@a")
    assert done.returncode == 0, (log.read_text(), (tmp_path / "stages.log.out").read_text())
    assert log.read_text().split()[:2] == ["resume", "train@a"]
    assert sh("dvc", "status", "--json").stdout.strip() == "{}"
    assert list(tmp_path.glob("runs/a/*/model.zip"))
    again = sh("bash", str(ROOT / "tools/stages.sh"), str(log), "train@a")
    assert again.returncode == 0
    assert log.read_text().splitlines()[-3].startswith("start train@a")
    out = (tmp_path / "stages.log.out").read_text()
    assert "didn't change, skipping" in out.split("resume=true")[-1]  # up to date: skipped


@pytest.mark.slow
def test_bring_back_records_the_clones_lock_entry_and_refuses_an_unfinished_stage(tmp_path):
    """A training stage a clone finished comes back with its outputs and the clone's own
    lock entry (this checkout computes the same one), its zoo stage run here, the pipeline
    up to date; a stage the clone has not finished is refused with exit 2."""
    import os
    import shutil

    bin_dir = str(Path(sys.executable).parent)
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}"}

    def sh(cwd: Path, *cmd: str) -> subprocess.CompletedProcess:
        return subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True,
                              timeout=300)  # fmt: skip

    here, clone = tmp_path / "here", tmp_path / "clone"
    (here / "tools").mkdir(parents=True)
    shutil.copy(ROOT / "tools/bring_back.sh", here / "tools/bring_back.sh")
    (here / "code.txt").write_text("7\n")
    (here / "dvc.yaml").write_text(
        "stages:\n  train:\n    foreach: [a, b]\n    do:\n"
        "      cmd: mkdir -p runs/${item} && cat code.txt code.txt > runs/${item}/model\n"
        "      deps: [code.txt]\n      outs:\n        - runs/${item}\n"
        "  zoo:\n    foreach: [a, b]\n    do:\n"
        "      cmd: mkdir -p zoo && cp runs/${item}/model zoo/${item}\n"
        "      deps:\n        - runs/${item}\n      outs:\n        - zoo/${item}:\n"
        "            cache: false\n"
        "  evaluate:\n    cmd: mkdir -p results && cp zoo/a results/a\n"
        "    deps: [zoo/a]\n    outs:\n      - results/a:\n          cache: false\n"
    )
    sh(here, "git", "init", "-q")
    sh(here, "dvc", "init", "-q")
    sh(here, "git", "add", "-A")
    sh(here, "git", "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "init")
    sh(tmp_path, "git", "clone", "-q", str(here), str(clone))
    assert sh(clone, "dvc", "repro", "--single-item", "train@a").returncode == 0

    back = sh(here, "bash", "tools/bring_back.sh", str(clone), "train@a")
    assert back.returncode == 0, back.stderr
    assert "recorded: the clone's lock entry exactly" in back.stdout
    import yaml

    ours = yaml.safe_load((here / "dvc.lock").read_text())["stages"]
    theirs = yaml.safe_load((clone / "dvc.lock").read_text())["stages"]
    assert ours["train@a"] == theirs["train@a"]
    assert (here / "zoo/a").read_text() == "7\n7\n"
    status = sh(here, "dvc", "status", "--json", "train@a", "zoo@a")
    assert status.stdout.strip() == "{}", status.stdout

    # an evaluation stage comes back alone: its outputs and lock, no zoo stage
    assert sh(clone, "dvc", "repro", "--single-item", "zoo@a").returncode == 0
    assert sh(clone, "dvc", "repro", "--single-item", "evaluate").returncode == 0
    evaluated = sh(here, "bash", "tools/bring_back.sh", str(clone), "evaluate")
    assert evaluated.returncode == 0, evaluated.stderr
    assert evaluated.stdout.strip().endswith(
        "brought back evaluate (recorded: the clone's lock entry exactly)"
    )
    assert (here / "results/a").read_text() == "7\n7\n"

    refused = sh(here, "bash", "tools/bring_back.sh", str(clone), "train@b")
    assert refused.returncode == 2
    assert "train@b is not done" in refused.stderr

    # the code here moved: the clone's entry is not recorded, the lock is put back and the
    # relock is called (absent from this tiny repository, so the script stops there)
    (here / "code.txt").write_text("8\n")
    lock = (here / "dvc.lock").read_text()
    moved = sh(here, "bash", "tools/bring_back.sh", str(clone), "train@a")
    assert moved.returncode != 0
    assert "recorded" not in moved.stdout and "tools/relock.py" in moved.stderr
    assert (here / "dvc.lock").read_text() == lock


def test_relock_compares_a_moved_output_at_its_new_place(tmp_path):
    """``tools/relock.py relock --moved OLD=NEW``: a preset the base wrote inside the package
    and the head wrote under results/presets is the same output when its bytes are; changed
    bytes, a file only one side wrote, or a move not given are differences."""
    from tools.relock import differing, moved_to

    moves = {"bgap/conf/rule": "results/presets/rule"}
    assert moved_to(Path("bgap/conf/rule/dense.yaml"), moves) == Path(
        "results/presets/rule/dense.yaml"
    )
    assert moved_to(Path("bgap/conf/rules.yaml"), moves) == Path("bgap/conf/rules.yaml")
    trees = {"base": tmp_path / "base", "head": tmp_path / "head"}
    for tree, folder in (
        (trees["base"], "bgap/conf/rule"),
        (trees["head"], "results/presets/rule"),
    ):
        (tree / folder).mkdir(parents=True)
        (tree / folder / "dense.yaml").write_text("time_gap: 1.2\n")
        (tree / "report.csv").write_text("a,b\n1,2\n")
    base = [Path("bgap/conf/rule/dense.yaml"), Path("report.csv")]
    head = [Path("results/presets/rule/dense.yaml"), Path("report.csv")]
    assert differing(trees, base, head, moves) == []
    assert differing(trees, base, head) == [
        "bgap/conf/rule/dense.yaml",
        "results/presets/rule/dense.yaml",
    ]
    (trees["head"] / "results/presets/rule/dense.yaml").write_text("time_gap: 1.3\n")
    assert differing(trees, base, head, moves) == ["results/presets/rule/dense.yaml"]
    (trees["head"] / "extra.txt").write_text("new\n")
    assert "extra.txt" in differing(trees, base, [*head, Path("extra.txt")], moves)


def test_relock_reads_each_trees_own_pipeline_for_a_stages_outputs(tmp_path, monkeypatch):
    """A stage whose output moved between the base and the head is listed at each tree's own
    place, whatever pipeline the working folder holds (DVC resolves a stage's name against
    the working folder's dvc.yaml)."""
    from tools.relock import _outputs

    for name, out in (("base", "bgap/conf/rule"), ("head", "results/presets/rule")):
        tree = tmp_path / name
        (tree / out).mkdir(parents=True)
        (tree / out / "dense.yaml").write_text("a: 1\n")
        (tree / "dvc.yaml").write_text(
            f"stages:\n  tune:\n    cmd: echo\n    outs:\n      - {out}\n"
        )
        subprocess.run(["dvc", "init", "-q", "--no-scm"], cwd=tree, check=True)
    monkeypatch.chdir(tmp_path / "head")
    assert _outputs(tmp_path / "base", "tune") == [Path("bgap/conf/rule/dense.yaml")]
    monkeypatch.chdir(tmp_path / "base")
    assert _outputs(tmp_path / "head", "tune") == [Path("results/presets/rule/dense.yaml")]


def test_relock_reads_a_moved_path_in_a_runs_settings_at_its_new_place(tmp_path):
    """A run's ``config.yaml`` that names a moved preset (``preset: bgap/conf/rule/x.yaml``)
    is the same setting as the head's at the new place; another value still differs."""
    from tools.relock import differing

    trees = {"base": tmp_path / "base", "head": tmp_path / "head"}
    for tree, preset in ((trees["base"], "bgap/conf"), (trees["head"], "results/presets")):
        (tree / "out").mkdir(parents=True)
        (tree / "out/config.yaml").write_text(
            f"preset_dir: {preset}\npreset: {preset}/rule/dense.yaml\ntrials: 60\nenv: dense\n"
        )
    files = [Path("out/config.yaml")]
    moves = {"bgap/conf": "results/presets"}
    assert differing(trees, files, files, moves) == []
    assert differing(trees, files, files) == ["out/config.yaml"]
    (trees["head"] / "out/config.yaml").write_text(
        "preset_dir: results/presets\npreset: results/presets/rule/dense.yaml\ntrials: 61\n"
    )
    assert differing(trees, files, files, moves) == ["out/config.yaml"]


def _study(root: Path, chosen: list[int], lane_changes: float, verdict: str) -> Path:
    """A study's committed results in miniature: the main arm's two sparse behaviour-rich
    policies kept at ``chosen`` of 3,000 episodes, their episodes, a sparse row against the
    rule and the headline claim."""
    folder = root / "results/evaluation/main/paper"
    folder.mkdir(parents=True)
    names = [f"main/sparse/sparse-behavior_rich-s{s}" for s in range(len(chosen))]
    pd.DataFrame(
        {
            "policy": names,
            "model": "best_model.zip",
            "chosen_episodes": chosen,
            "validated_episodes": 3000,
        }
    ).to_csv(folder / "models.csv", index=False)
    pd.DataFrame(
        {
            "policy": names,
            "mix": 0.5,
            "density": "sparse",
            "radius": 180.0,
            "seed": 100000,
            "crashed": False,
            "lane_changes": lane_changes,
            "distance": 1000.0,
        }
    ).to_parquet(folder / "episodes.parquet")
    pd.DataFrame(
        [
            {
                "density": "sparse",
                "arm": "main",
                "family": "behavior_rich",
                "yardstick": "rule",
                "per_100km": 2.9,
                "yard_per_100km": 0.38,
                "verdict": verdict,
            }
        ]
    ).to_csv(root / "results/yardsticks.csv", index=False)
    pd.DataFrame(
        [
            {
                "claim": HEADLINE,
                "arm": "main",
                "n": 5,
                "difference": 4.4,
                "lo": 1.5,
                "hi": 7.3,
                "verdict": verdict,
            }
        ]
    ).to_csv(root / "results/claims.csv", index=False)
    return root


def test_before_after_reads_each_sides_checkpoints_lane_changes_and_verdicts(tmp_path):
    """Before: checkpoints at episodes 300 and 2,400 of 3,000 (one in the first fifth,
    median 45%), no lane change; after: 1,500 and 2,700 (none early, median 70%), 2.5 lane
    changes per episode; the verdicts as each side's tables say."""
    from tools.before_after import markdown, side

    before = side(_study(tmp_path / "b", [300, 2400], 0.0, "contradicted"))
    after = side(_study(tmp_path / "a", [1500, 2700], 2.5, "not significant"))
    text = markdown(before, after)
    assert "| main | sparse | behavior_rich | 1 of 2 | 0 of 2 | 45% | 70% | 0.00 | 2.50 |" in text
    assert (
        "| main | behavior_rich | 2.90 / 0.38, contradicted | 2.90 / 0.38, not significant |"
        in text
    )
    assert (
        "| main | 5 | +4.4 [+1.5, +7.3], contradicted | +4.4 [+1.5, +7.3], not significant |"
        in text
    )
