"""Replayed traffic (issue 37) on highway-env's road, the reference: an exact replay of a
recorded episode, the reactive takeover behind a braking ego, and the tables refused."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from bgap.agents.policies import rollout
from bgap.common.errors import TrajectoryError
from bgap.traffic.replay import Replay
from bgap.traffic.road import IDLE, SLOWER
from bgap.traffic.scenario import env_config
from tests.conftest import make_cfg, scenes_table


def _replaying(config: dict, table, **traffic) -> dict:
    settings = {"source": "replay", "table": str(table), "mode": "log", "min_duration": 5.0,
                "vehicle": None, "start": None, "scene": None, **traffic}  # fmt: skip
    return {**config, "traffic": settings}


@pytest.mark.parametrize("density", ["sparse", pytest.param("dense", marks=pytest.mark.slow)])
def test_a_recorded_episode_replays_exactly_around_the_same_ego(tmp_path, density):
    """An episode recorded with the idle ego, replayed in log mode with the ego put where the
    recorded ego was and driven idle again: every recorded vehicle at its recorded position,
    to 1e-9 m, frame after frame, and the ego on its own track (here exactly: the same
    initial state and actions integrate to the same frames)."""
    config = env_config(make_cfg(f"env={density}", "env.duration=8"))
    recorded = rollout(config, "idle", [3], backend="highway", record=True)
    path = tmp_path / "recorded.parquet"
    recorded.trajectories.to_parquet(path)
    replay = _replaying(config, path, vehicle=0, start=0.0)
    again = rollout(replay, lambda obs: np.full(len(obs), IDLE), [11], backend="highway",
                    record=True)  # fmt: skip
    assert again.episodes.steps.tolist() == recorded.episodes.steps.tolist()
    both = recorded.trajectories.merge(again.trajectories, on=["frame", "vehicle_id"],
                                       suffixes=("", "_replayed"))  # fmt: skip
    assert len(both) == len(recorded.trajectories)
    others = both[both.vehicle_id > 0]
    assert np.abs(others.x - others.x_replayed).max() < 1e-9
    assert np.abs(others.y - others.y_replayed).max() < 1e-9
    ego = both[both.vehicle_id == 0]
    step = ego.speed.max() / 15.0  # one frame's travel
    assert np.abs(ego.x - ego.x_replayed).max() <= step
    assert np.abs(ego.y - ego.y_replayed).max() <= step


def _follower_table(path) -> pd.DataFrame:
    """One lane, 30 s at 15 Hz: vehicle 1 at x = 100 m and vehicle 2 at x = 60 m, both at a
    steady 20 m/s. The ego takes vehicle 1's place and brakes."""
    t = np.arange(451) / 15.0
    rows = [
        pd.DataFrame(
            {
                "episode": 0,
                "frame": np.arange(451),
                "time": t,
                "vehicle_id": vid,
                "x": x0 + 20.0 * t,
                "y": 0.0,
                "vx": 20.0,
                "vy": 0.0,
                "lane": 0,
                "label": "conservative",
            }
        )  # fmt: skip
        for vid, x0 in ((1, 100.0), (2, 60.0))
    ]
    table = pd.concat(rows, ignore_index=True)
    table.to_parquet(path)
    return table


def test_log_mode_runs_into_a_braking_ego_and_reactive_mode_brakes(tmp_path):
    """The recorded follower cannot react in log mode: it rear-ends the braking ego, and the
    crash is reported as a contact with a vehicle following its log. In reactive mode it
    switches to IDM behind the ego and stops in time."""
    from bgap.envs import make_highway

    path = tmp_path / "follower.parquet"
    _follower_table(path)
    config = env_config(make_cfg("env=sparse", "env.duration=30"))
    ends = {}
    for mode in ("log", "reactive"):
        env = make_highway(_replaying(config, path, mode=mode, vehicle=1, start=0.0))
        env.reset(seed=0)
        assert env.unwrapped.config["lanes_count"] == 1 and len(env.unwrapped.road.vehicles) == 2
        for _ in range(30):
            _, _, terminated, truncated, info = env.step(SLOWER)
            if terminated or truncated:
                break
        ends[mode] = (bool(info["crashed"]), bool(info["log_contact"]))
        follower = env.unwrapped.road.vehicles[1]
        ends[mode] += (follower.switched,)
    assert ends["log"] == (True, True, False)
    assert ends["reactive"] == (False, False, True)


