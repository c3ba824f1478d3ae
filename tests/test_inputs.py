"""Inputs nobody listed (issue 34): outputs that would destroy inputs or earlier results are
refused, run folders are locked while written, an interrupted command's metadata does not
block a rerun, and generated malformed tables and settings end in one known error or work."""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bgap.cmetric.io import load_trajectories
from bgap.common.config import validate
from bgap.common.errors import ConfigError, TrajectoryError
from tests.configs import compose
from tests.test_bad_inputs import _command

ROOT = Path(__file__).resolve().parent.parent
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}  # this checkout's bgap in child processes


def _digest(path: Path) -> str:
    return hashlib.sha1(path.read_bytes()).hexdigest()


def _table(path: Path) -> Path:
    # 60 frames at 15 Hz: 4 s, longer than CMetric's 3-second window
    rows = [(v, f, f * (1.0 + v % 3), 3.5 * (v % 3)) for v in range(6) for f in range(60)]
    pd.DataFrame(rows, columns=["vehicle_id", "frame", "x", "y"]).to_csv(path, index=False)
    return path


def test_cmetric_refuses_to_write_its_scores_over_its_input(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    runs = _table(tmp_path / "runs.csv")
    before = _digest(runs)
    status, err = _command("cmetric", ["input=runs.csv", "out=runs.csv"], monkeypatch, capsys)
    assert status == 2 and "runs.csv, the input table" in err and err.count("\n") == 1, err
    assert _digest(runs) == before


def test_cmetric_keeps_scores_of_other_settings_and_a_users_file(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    _table(tmp_path / "runs.csv")
    assert _command("cmetric", ["input=runs.csv", "out=s.csv"], monkeypatch, capsys)[0] == 0
    first = _digest(tmp_path / "s.csv")
    status, err = _command(
        "cmetric", ["input=runs.csv", "out=s.csv", "cmetric=paper"], monkeypatch, capsys
    )
    assert status == 2 and "holds scores of other settings" in err, err
    assert _digest(tmp_path / "s.csv") == first
    # the same settings again rewrite the same scores
    assert _command("cmetric", ["input=runs.csv", "out=s.csv"], monkeypatch, capsys)[0] == 0
    (tmp_path / "mine.csv").write_text("a user's own table\n")
    status, err = _command("cmetric", ["input=runs.csv", "out=mine.csv"], monkeypatch, capsys)
    assert status == 2 and "did not write" in err, err
    assert (tmp_path / "mine.csv").read_text() == "a user's own table\n"


def test_cmetric_side_files_never_replace_an_input_or_a_users_file(tmp_path, monkeypatch, capsys):
    """Beside ``out=t.csv`` bgap.cmetric writes t_windows.parquet, t_centrality.png and
    t_config.yaml: none of them may be the input table or a user's file."""
    monkeypatch.chdir(tmp_path)
    pd.read_csv(_table(tmp_path / "runs.csv")).to_parquet(tmp_path / "t_windows.parquet")
    before = _digest(tmp_path / "t_windows.parquet")
    args = ["input=t_windows.parquet", "out=t.csv"]
    status, err = _command("cmetric", args, monkeypatch, capsys)
    assert status == 2 and "would write t_windows.parquet, the input table" in err, err
    (tmp_path / "u_centrality.png").write_bytes(b"a user's figure")
    status, err = _command("cmetric", ["input=runs.csv", "out=u.csv"], monkeypatch, capsys)
    assert status == 2 and "u_centrality.png exist(s) and bgap.cmetric did not write" in err, err
    assert _digest(tmp_path / "t_windows.parquet") == before
    assert (tmp_path / "u_centrality.png").read_bytes() == b"a user's figure"
    assert not (tmp_path / "u.csv").exists() and not (tmp_path / "t.csv").exists()


def test_simulate_refuses_a_folder_of_a_users_files(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    user = tmp_path / "mine"
    user.mkdir()
    (user / "trajectories.parquet").write_text("mine")
    (user / "episodes.csv").write_text("mine too")
    status, err = _command("simulate", ["out=mine", "episodes=1"], monkeypatch, capsys)
    assert status == 2 and "holds files no bgap command wrote" in err, err
    assert (user / "trajectories.parquet").read_text() == "mine"
    assert sorted(p.name for p in user.iterdir()) == ["episodes.csv", "trajectories.parquet"]


def test_a_users_lone_config_yaml_is_not_taken_for_an_interrupted_commands(
    tmp_path, monkeypatch, capsys
):
    """A folder holding nothing but a user's own config.yaml (no command.txt: bgap writes
    that first) is compared as settings and refused, its file byte-identical; a command.txt
    left alone by a kill between bgap's two writes does not block a rerun."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "config.yaml").write_text("learning_rate: 0.001\nlayers: [64, 64]\n")
    status, err = _command("simulate", ["out=mine", "episodes=1"], monkeypatch, capsys)
    assert status == 2 and err.count("\n") == 1 and "mine" in err, err
    assert (tmp_path / "mine" / "config.yaml").read_text().startswith("learning_rate: 0.001")
    assert [p.name for p in (tmp_path / "mine").iterdir()] == ["config.yaml"]
    (tmp_path / "killed").mkdir()
    (tmp_path / "killed" / "command.txt").write_text("python -m bgap.simulate out=killed\n")
    status, err = _command("simulate", ["out=killed", "episodes=1"], monkeypatch, capsys)
    assert status == 0, err


@pytest.mark.parametrize(
    "left",
    [
        {"command.txt": "python -m bgap.simulate out=killed\n", ".config.4242.tmp.yaml": "a"},
        {".command.4242.tmp.txt": "python -m bgap.sim"},
    ],
    ids=["inside-config-yaml", "inside-command-txt"],
)
def test_a_kill_inside_the_metadatas_atomic_write_does_not_block_a_rerun(
    tmp_path, monkeypatch, capsys, left
):
    """SIGKILL between write_atomic's temporary file and its rename (a window CI's random
    kills met once) leaves ``.<name>.<pid>.tmp<suffix>`` beside or without command.txt: the
    same command runs again; a user's own hidden file still refuses the folder."""
    monkeypatch.chdir(tmp_path)
    killed = tmp_path / "killed"
    killed.mkdir()
    for name, text in left.items():
        (killed / name).write_text(text)
    status, err = _command("simulate", ["out=killed", "episodes=1"], monkeypatch, capsys)
    assert status == 0, err
    assert (killed / "config.yaml").exists()
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / ".notes.tmp.txt").write_text("a user's")
    status, err = _command("simulate", ["out=mine", "episodes=1"], monkeypatch, capsys)
    assert status == 2 and "holds files no bgap command wrote (.notes.tmp.txt)" in err, err


def test_an_interrupted_commands_metadata_does_not_block_a_rerun(tmp_path, monkeypatch, capsys):
    """Ctrl-C during bgap.simulate leaves config.yaml and command.txt only, and says so; a
    rerun with other settings then runs (nothing of a result would be lost)."""
    import bgap.commands.simulate as simulate

    monkeypatch.chdir(tmp_path)

    def ctrl_c(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(simulate, "record", ctrl_c)
    status, err = _command("simulate", ["out=sim", "episodes=1"], monkeypatch, capsys)
    assert status == 130 and "no table was written" in err and "do not block a rerun" in err
    assert sorted(p.name for p in (tmp_path / "sim").iterdir()) == ["command.txt", "config.yaml"]
    monkeypatch.undo()
    monkeypatch.chdir(tmp_path)
    status, err = _command(
        "simulate", ["out=sim", "episodes=1", "env=sparse", "seed=5"], monkeypatch, capsys
    )
    assert status == 0, err
    assert (tmp_path / "sim" / "trajectories.parquet").exists()


@contextmanager
def _held_by_another_process(lock: str, target: str, cwd: Path) -> Iterator[int]:
    """``bgap.runner.locks.<lock>(target)`` held by a child process; yields its pid."""
    holder = subprocess.Popen(
        [sys.executable, "-c", f"import time; from bgap.runner.locks import {lock}\n"
         f"with {lock}({target!r}):\n    print('held', flush=True); time.sleep(60)"],
        cwd=cwd, stdout=subprocess.PIPE, text=True, env=ENV,
    )  # fmt: skip
    try:
        assert holder.stdout.readline().strip() == "held"
        yield holder.pid
    finally:
        holder.kill()
        holder.wait()


def test_a_run_folder_being_trained_is_refused_naming_the_process(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    with _held_by_another_process("exclusive", "run", tmp_path) as pid:
        status, err = _command("train", ["profile=tiny", "run_dir=run"], monkeypatch, capsys)
        assert status == 2 and err.count("\n") == 1, err
        assert f"is being written by process {pid}" in err, err
    assert not (tmp_path / "run" / "config.yaml").exists()  # refused before writing


def test_a_scores_file_being_written_is_refused_naming_the_process(tmp_path, monkeypatch, capsys):
    """bgap.cmetric out=FILE: a second command writing the same scores file is refused in
    one line naming the holder; one writing another file of that folder is not."""
    monkeypatch.chdir(tmp_path)
    _table(tmp_path / "runs.csv")
    with _held_by_another_process("exclusive_file", "s.csv", tmp_path) as pid:
        status, err = _command("cmetric", ["input=runs.csv", "out=s.csv"], monkeypatch, capsys)
        assert status == 2 and err.count("\n") == 1, err
        assert f"is being written by process {pid}" in err, err
        assert _command("cmetric", ["input=runs.csv", "out=t.csv"], monkeypatch, capsys)[0] == 0
    assert not (tmp_path / "s.csv").exists()
    assert not list(tmp_path.glob(".t.csv*"))  # the lock file goes with the lock


def test_the_lock_is_released_and_leaves_no_file_nor_an_empty_folder_it_made(tmp_path):
    from bgap.common.errors import ConfigError
    from bgap.common.runs import LOCK
    from bgap.runner.locks import exclusive

    (tmp_path / "out").mkdir()
    with exclusive(tmp_path / "out"):
        assert (tmp_path / "out" / LOCK).exists()
        with exclusive(tmp_path / "out"):  # re-entrant in one process (bgap.run, train)
            pass
    assert list((tmp_path / "out").iterdir()) == []  # the user's folder stays, empty
    # a folder the command made, then a refusal before anything was written: no trace
    with pytest.raises(ConfigError), exclusive(tmp_path / "new"):
        raise ConfigError("refused after the lock")
    assert not (tmp_path / "new").exists()
    with exclusive(tmp_path / "kept"):  # written: kept
        (tmp_path / "kept" / "config.yaml").write_text("seed: 0\n")
    assert (tmp_path / "kept" / "config.yaml").exists()
    # refused once its metadata was written (a memory estimate made when the traffic is
    # built): the folder and the parents it made go; a folder it found stays
    from bgap.common.runs import save_run_metadata

    with pytest.raises(ConfigError), exclusive(tmp_path / "a" / "b" / "run"):
        save_run_metadata(tmp_path / "a" / "b" / "run", {"seed": 0})
        raise ConfigError("refused after the metadata")
    assert not (tmp_path / "a").exists()
    with pytest.raises(ConfigError), exclusive(tmp_path / "out" / "run"):
        save_run_metadata(tmp_path / "out" / "run", {"seed": 0})
        (tmp_path / "out" / "run" / "episodes.csv").write_text("a result\n")
        raise ConfigError("refused after a result")
    kept = sorted(p.name for p in (tmp_path / "out" / "run").iterdir())
    assert kept == ["command.txt", "config.yaml", "episodes.csv"]


def test_minus_zero_is_zero():
    from bgap.experiments.run import results_dir

    a, b = (validate(compose("run", [f"mix={m}", "grid.mixes=[-0.0]"])) for m in ("-0.0", "0.0"))
    assert results_dir(a) == results_dir(b) and str(a.mix) == "0.0"
    assert str(a.grid.mixes[0]) == "0.0"


def test_write_atomic_never_leaves_half_a_file(tmp_path):
    """A writer killed in the middle leaves the previous file whole, and no temporary."""
    from bgap.common.runs import write_atomic

    target = tmp_path / "table.csv"
    write_atomic(target, "old\n")

    def dies(path: Path) -> None:
        path.write_text("half of a new ")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_atomic(target, dies)
    assert target.read_text() == "old\n" and [p.name for p in tmp_path.iterdir()] == ["table.csv"]
    code = (
        "import os, sys; from pathlib import Path; from bgap.common.runs import write_atomic\n"
        "def slow(p):\n    f = open(p, 'w'); f.write('x' * 1000); f.flush(); print('writing', "
        "flush=True); import time; time.sleep(30)\n"
        f"write_atomic(Path({str(target)!r}), slow)"
    )
    writer = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=ENV
    )
    assert writer.stdout.readline().strip() == "writing"
    writer.kill()  # kill -9 in the middle of the write
    writer.wait()
    assert target.read_text() == "old\n"


# ------------------------------------------------------------------ generated inputs
COLUMNS = ("vehicle_id", "id", "frame", "time", "x", "y", "vx", "vy", "episode", "label", "odd")
CELL = st.one_of(
    st.integers(-3, 50),
    st.floats(allow_nan=True, allow_infinity=True, width=32),
    st.sampled_from(["", "a", "1e3", "nan", "-", "aggressive"]),
    st.none(),
)


@st.composite
def tables(draw) -> pd.DataFrame:
    columns = draw(st.lists(st.sampled_from(COLUMNS), min_size=0, max_size=7, unique=True))
    rows = draw(st.integers(0, 25))
    return pd.DataFrame(
        {c: draw(st.lists(CELL, min_size=rows, max_size=rows)) for c in columns}, dtype=object
    )


@settings(max_examples=250, derandomize=True, deadline=None,
          suppress_health_check=[HealthCheck.too_slow])  # fmt: skip
@given(tables(), st.sampled_from(["csv", "parquet", "frame"]))
def test_any_generated_table_is_read_or_refused_with_a_trajectory_error(tmp_path_factory, df, kind):
    """The one trajectory reader either returns a complete table or raises the one error
    type the commands turn into one line (never another exception)."""
    folder = tmp_path_factory.mktemp("gen")
    if kind == "frame":
        source = df
    elif kind == "csv":
        source = folder / "t.csv"
        df.to_csv(source, index=False)
    else:
        source = folder / "t.parquet"
        try:
            df.astype(str).to_parquet(source, index=False)
        except Exception:  # noqa: BLE001 - pandas cannot write it: nothing to read
            return
    try:
        table = load_trajectories(source)
    except TrajectoryError:
        return
    assert list(table.columns[:8]) == [
        "episode",
        "frame",
        "time",
        "vehicle_id",
        "x",
        "y",
        "vx",
        "vy",
    ]
    assert np.isfinite(table[["x", "y", "vx", "vy", "time"]].to_numpy(dtype=float)).all()


GOOD = pd.DataFrame(
    [(v, f, f * (1.0 + v % 3), 3.5 * (v % 3), "aggressive") for v in range(4) for f in range(8)],
    columns=["vehicle_id", "frame", "x", "y", "label"],
)


@st.composite
def damaged(draw) -> tuple[str, bytes]:
    """A good table's file, damaged as files are: cut short, bytes overwritten or inserted
    (another encoding, binary noise), a row with a field too many."""
    kind = draw(st.sampled_from(["csv", "parquet"]))
    data = GOOD.to_csv(index=False).encode() if kind == "csv" else GOOD.to_parquet(index=False)
    how = draw(st.sampled_from(["cut", "overwrite", "insert", "ragged"]))
    at = draw(st.integers(0, len(data) - 1))
    noise = draw(st.binary(min_size=1, max_size=8))
    if how == "cut":
        data = data[:at]
    elif how == "overwrite":
        data = data[:at] + noise + data[at + len(noise) :]
    elif how == "insert":
        data = data[:at] + noise + data[at:]
    elif kind == "csv":
        lines = data.split(b"\n")
        k = draw(st.integers(1, len(lines) - 2))
        lines[k] += b",7"
        data = b"\n".join(lines)
    return kind, data


@settings(max_examples=250, derandomize=True, deadline=None)
@given(damaged())
def test_any_damaged_file_is_read_or_refused_with_a_trajectory_error(tmp_path_factory, file):
    kind, data = file
    path = tmp_path_factory.mktemp("damaged") / f"t.{kind}"
    path.write_bytes(data)
    try:
        table = load_trajectories(path)
    except TrajectoryError:
        return
    assert np.isfinite(table[["x", "y", "vx", "vy", "time"]].to_numpy(dtype=float)).all()


NUMBERS = st.one_of(
    st.integers(-(2**40), 2**40),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0, -0.0, 1e-12, 1e308]),
)
KEYS = ("mix", "radius", "seed", "episodes", "env.duration", "env.vehicles_density",
        "env.vehicles_count", "env.lanes_count", "env.policy_frequency")  # fmt: skip


