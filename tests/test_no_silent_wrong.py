"""No silent wrong result: settings a command would drop are refused, trajectory tables are
read whatever their id types, and velocities that do not describe the positions are refused.

Each refusal is one line and exit status 2; where the right answer is to run, the result is
checked against the same table with integer ids (an independent computation of the same
thing)."""

from __future__ import annotations

import os
import re

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bgap.common.errors import TrajectoryError
from tests.commands import command


@pytest.fixture(scope="module")
def table(tmp_path_factory) -> pd.DataFrame:
    """bgap's own recorded traffic (two 30-second sparse scenes), the ego left out."""
    from bgap.common.config import validate
    from bgap.datasets.simulate import simulate
    from tests.configs import compose

    cfg = validate(compose("simulate", ["backend=vector", "env.duration=30", "episodes=2"]))
    t = simulate(cfg, progress=False)
    return t[~t.is_ego].reset_index(drop=True)


def _as_strings(t: pd.DataFrame) -> pd.DataFrame:
    s = t.copy()
    s["episode"] = "scene_" + s.episode.astype(str)
    s["vehicle_id"] = "v" + s.vehicle_id.astype(str)
    return s


@pytest.mark.parametrize(
    "arg,message",
    [
        ("+unknown=1", r"\+unknown=1 is not a setting of this command \(drop it\)"),
        ("+profile.eval_epsiodes=3", "did you mean profile.eval_episodes"),
        ("~mix", "~mix removes a setting this command needs"),
        ("~env", r"~env removes the env preset, which this command needs: choose one instead"),
    ],
)
def test_settings_a_command_would_drop_or_default_are_refused(
    arg, message, tmp_path, monkeypatch, capsys
):
    import re

    monkeypatch.chdir(tmp_path)
    args = ["baselines=[idle]", "backend=vector", "profile.eval_episodes=2", "out=o", arg]
    status, _, err = command("bgap.evaluate", args, monkeypatch, capsys)
    assert status == 2 and err.count("\n") == 1 and re.search(message, err), err
    assert not (tmp_path / "o").exists()  # refused before anything was written


@pytest.mark.parametrize("backend", ["vector", "highway"])
def test_replay_with_string_ids_plays_the_episodes_of_the_same_table_with_integer_ids(
    table, tmp_path, backend
):
    from bgap.common.config import validate
    from bgap.experiments.evaluate import evaluate
    from tests.configs import compose

    played = []
    spread = table.assign(vehicle_id=table.vehicle_id * 7)  # "v14" sorts before "v7" as text
    for name, t in (("int", spread), ("str", _as_strings(spread))):
        t.to_parquet(tmp_path / f"{name}.parquet")
        cfg = validate(
            compose(
                "evaluate",
                [
                    "traffic=replay",
                    f"traffic.table={tmp_path}/{name}.parquet",
                    f"backend={backend}",
                    "traffic.min_duration=10",
                    "env.duration=10",
                ],
            )
        )
        played.append(evaluate(cfg, {"rule": "rule"}, episodes=4, progress=False))
    pd.testing.assert_frame_equal(played[0], played[1])
    assert len(played[0]) == 4


def test_calibration_statistics_read_string_ids_as_integer_ids(table):
    from bgap.calibration.kinematics import class_samples

    a, b = class_samples(table), class_samples(_as_strings(table))
    assert a.keys() == b.keys() and a
    for cls in a:
        for stat in a[cls]:
            np.testing.assert_allclose(np.sort(a[cls][stat]), np.sort(b[cls][stat]))