@pytest.mark.parametrize(
    "edit,message",
    [
        (lambda t: t.drop(columns="lane"), "needs a lane column"),
        (lambda t: t[t.frame == 0], "single frame"),
        (
            lambda t: t.assign(x=np.where((t.vehicle_id == 2) & (t.frame == 200), t.x + 30, t.x)),
            "jumps",
        ),
        (lambda t: t[t.vehicle_id == 1], "one vehicle"),
        (lambda t: t[t.frame < 30], "stays 5 s"),
        (lambda t: t.assign(x=-t.x, vx=-t.vx), "drive towards -x"),
    ],
)
def test_tables_no_episode_can_come_from_are_refused_in_one_line(tmp_path, edit, message):
    table = edit(_follower_table(tmp_path / "good.parquet"))
    path = tmp_path / "bad.parquet"
    table.to_parquet(path)
    with pytest.raises(TrajectoryError, match=message) as err:
        Replay(path, 15, 5.0)
    assert "\n" not in str(err.value)


def test_recording_replayed_traffic_is_refused_by_the_library_too(tmp_path):
    """The command refuses it with its config; a script building the vector backend with
    ``record=True`` meets the same refusal, not a half-recorded table."""
    from bgap.common.errors import ConfigError
    from bgap.sim.vector import VectorHighway

    path = tmp_path / "t.parquet"
    _follower_table(path)
    config = _replaying(env_config(make_cfg("env=sparse", "env.duration=30")), path)
    with pytest.raises(ConfigError, match="recording replayed traffic is not supported"):
        VectorHighway(config, 1, record=True)


@pytest.mark.parametrize(
    "density,mode",
    [pytest.param("dense", "log", marks=pytest.mark.slow), ("sparse", "reactive"),
     pytest.param("dense", "reactive", marks=pytest.mark.slow)],
)  # fmt: skip
def test_the_vector_backend_replays_as_highway_env_does(tmp_path, density, mode):
    """Two recorded scenes replayed on both backends from the same seeds, a random ego: the
    same windows, observations, rewards, endings and log contacts, step after step (the
    windows end, the ego crashes into recorded vehicles, reactive ones take over)."""
    from bgap.envs import make_highway
    from bgap.sim.vector import VectorHighway

    config = env_config(make_cfg(f"env={density}", "env.duration=20", "mix=0.5"))
    recorded = rollout(config, "idle", [3, 4], backend="highway", record=True)
    recorded.trajectories.to_parquet(tmp_path / "recorded.parquet")
    replay = _replaying(config, tmp_path / "recorded.parquet", mode=mode)
    endings = set()
    for seed in range(4 if density == "dense" else 3):
        env = make_highway(replay)
        obs, _ = env.reset(seed=seed)
        venv = VectorHighway(replay, 1)
        vobs, _ = venv.reset(seed=[seed])
        np.testing.assert_allclose(vobs[0], obs, atol=1e-6)
        rng = np.random.default_rng(seed)
        for _ in range(25):
            action = int(rng.integers(5))
            obs, reward, term, trunc, info = env.step(action)
            vobs, vreward, vterm, vtrunc, vinfo = venv.step(np.array([action]))
            mine = vinfo["final_obs"][0] if vterm[0] or vtrunc[0] else vobs[0]
            np.testing.assert_allclose(mine, obs, atol=1e-6)
            assert vreward[0] == pytest.approx(reward, abs=1e-9)
            assert (vterm[0], vtrunc[0]) == (term, trunc)
            assert bool(vinfo["log_contact"][0]) == info["log_contact"]
            if term or trunc:
                endings.add(("crash" if term else "window", info["log_contact"]))
                break
    assert ("window", False) in endings  # some windows ran out ...
    if density == "dense":  # ... others ended in crashes (with a log vehicle in log mode)
        assert ("crash", mode == "log") in endings