@settings(max_examples=25, derandomize=True, deadline=None)
@given(st.dictionaries(st.sampled_from(KEYS), NUMBERS, min_size=1, max_size=3))
def test_any_generated_setting_is_accepted_or_refused_with_a_config_error(values):
    """Every generated value of the simulate command's numeric settings, composed through
    Hydra as the command line is (25 cases, 0.4 s each; every command's settings, merged
    without Hydra, 200 per command under -m slow: the test below), either validates (and is
    then finite and in range where it matters) or is one ConfigError naming a key."""
    overrides = [f"{k}={v!r}" for k, v in values.items()]
    try:
        cfg = validate(compose("simulate", overrides))
    except ConfigError as err:
        assert any(k.split(".")[-1] in str(err) for k in values), str(err)
        return
    except Exception as err:  # noqa: BLE001 - Hydra's own type errors are known mistakes
        from bgap.common.cli import known_errors

        assert isinstance(err, known_errors()), repr(err)
        return
    assert 0.0 <= cfg.mix <= 1.0 and np.isfinite(cfg.env.duration) and cfg.env.duration > 0
    assert 0 <= cfg.seed <= 2**32 - 1


COMMANDS = ("train", "evaluate", "run", "sweep", "recipe", "calibrate", "datasets",
            "cmetric_app", "simulate")  # fmt: skip