@pytest.mark.slow
def test_calibrating_to_a_table_with_string_ids_is_calibrating_to_its_integers(
    table, tmp_path, monkeypatch, capsys
):
    """``bgap.calibrate calibrate.target=`` a table whose scenes and vehicles are named by
    strings: the same scores and statistics as the table of the integers they name."""
    import json

    monkeypatch.chdir(tmp_path)
    spread = table.assign(vehicle_id=table.vehicle_id * 7)  # "v14" sorts before "v7" as text
    found = {}
    for name, t in (("int", spread), ("str", _as_strings(spread))):
        t.to_parquet(f"{name}.parquet")
        args = [f"calibrate.target={name}.parquet", "calibrate.trials=1", "calibrate.rounds=1",
                "calibrate.episodes=1", "calibrate.duration=5", "calibrate.min_vehicles=4",
                f"root={name}"]  # fmt: skip
        status, _, err = command("bgap.calibrate", args, monkeypatch, capsys)
        assert status == 0, err
        report = tmp_path / name / "calibration"
        found[name] = (json.loads((report / "scores.json").read_text()),
                       pd.read_csv(report / "statistics.csv"))  # fmt: skip
    ints, strings = (dict(found[n][0], target=None) for n in ("int", "str"))
    for key, value in ints.items():  # sums in another order may differ in the last bits
        if isinstance(value, float):
            assert strings[key] == pytest.approx(value, rel=1e-12), key
        else:
            assert strings[key] == value, key
    pd.testing.assert_frame_equal(found["int"][1], found["str"][1], rtol=1e-12)


@pytest.mark.parametrize(
    "change,message",
    [
        (lambda t: t.assign(vx=t.vx * 3.6), "vx looks like km/h: divide it by 3.6"),
        (lambda t: t.assign(vx=1e9), "drop vx and vy to have them computed"),
        (
            lambda t: t.assign(time=t.time.max() - t.time, frame=t.frame.max() - t.frame),
            "the clock may run backwards",
        ),
    ],
    ids=["km/h", "1e9", "reversed clock"],
)
def test_velocities_that_do_not_describe_the_positions_are_refused(
    table, change, message, tmp_path, monkeypatch, capsys
):
    """By the reader, and by the command that replays the table (the issue's case: egos
    "driving" 41 million m/s), before any folder is made."""
    from bgap.common.tables import load_trajectories

    load_trajectories(table)  # the table as recorded reads
    with pytest.raises(TrajectoryError, match=message) as err:
        load_trajectories(change(table))
    assert "\n" not in str(err.value)
    monkeypatch.chdir(tmp_path)
    change(table).to_parquet("t.parquet")
    replay = ["traffic=replay", "traffic.table=t.parquet", "traffic.min_duration=10"]
    args = ["baselines=[idle]", "backend=vector", *replay, "env.duration=10", "out=o"]
    status, _, err = command("bgap.evaluate", args, monkeypatch, capsys)
    assert status == 2 and err.count("\n") == 1 and re.search(message, err), err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    "config,message",
    [
        (
            {"vehicle_count": 40},
            "'vehicle_count' is not a setting of the environment (did you mean 'vehicles_count'?)",
        ),
        ({"duration": float("nan")}, "duration=nan is invalid"),
        ({"duration": -5}, "duration=-5 is invalid"),
        ({"action": {"target_speeds": []}}, "action.target_speeds=[] is invalid"),
        ({"lanes_count": 0}, "lanes_count=0 is invalid"),
        ({"behavior": {"aggressive": {"time_gap": 1.0}}}, "is partial: give both classes"),
        (
            {"observation": {"vehicle_count": 40}},
            "observation.vehicle_count is not a setting of the Kinematics observation (did "
            "you mean 'vehicles_count'?)",
        ),
        ({"action": {"target_speed": [10, 20]}}, "(did you mean 'target_speeds'?)"),
        ({"observation": {"type": "Kinematic"}}, "observation.type='Kinematic' is invalid"),
    ],
)
def test_gym_make_refuses_what_it_would_ignore_or_break_on(config, message):
    import gymnasium as gym

    from bgap import ENV_ID
    from bgap.common.errors import ConfigError

    with pytest.raises(ConfigError) as err:
        gym.make(ENV_ID, config=config)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_the_nested_settings_refused_are_those_highway_env_ignores():
    """The reference: highway-env's registered environments' own defaults. Every observation
    and action setting in them is accepted, except a few that highway-env's classes take
    and drop ("flatten", a continuous action's "target_speeds"): built with and without
    such a key, the class holds the same state."""
    from importlib import import_module

    import gymnasium as gym

    from bgap.common.errors import ConfigError
    from bgap.traffic.scenario import NESTED_TYPES, _check_nested

    checked, dropped = set(), set()
    for spec in gym.registry.values():
        if not str(spec.entry_point).startswith("highway_env."):
            continue
        module, name = spec.entry_point.split(":")
        defaults = getattr(import_module(module), name).default_config()
        for key, (where, classes) in NESTED_TYPES.items():
            given, kind = dict(defaults[key]), defaults[key]["type"]
            cls = getattr(import_module(where), classes[kind])
            while True:
                try:
                    _check_nested(key, given, kind)
                    break
                except ConfigError as err:
                    extra = str(err).split(" ")[0].split(".", 1)[1]
                    kept = {k: v for k, v in given.items() if k not in ("type", extra)}
                    with_it, without = cls(None, **kept, **{extra: given[extra]}), cls(None, **kept)
                    assert repr(vars(with_it)) == repr(vars(without)), (spec.id, extra)
                    dropped.add(extra)
                    del given[extra]
            checked.add(kind)
    assert {"Kinematics", "DiscreteMetaAction", "ContinuousAction", "OccupancyGrid"} <= checked
    assert dropped == {"flatten", "target_speeds"}


