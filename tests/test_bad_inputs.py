"""Every command meets bad input with one line and exit status 2, and an interruption with one
line saying what was kept; none of them changes a file of the repository.

The commands run in this process through their entry points (``main()`` with ``sys.argv``),
from a temporary working folder; a checksum of every file of the repository is compared
before and after each case.
"""

from __future__ import annotations

import hashlib
import importlib
import os
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parent.parent

ROWS = [(f, v, 10.0 * v + 2.0 * f, 4.0 * (v % 2)) for f in range(40) for v in range(3)]


def _tables(folder: Path) -> None:
    """One trajectory file per defect."""
    good = pd.DataFrame(ROWS, columns=["frame", "vehicle_id", "x", "y"])
    good.to_csv(folder / "good.csv", index=False)
    good.drop(columns="y").to_csv(folder / "no_y.csv", index=False)
    nan = good.copy()
    nan.loc[3, "x"] = np.nan
    nan.to_csv(folder / "nan.csv", index=False)
    pd.concat([good, good.iloc[:1]]).to_csv(folder / "duplicate.csv", index=False)
    late = good.copy()
    late["time"] = late.frame / 15.0
    late.loc[late.frame == 5, "time"] = 0.0
    late.to_csv(folder / "unsorted.csv", index=False)
    good[good.vehicle_id == 0].to_csv(folder / "one_vehicle.csv", index=False)
    good[good.frame == 0].to_csv(folder / "one_frame.csv", index=False)
    (folder / "empty.csv").write_text("")
    good.iloc[:0].to_csv(folder / "header_only.csv", index=False)
    words = good.astype({"x": str})
    words.loc[0, "x"] = "left"
    words.to_csv(folder / "wrong_type.csv", index=False)
    ids = good.rename(columns={"vehicle_id": "id"})
    ids["track_id"] = ids["id"]
    ids.to_csv(folder / "both_ids.csv", index=False)
    (folder / "notes.txt").write_text("not a table")
    (folder / "evaluation").mkdir(exist_ok=True)
    (folder / "evaluation" / "episodes.parquet").write_bytes(b"PAR1 truncated")
    one_class = good.assign(label="aggressive", lane=0)
    one_class.to_csv(folder / "one_class.csv", index=False)
    # defective files (issue 34): cut short, of another encoding, ragged, not a model
    good.to_parquet(folder / "whole.parquet", index=False)
    whole = (folder / "whole.parquet").read_bytes()
    (folder / "truncated.parquet").write_bytes(whole[: len(whole) // 2])
    (folder / "latin1.csv").write_bytes("vehicle_id,frame,x,y\n1,0,0,\xe9\n".encode("latin-1"))
    (folder / "ragged.csv").write_text("vehicle_id,frame,x,y\n1,0,0,0\n1,1,1,0,7\n")
    (folder / "not_a_model.zip").write_text("not a zip archive")
    (folder / "done").mkdir()
    (folder / "done" / "README.md").write_text("an earlier run's results page\n")
    (folder / "done" / "boundary.json").write_text("{}\n")
    (folder / "empty_run").mkdir()  # a typo's folder, or one killed before a checkpoint
    (folder / "broken").mkdir()
    (folder / "broken" / "config.yaml").write_text("mix: [0.5\n")  # cut short
    (folder / "broken" / "trajectories.parquet").write_bytes(b"a user's table")
    (folder / "parity").mkdir()
    pd.DataFrame({"seed": [0], "mix": [0.5], "backend": ["highway"]}).to_csv(
        folder / "parity" / "episodes.csv", index=False
    )
    import zipfile

    with zipfile.ZipFile(folder / "no_data.zip", "w") as archive:
        archive.writestr("policy.pth", b"\0" * 16)


CASES = [
    # --- defective files (issue 34)
    ("cmetric", ["input={tmp}/truncated.parquet"], r"cannot be read as Parquet"),
    ("cmetric", ["input={tmp}/latin1.csv"], r"is not UTF-8 text"),
    ("cmetric", ["input={tmp}/ragged.csv"], r"is not a well-formed CSV table"),
    ("calibrate", ["calibrate.target={tmp}/truncated.parquet"], r"cannot be read as Parquet"),
    ("evaluate", ["models=[{tmp}/not_a_model.zip]", "baselines=[]"], r"is not a readable model"),
    ("evaluate", ["models=[{tmp}/no_data.zip]", "baselines=[]"], r"is not a readable model"),
    ("simulate", ["policy={tmp}/not_a_model.zip", "episodes=1"], r"is not a readable model"),
    # --- values that passed the checks and failed later (issue 34)
    ("simulate", ["env.duration=nan"], r"env\.duration=nan is invalid: must be a finite number"),
    ("simulate", ["env.vehicles_density=inf"], r"env\.vehicles_density=inf is invalid: must be"),
    ("train", ["seed=4294967296"], r"seed=4294967296 is invalid: must be <= 4294967295"),
    ("train", ["seeds=[0,4294967296]"], r"seeds\[1\]=4294967296 is invalid"),
    ("train", ["hydra.run.dir=elsewhere"], r"hydra\.run\.dir=elsewhere is not used"),
    ("train", ["resume=true", "run_dir={tmp}/typo"], r"resume=true: nothing to resume at"),
    ("parity", ["--episodes", "0"], r"episodes=0 is invalid: must be a whole number >= 1"),
    ("parity", ["duration=nan"], r"duration=nan is invalid: must be a finite number"),
    ("parity", ["--episodes", "many"], r"episodes=many .* could not be converted to Integer"),
    # --- simulate: every config range and mistake
    ("simulate", ["mix=1.5"], r"mix=1\.5 is invalid: must lie in \[0, 1\]"),
    ("simulate", ["mix=-0.1"], r"mix=-0\.1 is invalid"),
    ("simulate", ["radius=0"], r"radius=0\.0 is invalid: must be a positive"),
    ("simulate", ["radius=-1"], r"radius=-1\.0 is invalid"),
    ("simulate", ["seed=-3"], r"seed=-3 is invalid: must be >= 0"),
    ("simulate", ["episodes=0"], r"episodes=0 is invalid: must be >= 1"),
    ("simulate", ["env.duration=0"], r"env\.duration=0\.0 is invalid"),
    ("simulate", ["env.lanes_count=0"], r"env\.lanes_count=0 is invalid"),
    ("simulate", ["env.policy_frequency=2"], r"env\.simulation_frequency=15 is invalid"),
    ("simulate", ["env.vehicles_count=many"], r"vehicles_count=many.*could not be converted"),
    ("simulate", ["foo=1"], r"Could not override 'foo'"),
    ("simulate", ["env=medium"], r"Could not find 'env/medium'.*dense.*sparse"),
    ("simulate", ["behavior=reckless"], r"Could not find 'behavior/reckless'"),
    ("simulate", ["behavior.aggressive.politeness=2"], r"politeness=2\.0 is invalid"),
    ("simulate", ["reward.speed_range=[30,20]"], r"reward\.speed_range=\[30\.0, 20\.0\]"),
    ("simulate", ["policy=nowhere/model.zip"], r"policy='nowhere/model\.zip' is invalid"),
    ("simulate", ["render=true", "backend=vector"], r"render=True is invalid.*backend=highway"),
    ("simulate", ["backend=gpu"], r"backend='gpu' is invalid"),
    ("simulate", ["behavior.converged=false"], r"behavior='paper' is invalid: is a calibration"),
    # --- train
    ("train", ["agent.gamma=0"], r"agent\.gamma=0\.0 is invalid"),
    ("train", ["agent.loss=l1"], r"agent\.loss='l1' is invalid: use mse or huber"),
    ("train", ["agent.buffer_size=10"], r"agent\.buffer_size=10 is invalid"),
    ("train", ["profile.n_envs=0"], r"profile\.n_envs=0 is invalid"),
    ("train", ["profile.train_steps=0"], r"profile\.train_steps=0 is invalid"),
    ("train", ["profile.eval_during_training=0"], r"profile\.eval_during_training=0 is invalid"),
    ("train", ["profile.eval_every_episodes=-1"], r"profile\.eval_every_episodes=-1 is invalid"),
    ("train", ["mix_sampling=sometimes"], r"mix_sampling='sometimes' is invalid"),
    ("train", ["policy=clever"], r"policy='clever' is invalid"),
    ("train", ["profile=huge"], r"Could not find 'profile/huge'"),
    # --- evaluate and the main job
    ("evaluate", ["baselines=[idle,sleepy]"], r"baselines=\['idle', 'sleepy'\] is invalid"),
    ("evaluate", ["models=[{tmp}/nowhere]"], r"no model at .*nowhere; train it"),
    ("evaluate", ["workers=0"], r"workers=0 is invalid"),
    ("evaluate", ["grid.mixes=[1.5]"], r"grid\.mixes=\[1\.5\] is invalid"),
    ("evaluate", ["grid.radii=[0]"], r"grid\.radii=\[0\.0\] is invalid"),
    ("evaluate", ["grid.simulated=false"], r"grid\.replays=\[\] is invalid: a grid without"),
    ("evaluate", ["grid.replays=[{tmp}/none.parquet]"], r"no such trajectory table"),
    ("evaluate", ["grid.replays=[{tmp}/good.csv]"], r"replay needs a lane column"),
    # --- a Ray cluster (issue 35): refused before Ray is asked anything
    ("train", ["cluster.address=local", "cluster.storage=s3://bucket/x"], r"mount the bucket"),
    ("train", ["cluster.address=local", "cluster.storage=/proc/bgap"], r"cannot be written here"),
    ("sweep", ["cluster.address=10.0.0.1:6379"], r"cannot share a SQLite file"),
    ("run", ["mix=2"], r"mix=2\.0 is invalid"),
    ("run", ["seed=-1"], r"seed=-1 is invalid"),
    # --- calibrate and sweep
    ("calibrate", ["calibrate.bounds.acc=[6,1]"], r"calibrate\.bounds\.acc=\[6\.0, 1\.0\]"),
    ("calibrate", ["calibrate.bounds.politness=[0,1]"], r"Could not override.*politness"),
    ("calibrate", ["calibrate.classes=[reckless]"], r"calibrate\.classes=\['reckless'\]"),
    ("calibrate", ["calibrate.trials=0"], r"calibrate\.trials=0 is invalid"),
    ("calibrate", ["calibrate.scene_mix=0"], r"calibrate\.scene_mix=0\.0 is invalid"),
    ("calibrate", ["cmetric.mu=-1"], r"cmetric\.mu=-1\.0 is invalid"),
    ("calibrate", ["calibrate.target_fps=0"], r"calibrate\.target_fps=0\.0 is invalid"),
    ("calibrate", ["calibrate.weights.speed=-1"], r"calibrate\.weights=.* must be >= 0"),
    (
        "calibrate",
        ["calibrate.target={tmp}/missing.csv", "root={tmp}/out"],
        r"missing\.csv: no such file",
    ),
    ("calibrate", ["calibrate.target={tmp}/good.csv", "root={tmp}/out"], r"no 'label' column"),
    (
        "calibrate",
        ["calibrate.target={tmp}/one_class.csv", "root={tmp}/out"],
        r"too few vehicles of class \{'conservative': 0, 'aggressive': 3\}",
    ),
    (
        "calibrate",
        ["calibrate.storage=postgresql://bgap@127.0.0.1:9/none", "root={tmp}/out"],
        r"calibrate\.storage",
    ),
    ("sweep", ["sweep=nosuch", "root={tmp}/out"], r"sweep='nosuch' has no search space"),
    ("sweep", ["mode=both"], r"mode='both' is invalid"),
    # --- CMetric: every trajectory-file defect
    ("cmetric", [], r"input=None: give the trajectory table"),
    ("cmetric", ["input={tmp}/missing.csv"], r"missing\.csv: no such file"),
    ("cmetric", ["input={tmp}"], r"is a folder; give a \.csv or \.parquet file"),
    ("cmetric", ["input={tmp}/notes.txt"], r"unknown format '\.txt'"),
    ("cmetric", ["input={tmp}/empty.csv"], r"empty\.csv is empty"),
    ("cmetric", ["input={tmp}/header_only.csv"], r"has no rows"),
    ("cmetric", ["input={tmp}/no_y.csv"], r"missing column\(s\) \['y'\]"),
    ("cmetric", ["input={tmp}/nan.csv"], r"column 'x' has 1 NaN"),
    ("cmetric", ["input={tmp}/wrong_type.csv"], r"column 'x' has 1 NaN, infinite or non-numeric"),
    ("cmetric", ["input={tmp}/nan.csv", "out={tmp}/scores.txt"], r"neither a folder nor a"),
    ("cmetric", ["input={tmp}/duplicate.csv"], r"1 duplicate \(episode, frame, vehicle_id\)"),
    ("cmetric", ["input={tmp}/unsorted.csv"], r"time is not increasing with frame"),
    ("cmetric", ["input={tmp}/one_vehicle.csv"], r"single vehicle"),
    ("cmetric", ["input={tmp}/one_frame.csv"], r"single frame"),
    ("cmetric", ["input={tmp}/both_ids.csv"], r"columns \['vehicle_id'\] are given twice"),
    ("cmetric", ["input={tmp}/good.csv", "fps=0"], r"fps=0\.0 is invalid"),
    ("cmetric", ["input={tmp}/good.csv", "cmetric.window=0"], r"cmetric\.window=0\.0"),
    # --- figures: evaluation folders that hold no episodes, or damaged ones
    ("figures", ["evaluations=[{tmp}/nothing]"], r"no evaluation episodes in .*nothing: run"),
    ("figures", ["{tmp}/nothing"], r"no evaluation episodes in .*nothing: run bgap.evaluate"),
    ("figures", ["{tmp}/nothing", "out={tmp}/done"], r"done holds the results of an earlier"),
    ("figures", ["{tmp}/nothing", "--out", "{tmp}/done"], r"done holds the results of an earlier"),
    ("cmetric.boundary", ["{tmp}/good.csv", "--out", "{tmp}/done"], r"json.* from an earlier"),
    ("cmetric.boundary", ["tables=[{tmp}/good.csv]", "out={tmp}/done"], r"json.* from an earlier"),
    ("cmetric.boundary", ["{tmp}/nothing"], r"nothing: no such file"),
    ("cmetric.boundary", ["tables=[]"], r"tables=\[\] is invalid: give labelled tables"),
    ("cmetric.boundary", ["{tmp}/nothing", "--cmetric", "paper"], r"nothing: no such file"),
    ("cmetric.boundary", ["tables=[{tmp}/nothing]", "cmetric_preset=paper"], r"no such file"),
    ("figures", ["evaluations=[{tmp}/evaluation]"], r"episodes.parquet cannot be read as Parquet"),
    # --- select: no run folders, a bad group size, an earlier selection
    ("select", ["{tmp}/nothing", "--out", "{tmp}/kept"], r"no run folders .* in .*nothing"),
    ("select", ["{tmp}/nothing", "--out", "{tmp}/k", "--group", "0"], r"group=0 is invalid"),
    ("select", ["runs={tmp}/nothing", "out={tmp}/kept"], r"no run folders .* in .*nothing"),
    ("select", ["{tmp}/nothing", "--out", "{tmp}/done"], r"done holds files no bgap command wrote"),
    # --- parity: the fast mode's rows would replace the parity stage's own
    (
        "parity",
        ["--fast", "--out", "results/parity"],
        r"fast=true needs its own out= \(got results/parity\)",
    ),
    # --- inputs nobody listed (issue 34, second look)
    ("parity", ["--mixes", "x", "--out", "{tmp}/p"], r"mixes=\[x\] .* converted to Float"),
    ("parity", ["mixes=[2]", "out={tmp}/p"], r"every mix must lie in \[0, 1\]"),
    ("parity", ["--seed", "-5", "--out", "{tmp}/p"], r"seed=-5 is invalid"),
    ("parity", ["backends=[gpu]", "out={tmp}/p"], r"backends=\['gpu'\] is invalid"),
    ("parity", ["--backends", "vector", "--out", "{tmp}/p"], r"parity compares both backends"),
    ("parity", ["--out", "{tmp}/parity"], r"parity holds the results of an earlier run"),
    (
        "parity",
        ["--reuse", "--backends", "vector", "--out", "{tmp}/parity"],
        r"holds highway episodes of other mixes or seeds",
    ),  # fmt: skip
    ("simulate", ["out={tmp}/broken"], r"broken/config.yaml is not a settings file bgap can read"),
    ("simulate", ["reward.speed_range=[30]"], r"reward\.speed_range=\[30\.0\] is invalid"),
    ("simulate", ["env.ego_speeds=[20,10]"], r"env\.ego_speeds=\[20\.0, 10\.0\] is invalid"),
    ("train", ["agent.net_arch=[64,0]"], r"agent\.net_arch=\[64, 0\] is invalid"),
    ("train", ["resume=true", "run_dir={tmp}/empty_run"], r"no checkpoint was written there yet"),
    ("sweep", ["trials=0"], r"trials=0 is invalid: must be >= 1"),
    ("sweep", ["sweep_eval_episodes=0"], r"sweep_eval_episodes=0 is invalid"),
]

MODULES = {
    "simulate": "bgap.simulate",
    "train": "bgap.train",
    "evaluate": "bgap.evaluate",
    "run": "bgap.run",
    "calibrate": "bgap.calibrate",
    "sweep": "bgap.sweep",
    "cmetric": "bgap.cmetric.__main__",
    "parity": "bgap.parity",
    "figures": "bgap.figures",
    "select": "bgap.select",
    "cmetric.boundary": "bgap.cmetric.boundary.__main__",
}


def _checksums() -> dict[str, str]:
    """Every file git tracks or would track in the repository, by content."""
    listed = subprocess.run(
        ["git", "ls-files", "--cached", "--others", "--exclude-standard"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    return {
        name: hashlib.sha1((ROOT / name).read_bytes()).hexdigest()
        for name in listed
        if (ROOT / name).is_file()
    }


@pytest.fixture(scope="module")
def repository():
    return _checksums()


def _command(name: str, args: list[str], monkeypatch, capsys) -> tuple[int, str]:
    """Exit status (0 when the command returns) and stderr of ``python -m bgap.<name>``."""
    main = importlib.import_module(MODULES[name]).main
    monkeypatch.setattr(sys, "argv", [f"bgap.{name}", *args])
    try:
        main()
        status = 0
    except SystemExit as stop:
        status = stop.code
    return status, capsys.readouterr().err


@pytest.mark.parametrize("name,args,message", CASES, ids=[" ".join(c[1]) or c[0] for c in CASES])
def test_bad_input_gets_one_line_and_status_2(
    name, args, message, tmp_path, monkeypatch, capsys, repository
):
    _tables(tmp_path)
    monkeypatch.chdir(tmp_path)
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    status, err = _command(name, args, monkeypatch, capsys)
    assert status == 2, err
    assert err.startswith(f"bgap.{name}: ") and err.count("\n") == 1, err
    assert re.search(message, err), err
    assert _checksums() == repository  # nothing outside the working folder changed


def test_a_model_of_another_density_is_a_clear_error(tmp_path, monkeypatch, capsys):
    from bgap.common.config import validate
    from bgap.experiments.train import train
    from tests.configs import compose

    monkeypatch.chdir(tmp_path)
    cfg = validate(compose("train", ["env=sparse", "profile=tiny", f"root={tmp_path}"]))
    run = train(cfg, progress=False)
    status, err = _command(
        "evaluate", ["env=dense", f"models=[{run}]", "baselines=[]"], monkeypatch, capsys
    )
    assert status == 2 and err.count("\n") == 1, err
    assert "observes 5 vehicles" in err and "density sparse" in err


def test_ctrl_c_says_what_was_kept_and_how_to_continue(tmp_path, monkeypatch, capsys, repository):
    from bgap.agents.monitor import SB3Monitor

    monkeypatch.chdir(tmp_path)
    original = SB3Monitor._on_step

    def ctrl_c(self):
        if self.num_timesteps >= 100 and not self.ctrl_c.requested:
            os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C, once
        return original(self)

    monkeypatch.setattr(SB3Monitor, "_on_step", ctrl_c)
    status, err = _command(
        "train", ["profile=tiny", "run_dir=run", "hydra.job.chdir=false"], monkeypatch, capsys
    )
    err = err.strip().splitlines()[-1]  # after the progress bar
    assert status == 130 and err.startswith("bgap.train: interrupted: training stopped"), err
    assert "the checkpoint of step 100 is in run/checkpoints" in err
    assert "python -m bgap.train resume=true run_dir=run" in err
    monkeypatch.setattr(SB3Monitor, "_on_step", original)
    # the same command without resume=true refuses to start the run folder over
    status, err = _command("train", ["profile=tiny", "run_dir=run"], monkeypatch, capsys)
    assert status == 2 and "holds an unfinished training: resume=true" in err

    import bgap.calibration.calibrate as cal

    def stop(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(cal, "scene_scores", stop)
    status, err = _command("calibrate", ["root=out"], monkeypatch, capsys)
    last = err.strip().splitlines()[-1]  # after the study's progress output
    assert status == 130 and "Traceback" not in err
    assert last.startswith("bgap.calibrate: interrupted: every finished trial is kept")
    assert _checksums() == repository


def test_sigterm_stops_a_training_as_ctrl_c_does(tmp_path, monkeypatch, capsys):
    """A scheduler's stop (SIGTERM) keeps the checkpoint and says how to resume, in one line."""
    from bgap.agents.monitor import SB3Monitor

    monkeypatch.chdir(tmp_path)
    original = SB3Monitor._on_step
    sent = []

    def term(self):
        if self.num_timesteps >= 100 and not sent:
            sent.append(self.num_timesteps)
            os.kill(os.getpid(), signal.SIGTERM)
        return original(self)

    monkeypatch.setattr(SB3Monitor, "_on_step", term)
    before = signal.getsignal(signal.SIGTERM)
    status, err = _command("train", ["profile=tiny", "run_dir=run"], monkeypatch, capsys)
    last = err.strip().splitlines()[-1]  # after the progress bar
    assert status == 130 and last.startswith("bgap.train: interrupted: training stopped"), err
    assert "python -m bgap.train resume=true run_dir=run" in last and "Traceback" not in err
    assert signal.getsignal(signal.SIGTERM) is before  # the command put the handler back


def test_a_run_folder_of_other_settings_is_refused(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    args = ["env=sparse", "episodes=1", "env.duration=2", "backend=vector", "out=data"]
    assert _command("simulate", [*args, "mix=0.2"], monkeypatch, capsys)[0] == 0
    status, err = _command("simulate", [*args, "mix=0.8"], monkeypatch, capsys)
    assert status == 2 and "data holds a result of other settings: mix (0.2 there, 0.8 now)" in err


def test_a_finished_training_saved_before_later_settings_is_reused(tmp_path, monkeypatch, capsys):
    """A run folder whose stored config predates settings added since (a replay's
    ``traffic.scenes``, the ``traffic.mixture``, the checkpoint rule) reads them at the value
    its training had, so rerunning its command reuses it rather than refusing it."""
    monkeypatch.chdir(tmp_path)
    args = ["profile=tiny", "run_dir=run"]
    assert _command("train", args, monkeypatch, capsys)[0] == 0
    config = tmp_path / "run/config.yaml"
    later = ("  scenes: all", "  mixture: null", "  checkpoint_rule: return")
    lines = config.read_text().splitlines()
    assert all(line in lines for line in later)
    config.write_text("\n".join(line for line in lines if line not in later) + "\n")
    status, err = _command("train", args, monkeypatch, capsys)
    assert status == 0, err


def test_a_users_calibration_and_sweep_write_only_under_their_root(tmp_path, monkeypatch, capsys):
    """With root= in a temporary folder, the repository's git status stays clean."""

    def status() -> str:
        return subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=all"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            check=True,
        ).stdout

    before = status()
    calibrate = ["calibrate.trials=1", "calibrate.rounds=1", "calibrate.episodes=1"]
    calibrate += ["calibrate.duration=5", f"root={tmp_path}/cal"]
    assert _command("calibrate", calibrate, monkeypatch, capsys)[0] == 0
    assert (tmp_path / "cal/presets/behavior/user_calibrated.yaml").exists()
    sweep = ["trials=1", "profile=tiny", "sweep_eval_episodes=2", f"root={tmp_path}/sw"]
    assert _command("sweep", sweep, monkeypatch, capsys)[0] == 0
    assert (tmp_path / "sw/presets/reward/user_tuned.yaml").exists()
    assert status() == before


def test_settings_that_differ_never_share_a_folder_or_a_study():
    from dataclasses import replace

    from bgap.common.config import validate
    from bgap.experiments.run import results_dir
    from bgap.experiments.sweep import study_name
    from tests.configs import compose

    run = validate(compose("run", []))
    other_reward = validate(compose("run", ["reward=authors"]))
    assert results_dir(run) != results_dir(other_reward)
    assert results_dir(run) == results_dir(replace(run, workers=7))  # speed only
    sweep = validate(compose("sweep", []))
    longer = validate(compose("sweep", ["profile.train_steps=60000"]))
    assert study_name(sweep) != study_name(longer)
    assert study_name(sweep) == study_name(replace(sweep, trials=99))  # a rerun's budget


def test_a_training_killed_at_any_moment_resumes_to_the_same_parameters(
    tmp_path, monkeypatch, capsys
):
    """kill -9 while training (vector backend): the resumed run, from the last checkpoint,
    ends with the parameters of an uninterrupted run."""
    import os
    import signal
    import time

    from bgap.agents.dqn import DQN
    from bgap.common.config import validate
    from bgap.experiments.train import train
    from tests.configs import compose

    overrides = ["profile=tiny", "profile.checkpoint_every=40", "mix_sampling=paper"]
    whole = train(validate(compose("train", [*overrides, f"run_dir={tmp_path}/whole"])), False)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    args = [sys.executable, "-m", "bgap.train", *overrides, f"run_dir={tmp_path}/cut"]
    child = subprocess.Popen(args, cwd=tmp_path, env=env, stderr=subprocess.DEVNULL)
    state = tmp_path / "cut/checkpoints/state.pkl"
    deadline = time.time() + 120
    while not state.exists() and child.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    child.send_signal(signal.SIGKILL)
    child.wait()
    assert state.exists() and not (tmp_path / "cut/model.zip").exists()
    # a damaged checkpoint (a copy of this one): one line, not an UnpicklingError
    shutil.copytree(tmp_path / "cut", tmp_path / "damaged")
    (tmp_path / "damaged/checkpoints/state.pkl").write_bytes(b"\x80\x04 not a pickle")
    damaged = [*overrides, f"run_dir={tmp_path}/damaged", "resume=true"]
    status, err = _command("train", damaged, monkeypatch, capsys)
    assert status == 2 and "holds a damaged checkpoint" in err and err.count("\n") == 1, err
    cfg = validate(compose("train", [*overrides, f"run_dir={tmp_path}/cut", "resume=true"]))
    cut = train(cfg, progress=False)

    def parameters(run):
        model = DQN.load(run / "model.zip", device="cpu")
        return np.concatenate([p.detach().numpy().ravel() for p in model.policy.parameters()])

    np.testing.assert_array_equal(parameters(whole), parameters(cut))