"""Every Hydra command's config (cmetric_search needs its tables: tests/test_bad_inputs.py)."""


def _numeric_keys(cfg, lists: bool = False) -> list[str]:
    """The int and float settings of ``cfg`` (``lists``: its lists of numbers instead)."""
    from omegaconf import OmegaConf

    def number(value) -> bool:
        return isinstance(value, (int, float)) and not isinstance(value, bool)

    def walk(node, prefix=""):
        for key, value in node.items():
            if isinstance(value, dict):
                yield from walk(value, f"{prefix}{key}.")
            elif not lists and number(value):
                yield f"{prefix}{key}"
            elif lists and isinstance(value, list) and value and all(map(number, value)):
                yield f"{prefix}{key}"

    return sorted(walk(OmegaConf.to_container(cfg)))


@pytest.mark.parametrize(
    "command,examples",
    [*((c, 16) for c in COMMANDS),
     *(pytest.param(c, 200, marks=pytest.mark.slow) for c in COMMANDS)],
)  # fmt: skip
def test_any_generated_setting_of_any_command_is_accepted_or_refused_in_one_line(command, examples):
    """Generated combinations (16 per command, with the simulate test above over 200 in the
    default suite; 200 per command under -m slow, about 40 s per command on 2 cores) of up to
    three of the command's numeric settings (every int and float key of its composed config,
    and every list of numbers given as a list of 0-3 numbers), merged as the command line
    merges them (OmegaConf's typed merge; composing through Hydra per case costs 0.3 s): each
    validates, with every number finite and every seed in numpy's range, or is refused with a
    one-line ConfigError naming a setting (one of these, or the other side of a constraint
    between two: ``sumo.length=0`` is refused as ``sumo.ego_position=2000.0 ... must lie on
    the road``), or one of OmegaConf's known type errors."""
    from omegaconf import OmegaConf

    from bgap.common.cli import known_errors

    base = compose(command, [])
    keys = _numeric_keys(base)
    assert len(keys) >= 5, keys
    listed = _numeric_keys(base, lists=True)
    value = st.sampled_from(keys).flatmap(lambda k: st.tuples(st.just(k), NUMBERS))
    if listed:
        lists = st.tuples(st.sampled_from(listed), st.lists(NUMBERS, max_size=3))
        value = st.one_of(value, lists)

    @settings(max_examples=examples, derandomize=True, deadline=None, database=None)
    @given(st.lists(value, min_size=1, max_size=3, unique_by=lambda kv: kv[0]).map(dict))
    def check(values):
        try:
            merged = OmegaConf.merge(base, OmegaConf.from_dotlist(
                [f"{k}={v!r}" for k, v in values.items()]))  # fmt: skip
            cfg = validate(merged)
        except ConfigError as err:
            assert re.search(r"\b[a-z_][a-z0-9_.]*(\[\d+\])?=", str(err)), (values, str(err))
            assert "\n" not in str(err)
            return
        except Exception as err:  # noqa: BLE001 - OmegaConf's own type errors
            assert isinstance(err, known_errors()), (values, repr(err))
            return
        resolved = OmegaConf.to_container(OmegaConf.structured(cfg), resolve=True)
        for key in _numeric_keys(OmegaConf.create(resolved)):
            value = OmegaConf.select(OmegaConf.create(resolved), key)
            assert np.isfinite(value), (key, value)
            if "seed" in key.split(".")[-1]:
                assert 0 <= value <= 2**32 - 1, (key, value)

    check()