def test_gym_make_merges_nested_settings_as_the_docs_example_needs():
    """The environment page's example: the observation keeps its type and features and
    reads 40 vehicles, on highway-env's backend and the vector one alike."""
    import gymnasium as gym

    from bgap import ENV_ID
    from bgap.sim.vector import VectorHighway

    config = {"vehicles_count": 40, "observation": {"vehicles_count": 40}}
    env = gym.make(ENV_ID, config=config)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (40, 5)
    assert env.unwrapped.config["observation"]["type"] == "Kinematics"
    assert VectorHighway(config, 1).observation_space.shape[-2:] == (40, 5)


@pytest.mark.parametrize(
    "source,message",
    [
        (lambda t: 42, "takes a DataFrame or a .csv/.parquet path, not int"),
        (lambda t: t[t.frame < 2], "shorter than CMetric's window (3 s)"),
        (
            lambda t: t.assign(x=t.x / 1000, y=t.y / 1000, vx=t.vx / 1000, vy=t.vy / 1000),
            "outside road traffic's 0.3-80 m/s",
        ),
    ],
    ids=["not a table", "two frames", "kilometres"],
)
def test_cmetric_refuses_what_it_cannot_score_in_one_line(table, source, message):
    from bgap.cmetric import score_trajectories

    with pytest.raises(TrajectoryError, match=re.escape(message)) as err:
        score_trajectories(source(table))
    assert "\n" not in str(err.value)


SCHEMA_KEYS = ["mix", "radius", "seed", "env.duration", "profile.eval_episodes", "grid", "env"]