def test_evaluation_grids_take_replay_cells_beside_simulated_ones(tmp_path):
    """``grid.replays=[sparse:TABLE]``: each table x mode is a cell whose mix is the table's
    labelled aggressive share (by hand from the recording's labels), whose episodes are
    those of a plain ``traffic=replay`` rollout on the same seeds, and whose rows carry the
    replay's name; simulated cells beside it carry "" (never a missing key)."""
    from bgap.common.config import validate
    from bgap.experiments.evaluate import evaluate, grid_cells
    from bgap.experiments.evaluate_results import summarize
    from tests.configs import compose

    config = env_config(make_cfg("env=sparse", "env.duration=12", "mix=0.4"))
    recorded = rollout(config, "idle", [3, 4], backend="vector", record=True).trajectories
    table = tmp_path / "sumo-like" / "trajectories.parquet"
    table.parent.mkdir()
    recorded.to_parquet(table)
    tracks = recorded.drop_duplicates(["episode", "vehicle_id"]).label.map(str)
    share = (tracks == "aggressive").sum() / tracks.isin(["aggressive", "conservative"]).sum()
    cfg = validate(compose("evaluate", [
        "env=sparse", "env.duration=12", "grid.mixes=[0.0]", f"grid.replays=[sparse:{table}]",
        "grid.modes=[log,reactive]", "traffic.min_duration=5", "backend=vector",
    ]))  # fmt: skip
    cells = grid_cells(cfg)
    assert [(c.mix, c.replay) for c in cells] == [
        (0.0, ""), (share, "sumo-like/log"), (share, "sumo-like/reactive")]  # fmt: skip
    episodes = evaluate(cfg, {"idle": "idle"}, episodes=3, progress=False)
    names = ["", "sumo-like/log", "sumo-like/reactive"]
    assert list(episodes.replay) == [name for name in names for _ in range(3)]
    plain = validate(compose("evaluate", [  # the same run with traffic=replay, one table
        "env=sparse", "env.duration=12", "traffic=replay", f"traffic.table={table}",
        "traffic.mode=reactive", "traffic.min_duration=5", "backend=vector",
    ]))  # fmt: skip
    seeds = [cfg.eval_seed + k for k in range(3)]
    direct = rollout(env_config(plain), "idle", seeds, "vector").episodes
    mine = episodes[episodes.replay == "sumo-like/reactive"].reset_index(drop=True)
    for col in ("steps", "crashed", "avg_speed", "return"):
        assert mine[col].tolist() == direct[col].tolist()
    assert len(summarize(episodes)) == 3


@pytest.mark.parametrize(
    "overrides,message",
    [
        (["grid.replays=[sparse:/nowhere.parquet]"], "no such trajectory table"),
        (["grid.replays=[nodensity:{table}]"], "has no preset env/nodensity.yaml"),
        (["grid.simulated=false"], "needs replays"),
        (["grid.replays=[{table}]", "grid.modes=[live]"], "each one of"),
    ],
)
def test_bad_replay_grids_fail_in_one_line(tmp_path, overrides, message):
    from bgap.common.config import validate
    from bgap.common.errors import ConfigError
    from tests.configs import compose

    table = tmp_path / "t.parquet"
    _follower_table(table)
    with pytest.raises(ConfigError, match=message) as err:
        validate(compose("evaluate", [o.format(table=table) for o in overrides]))
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("backend", ["highway", "vector"])
def test_traffic_scenes_replays_one_side_of_the_split_on_both_backends(tmp_path, backend):
    """``traffic.scenes=test`` draws every window from the table's held-out scenes and
    ``train`` from the others, on both backends; ``all`` (the default) from all six."""
    from bgap.sim.simulators import make_vector_env
    from bgap.traffic.scenes import split_scenes

    train, test = split_scenes("sumo-idm-dense", range(6))
    config = env_config(make_cfg("env=sparse", "env.duration=4"))
    for side, want in (("test", test), ("train", train), ("all", range(6))):
        settings = _replaying(config, scenes_table(tmp_path / side), min_duration=4.0)
        settings["traffic"] |= {"scenes": side} if side != "all" else {}
        venv = make_vector_env(settings, 2, backend)
        inner = venv.env.envs[0].unwrapped if backend == "highway" else venv
        replay = inner.replay
        drawn = {replay.scenes[s].number for s, _ in replay.candidates}
        assert drawn == set(want), side
        venv.reset(seed=0)
        venv.close()