# ------------------------------------------------------------------ kill -9 and resume
def _train(run_dir: Path, setting: str, resume: bool = False) -> subprocess.Popen:
    args = ["profile=tiny", "env=sparse", setting, f"run_dir={run_dir}"]
    return subprocess.Popen(
        [sys.executable, "-m", "bgap.train", *args, *(["resume=true"] if resume else [])],
        cwd=run_dir.parent, env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip


def _weights(run_dir: Path) -> bytes:
    import zipfile

    with zipfile.ZipFile(run_dir / "model.zip") as archive:
        return archive.read("policy.pth")


TRAININGS = ("learner=sb3", "learner=batched", "agent=qrdqn", "agent=ppo")
"""Both learners (DQN), and the SB3 learner's other algorithms."""


@pytest.mark.parametrize(
    "learner,kills",
    # 20 kills at random moments per learner and algorithm, under -m slow only (the default
    # suite kills each learner at a checkpoint: tests/test_bad_inputs.py, tests/test_batched.py)
    [pytest.param(t, 20, marks=pytest.mark.slow) for t in TRAININGS],
)  # fmt: skip
def test_kill_9_at_any_moment_then_resume_ends_with_the_uninterrupted_parameters(
    tmp_path, learner, kills
):
    """A training killed with SIGKILL at a random moment (checkpoint writes included), then
    continued with resume=true, ends with the weights of a training never interrupted
    (DQN on both learners, QR-DQN and PPO on SB3's)."""
    whole = tmp_path / "whole"
    start = time.perf_counter()
    assert _train(whole, learner).wait(timeout=600) == 0
    took = time.perf_counter() - start
    rng = np.random.default_rng(34)
    for k in range(kills):
        run = tmp_path / f"cut{k}"
        first = _train(run, learner)
        try:
            first.wait(timeout=float(rng.uniform(0.3, took)))
        except subprocess.TimeoutExpired:
            first.kill()  # SIGKILL: no handler runs
            first.wait()
        # what a user does: resume=true where a checkpoint was written (bgap.train refuses it
        # with nothing to resume), the same command again where none was
        saved = any(run.rglob("state.pkl")) or any(run.rglob("model.zip"))
        resumed = _train(run, learner, resume=saved)
        assert resumed.wait(timeout=600) == 0, f"repetition {k}: the resume failed"
        assert _weights(run) == _weights(whole), f"repetition {k}: other weights"


@pytest.mark.parametrize(
    "learner",
    ["learner=sb3", pytest.param("learner=batched", marks=pytest.mark.slow)],  # time budget
)
def test_a_kill_after_the_last_checkpoint_before_model_zip_resumes_to_the_same_weights(
    tmp_path, learner
):
    """Killed between the last checkpoint (of the final step) and the renaming of model.zip,
    the window CI's random kills once met (PPO): resume=true has nothing left to learn and
    writes the uninterrupted training's model.zip, where it raised an AttributeError."""
    whole = tmp_path / "whole"
    assert _train(whole, learner).wait(timeout=600) == 0
    cut = tmp_path / "cut"
    shutil.copytree(whole, cut)
    (cut / "model.zip").unlink()  # what such a kill leaves: the checkpoint of the last step
    assert _train(cut, learner, resume=True).wait(timeout=600) == 0
    assert _weights(cut) == _weights(whole)


def test_a_log_whose_vehicles_keep_their_own_clocks_is_refused_and_a_common_clock_read():
    """Four vehicles sampled every 0.04 s, each 13 ms after the previous: frames made from
    their times would each hold one vehicle (no traffic graph). The same log on a common
    clock reads with every vehicle in every frame."""
    rows = [(v, k * 0.04 + 0.013 * v, float(k), 3.5 * (v % 2)) for v in range(4) for k in range(30)]
    own = pd.DataFrame(rows, columns=["vehicle_id", "time", "x", "y"])
    with pytest.raises(TrajectoryError, match="keep their own clocks: sampled every 0.04 s"):
        load_trajectories(own)
    common = own.assign(time=[k * 0.04 for v in range(4) for k in range(30)])
    table = load_trajectories(common)
    assert table.groupby("frame").vehicle_id.nunique().min() == 4
    # offsets 0.3 and 0.7 of a step are 0.4 apart on the clock's circle (not mirror images)
    two = [(v, k * 0.04 + o, float(k), 0.0) for v, o in ((0, 0.012), (1, 0.028)) for k in range(30)]
    with pytest.raises(TrajectoryError, match="offsets up to 0.016 s apart"):
        load_trajectories(pd.DataFrame(two, columns=["vehicle_id", "time", "x", "y"]))
    # one step less a hair: the same clock (0.0 and 0.039 s of a 0.04 s step)
    near = [(v, k * 0.04 + o, float(k), 0.0) for v, o in ((0, 0.0), (1, 0.039)) for k in range(30)]
    assert load_trajectories(pd.DataFrame(near, columns=["vehicle_id", "time", "x", "y"])).size


def test_a_preset_is_rewritten_only_by_the_run_that_wrote_it(tmp_path):
    """Two sweeps under one root write the same default preset path: the second is refused
    instead of replacing the first's preset; the first, resumed, rewrites its own; a user's
    file of that name is never replaced."""
    from bgap.common.presets import write_preset
    from bgap.traffic.scenario import RewardConfig

    path = tmp_path / "presets" / "reward" / "user_tuned.yaml"
    write_preset(
        RewardConfig(collision=-2.0), "reward", path, "sweep (study a) trial 1", "(study a)"
    )
    first = path.read_text()
    assert "collision: -2.0" in first and first.startswith("# sweep (study a) trial 1\n")
    with pytest.raises(ConfigError, match="holds a preset this run did not write"):
        write_preset(RewardConfig(), "reward", path, "sweep (study b) trial 3", "(study b)")
    assert path.read_text() == first
    write_preset(
        RewardConfig(collision=-3.0), "reward", path, "sweep (study a) trial 7", "(study a)"
    )
    assert "collision: -3.0" in path.read_text()
    mine = tmp_path / "mine.yaml"
    mine.write_text("collision: -9\n")
    with pytest.raises(ConfigError, match="mine.yaml holds a preset this run did not write"):
        write_preset(RewardConfig(), "reward", mine, "sweep (study a)", "(study a)")
    assert mine.read_text() == "collision: -9\n"


@pytest.mark.parametrize(
    "name,default",
    [("parity", "outputs/parity"), ("figures", "outputs/figures"), ("select", "???")],
)
def test_commands_of_a_study_stage_write_under_outputs_by_default(name, default):
    """Run from the repository root, their default output is never the committed results/
    (only the pipeline's stages write there, with an explicit out=)."""
    from bgap.analysis import figures
    from bgap.common.config import compose
    from bgap.experiments import parity, select

    schemas = {"parity": parity.SCHEMAS, "figures": figures.SCHEMAS, "select": select.SCHEMAS}
    composed = compose(name, [], schemas[name])
    assert composed.out == default if default != "???" else composed._get_node("out")._is_missing()


def test_a_shipped_preset_reads_through_its_schema_fresh_and_once_per_version(
    tmp_path, monkeypatch
):
    """``presets.shipped``: the packaged folder wins over the pipeline's (Hydra's order), each
    call gets its own copy, an edited file is read again, and a missing one is None or one
    line with the group's presets."""
    import bgap.common.presets as presets
    from bgap.common.errors import ConfigError
    from bgap.traffic.scenario import EnvConfig

    packaged, pipeline = tmp_path / "conf", tmp_path / "results"
    for folder, lanes in ((packaged, 3), (pipeline, 5)):
        (folder / "env").mkdir(parents=True)
        (folder / "env" / "road.yaml").write_text(f"defaults: [base_env]\nlanes_count: {lanes}\n")
    (pipeline / "env" / "other.yaml").write_text("lanes_count: 2\n")
    monkeypatch.setattr(presets, "SHIPPED", (str(packaged), str(pipeline)))
    first = presets.shipped(EnvConfig, "env", "road")
    assert first == presets.load_preset(EnvConfig, packaged / "env" / "road.yaml")
    assert first.lanes_count == 3 and presets.shipped(EnvConfig, "env", "other").lanes_count == 2
    first.lanes_count = 9  # the caller's copy, not the cache
    assert presets.shipped(EnvConfig, "env", "road").lanes_count == 3
    (packaged / "env" / "road.yaml").write_text("lanes_count: 4\n")  # another size: read again
    assert presets.shipped(EnvConfig, "env", "road").lanes_count == 4
    assert presets.shipped(EnvConfig, "env", "none") is None
    with pytest.raises(ConfigError, match=r"^no road; use one of \['other', 'road'\]$"):
        presets.shipped(EnvConfig, "env", "none", "no road")