@pytest.mark.slow  # the default suite's time budget
@settings(max_examples=60, derandomize=True, deadline=None, database=None)
@given(
    st.one_of(
        st.from_regex(r"\+[a-z]{1,8}(\.[a-z_]{1,10})?=[0-9]", fullmatch=True),
        st.sampled_from(SCHEMA_KEYS).map(lambda k: f"~{k}"),
    )
)
def test_generated_plus_and_tilde_overrides_are_refused_or_honoured(override):
    """``+key`` with a key the schema lacks, and ``~key`` of a setting or preset, never run
    with the setting silently dropped or defaulted: refused in one line, or (a ``+key`` the
    schema has) honoured in the config the command uses."""
    from omegaconf import OmegaConf

    from bgap.common import config
    from bgap.common.errors import ConfigError
    from bgap.common.presets import is_group
    from bgap.experiments.config import SCHEMAS

    key = override.lstrip("+~").split("=")[0]
    if override.startswith("~") and is_group(key):
        with pytest.raises(ConfigError, match="preset, which this command needs"):
            config._refuse_removed(override)
        return
    try:
        composed = config.compose("evaluate", [override], SCHEMAS)
    except Exception:  # noqa: BLE001 - Hydra refuses it itself (the app prints one line)
        return
    try:
        used = config.load(composed)
    except ConfigError as err:
        assert "\n" not in str(err) and key.split(".")[-1] in str(err)
        return
    assert override.startswith("+")  # only a key the schema knows may pass
    assert OmegaConf.select(OmegaConf.structured(used), key) is not None


def test_a_file_where_the_output_folder_goes_and_a_full_disk_are_one_line(
    tmp_path, monkeypatch, capsys
):
    """out= naming an existing file, and a disk that fills while results are written: one
    line each, exit status 2, no traceback, the file untouched."""
    import errno

    from bgap.common import runs

    monkeypatch.chdir(tmp_path)
    (tmp_path / "notes.txt").write_text("mine\n")
    args = ["baselines=[idle]", "profile.eval_episodes=1", "env.duration=2"]
    status, _, err = command("bgap.evaluate", [*args, "out=notes.txt"], monkeypatch, capsys)
    assert status == 2 and err.count("\n") == 1 and "is a file, not a folder" in err, err
    assert (tmp_path / "notes.txt").read_text() == "mine\n"

    faults = {
        errno.ENOSPC: "no space left on the device writing o/",
        errno.EROFS: "is on a read-only file system: give the output (out=, root=) a writable",
        errno.EDQUOT: "the disk quota is used up",
    }
    for code, line in faults.items():

        def fault(path, data, code=code):
            raise OSError(code, os.strerror(code), str(path))

        monkeypatch.setattr(runs, "write_atomic", fault)
        status, _, err = command("bgap.evaluate", [*args, f"out=o{code}"], monkeypatch, capsys)
        assert status == 2 and err.count("\n") == 1 and line.replace("o/", f"o{code}/") in err
        assert "Traceback" not in err and "run the same command again" in err, err

    from bgap.common.cli import machine_fault  # an error that names no file says none

    assert machine_fault(OSError(errno.ENOSPC, "full")).startswith(
        "no space left on the device: free some, and run the same command again"
    )
    assert machine_fault(OSError(errno.EROFS, "ro")).startswith("the output is on a read-only")

    def broken(path, data):  # not a fault of the machine's: a bug keeps its traceback
        raise OSError(errno.EIO, "Input/output error", str(path))

    monkeypatch.setattr(runs, "write_atomic", broken)
    with pytest.raises(OSError, match="Input/output"):
        command("bgap.evaluate", [*args, "out=bug"], monkeypatch, capsys)


@pytest.mark.parametrize("backend", ["vector", "highway"])
def test_a_traffic_the_memory_cannot_hold_is_one_line(backend, tmp_path, monkeypatch, capsys):
    """A hundred million vehicles: refused in one line with the estimate, before the
    out-of-memory killer ends the process without a word; the library says the same."""
    import gymnasium as gym

    from bgap.common.errors import ConfigError

    monkeypatch.chdir(tmp_path)
    args = ["env.vehicles_count=100000000", f"backend={backend}", "episodes=1", "out=o"]
    status, _, err = command("bgap.simulate", args, monkeypatch, capsys)
    last = err.strip().splitlines()[-1]
    assert status == 2 and "vehicles_count=100000000 needs about" in last, err
    assert "GiB available: fewer vehicles" in last and "Traceback" not in err
    assert not (tmp_path / "o").exists()  # found once the traffic is built: taken back
    with pytest.raises(ConfigError, match="needs about 298"):  # 3.2 kB a vehicle
        gym.make("bgap/BehaviorHighway-v0", config={"vehicles_count": 10**8})


@pytest.mark.parametrize("learner", ["sb3", "batched"])
def test_a_replay_buffer_the_memory_cannot_hold_is_one_line(learner, tmp_path, monkeypatch, capsys):
    """Twenty billion transitions: refused before numpy's lazy zeros let the training start
    (SB3's own check only warns); the estimate is the buffer's arrays, counted by hand."""
    monkeypatch.chdir(tmp_path)
    size, features = 20_000_000_000, 5 * 5  # the tiny profile observes 5 vehicles x 5
    slot = 2 * 4 * features + 8 + 3 * 4 + 8 + 2 * 8  # obs, next obs, action, flags, priority
    args = ["profile=tiny", f"agent.buffer_size={size}", f"learner={learner}", "run_dir=run"]
    status, _, err = command("bgap.train", args, monkeypatch, capsys)
    last = err.strip().splitlines()[-1]
    assert status == 2 and "Traceback" not in err, err
    assert f"agent.buffer_size={size} needs about {size * slot / 2**30:,.1f} GiB" in last
    assert not any(tmp_path.iterdir())  # no run folder left to hold the corrected command


def test_a_refused_calibration_target_leaves_no_folder_to_refuse_the_fix(
    tmp_path, monkeypatch, capsys
):
    """A target table that is missing or has no labels is refused before the report folder
    is written: the corrected command would otherwise meet "other settings"."""
    monkeypatch.chdir(tmp_path)
    pd.DataFrame({"episode": [0, 0], "vehicle_id": [1, 1], "frame": [0, 1], "x": [0.0, 1.0],
                  "y": [0.0, 0.0]}).to_csv("unlabelled.csv", index=False)  # fmt: skip
    for target, says in (("missing.csv", "no such file"), ("unlabelled.csv", "no 'label'")):
        args = ["root=out", f"calibrate.target={target}"]
        status, _, err = command("bgap.calibrate", args, monkeypatch, capsys)
        assert status == 2 and says in err and "Traceback" not in err, err
        assert not (tmp_path / "out").exists()


SAVED = {  # command, its config, arguments, the folder its config.yaml is in
    "calibrate": ("bgap.calibrate", "calibrate", ["calibrate.trials=1", "calibrate.rounds=1",
                  "calibrate.episodes=1", "calibrate.duration=5", "root=o"], "o/calibration"),
    "tune_rule": ("bgap.tune_rule", "tune_rule", ["situation=dense", "env=dense", "grid=paper",
                  "grid.densities=[dense]", "grid.mixes=[0.5]", "grid.radii=[180.0]",
                  "env.duration=4", "trials=1", "episodes=1", "out=o", "preset=p.yaml"], "o"),
    "cmetric": ("bgap.cmetric.__main__", "cmetric_app", ["input=t.csv", "out=o/", "fps=5"], "o"),
    "run": ("bgap.run", "run", ["profile=tiny", "mix=0.7", "root=o"], "o/results/*"),
    "recipe": ("bgap.recipe", "recipe", ["profile=tiny", "profile.eval_every_episodes=3",
               "trials=2", "candidates=1", "check_seeds=[0,1]", "check_episodes=10",
               "sweep_eval_episodes=2", "root=o"], "o/recipe"),
    "train": ("bgap.train", "train", ["profile=tiny", "policy=default", "mix=0.8",
              "run_dir=o"], "o"),
}  # fmt: skip


@pytest.mark.slow
@pytest.mark.parametrize("name", list(SAVED))
def test_the_saved_config_is_the_config_the_command_used(name, tmp_path, monkeypatch, capsys):
    """The commands beyond simulate, evaluate, watch and zoo (tests/test_zoo.py): the saved
    ``config.yaml`` is the config composed from the command line, except where the command
    documents that it trains under another (policy=default: stock traffic at a fixed mix)."""
    import yaml
    from omegaconf import OmegaConf

    from bgap.calibration.config import SCHEMAS as CALIBRATE
    from bgap.cmetric.config import SCHEMAS as CMETRIC
    from bgap.common import config as plumbing
    from bgap.experiments.config import SCHEMAS as EXPERIMENTS
    from bgap.experiments.tune_rule import SCHEMAS as TUNE_RULE

    monkeypatch.chdir(tmp_path)
    module, config, args, folder = SAVED[name]
    if name == "cmetric":  # a table of 4 vehicles over 5 s, at 5 frames a second
        frames = np.tile(np.arange(25), 4)
        vehicle = np.repeat(np.arange(4), 25)
        x = vehicle * 30.0 + 25.0 * frames / 5
        table = {
            "episode": 0,
            "vehicle_id": vehicle,
            "frame": frames,
            "x": x,
            "y": vehicle % 2 * 4.0,
        }
        pd.DataFrame(table).to_csv("t.csv", index=False)
    status, _, err = command(module, args, monkeypatch, capsys)
    assert status == 0, err
    schemas = {"calibrate": CALIBRATE, "tune_rule": TUNE_RULE, "cmetric_app": CMETRIC,
               "train": EXPERIMENTS, "run": EXPERIMENTS, "recipe": EXPERIMENTS}[config]  # fmt: skip
    expected = OmegaConf.to_container(plumbing.compose(config, args, schemas), resolve=True)
    (saved,) = tmp_path.glob(f"{folder}/config.yaml")  # the results of bgap.run: one folder
    saved = yaml.safe_load(saved.read_text())
    if name == "train":  # policy=default trains in stock traffic, at the mix it samples
        assert saved["behavior"]["name"] == "stock" and expected["behavior"]["name"] != "stock"
        assert saved.pop("mix_sampling") == "fixed"
        expected.pop("mix_sampling")
        saved.pop("behavior"), expected.pop("behavior")
    assert saved == expected


@st.composite
def _drives(draw) -> tuple[pd.DataFrame, list]:
    """A physically consistent table: 2-6 vehicles at 5-40 m/s in two lanes, 10 Hz for 2-5 s,
    with velocities; their ids integers, strings or both; and the integers they stand for."""
    n = draw(st.integers(2, 6))
    steps = draw(st.integers(20, 50))
    kind = draw(st.sampled_from(["int", "str", "mixed"]))
    numbers = draw(st.lists(st.integers(0, 500), min_size=n, max_size=n, unique=True))
    speeds = draw(st.lists(st.floats(5.0, 40.0), min_size=n, max_size=n))
    ids = [v if kind == "int" or (kind == "mixed" and k % 2) else f"car{v}"
           for k, v in enumerate(numbers)]  # fmt: skip
    t = np.arange(steps) / 10.0
    rows = [
        pd.DataFrame(
            {
                "vehicle_id": [ident] * steps,
                "time": t,
                "x": 20.0 * k + speed * t,
                "y": 4.0 * (k % 2),
                "vx": speed,
                "vy": 0.0,
            }
        )  # fmt: skip
        for k, (ident, speed) in enumerate(zip(ids, speeds, strict=True))
    ]
    return pd.concat(rows, ignore_index=True), numbers


DEFECTS = {
    "none": (lambda t: t, None),
    "km/h": (lambda t: t.assign(vx=t.vx * 3.6), "vx looks like km/h: divide it by 3.6"),
    "feet per second": (lambda t: t.assign(vx=t.vx * 3.28084), "x the speed its positions"),
    "clock backwards": (lambda t: t.assign(time=t.time.max() - t.time), "may run backwards"),
    "halved": (lambda t: t.assign(vx=t.vx * 0.4), "x the speed its positions change at"),
}


@settings(max_examples=100, derandomize=True, deadline=None, database=None)
@given(_drives(), st.sampled_from(list(DEFECTS)))
def test_generated_tables_with_any_ids_read_or_their_defect_is_one_line(drive, defect):
    """Any id type reads as the table of the integers it names; each unit error, reversed
    clock or inconsistent velocity is refused in one line naming it."""
    from bgap.common.tables import load_trajectories

    table, numbers = drive
    change, message = DEFECTS[defect]
    if message is not None:
        with pytest.raises(TrajectoryError, match=re.escape(message)) as err:
            load_trajectories(change(table), fps=10)
        assert "\n" not in str(err.value)
        return
    read = load_trajectories(table, fps=10)
    names = dict(zip(table.vehicle_id.unique(), numbers, strict=True))
    as_int = load_trajectories(table.assign(vehicle_id=table.vehicle_id.map(names)), fps=10)
    key = ["episode", "frame"]
    read = read.assign(vehicle_id=read.vehicle_id.map(names)).sort_values([*key, "vehicle_id"])
    as_int = as_int.sort_values([*key, "vehicle_id"])
    columns = [*key, "time", "vehicle_id", "x", "y", "vx", "vy"]
    pd.testing.assert_frame_equal(
        read[columns].reset_index(drop=True), as_int[columns].reset_index(drop=True),
        check_dtype=False,
    )  # fmt: skip


VALUES = st.one_of(
    st.integers(-3, 12),
    st.floats(allow_nan=True, allow_infinity=True, width=32),
    st.sampled_from(["", "dense", [], [1, 2]]),
)
ENV_KEYS = ["vehicles_count", "lanes_count", "duration", "mix", "perception_radius",
            "policy_frequency", "vehicle_count", "lane_count", "radius"]  # fmt: skip


@settings(max_examples=400, derandomize=True, deadline=None, database=None)
@given(
    st.dictionaries(st.sampled_from(ENV_KEYS), VALUES, max_size=3),
    st.dictionaries(st.sampled_from(["vehicles_count", "vehicle_count", "order"]), VALUES,
                    max_size=2),
)  # fmt: skip
def test_generated_gym_make_configs_are_honoured_or_refused_in_one_line(top, observation):
    """Whatever a script passes to ``gym.make``: the environment runs with exactly those
    settings, or one ConfigError (a ValueError) names the key; nothing else escapes."""
    import gymnasium as gym

    from bgap import ENV_ID
    from bgap.common.errors import ConfigError

    config = {**top, **({"observation": observation} if observation else {})}
    try:
        env = gym.make(ENV_ID, config=config)
        env.reset(seed=0)
        env.step(1)
    except ConfigError as err:
        assert "\n" not in str(err)
        return
    used = env.unwrapped.config
    assert all(used[k] == v for k, v in top.items()), (config, used)
    assert all(used["observation"][k] == v for k, v in observation.items())


@pytest.mark.slow
def test_a_dense_model_in_sparse_traffic_is_refused_by_every_command(tmp_path, monkeypatch, capsys):
    """The issue's case (simulate gave SB3's shape error): a model observing 40 vehicles in
    traffic observing 5, refused in one line by simulate, as evaluate refuses it."""
    monkeypatch.chdir(tmp_path)
    status, _, err = command("bgap.train", ["env=dense", "profile=tiny", "run_dir=run"],
                             monkeypatch, capsys)  # fmt: skip
    assert status == 0, err
    for module, args in (
        ("bgap.simulate", ["policy=run/model.zip", "env=sparse", "episodes=1", "out=s"]),
        ("bgap.evaluate", ["models=[run]", "baselines=[]", "env=sparse", "out=e"]),
    ):
        status, _, err = command(module, args, monkeypatch, capsys)
        assert status == 2 and err.count("\n") == 1 and "Traceback" not in err, err
        assert "40" in err and "5" in err
        assert not (tmp_path / args[-1][4:]).exists()
