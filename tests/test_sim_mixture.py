"""The mixture's traffic on the vector backend (bgap.sim.mixture): episodes draw their
sources with the documented weights (chi-square), a drawn episode's drivers carry their
class's parameters times their own factor (hand-computed from the presets), stock episodes
carry highway-env's IDM, replayed environments play training scenes only, and the same seed
gives the same episodes."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest
from scipy.stats import chisquare

from bgap.common.errors import ConfigError
from bgap.sim import core
from bgap.sim.highway_params import IDM_DEFAULTS
from bgap.sim.mixture import DrawnTraffic, MixtureHighway, SplitReplay, member_sizes
from bgap.sim.sb3 import SB3VecEnv
from bgap.traffic.mixture import MixtureConfig
from bgap.traffic.scenario import env_config
from bgap.traffic.scenes import split_scenes, table_name
from tests.conftest import make_cfg, scenes_table

ROWS = 17


def _config() -> dict:
    return env_config(make_cfg("env=sparse", f"env.observed_vehicles={ROWS}", "env.duration=4"))


def test_episodes_draw_bgap_and_stock_with_their_weights():
    """3,000 episodes, 100 of each of 30 environments: bgap against stock at 0.5 : 0.2
    (the default weights, replay left out), chi-square at the 1% level."""
    mixture = MixtureConfig(sources={"bgap": 0.5, "stock": 0.2, "replay": 0.0}, vehicles=[5])
    env = DrawnTraffic({**_config(), "vehicles_count": 5}, 30, mixture)
    env.reset(seed=0)
    counts = Counter(d.source for d in env.drawn)
    for _ in range(99):  # a reset, or an automatic one, spawns each env's next episode
        env._spawn(np.arange(30))
        counts.update(d.source for d in env.drawn)
    n = sum(counts.values())
    assert chisquare([counts["bgap"], counts["stock"]], [n * 5 / 7, n * 2 / 7]).pvalue > 0.01


def test_a_drawn_episodes_drivers_carry_their_class_times_their_factor():
    """Each vehicle's time gap, accelerations and MOBIL parameters are its preset class's
    (Table I for ``paper``) times its drawn factor, its minimum gap likewise bumper to
    bumper; stock episodes keep highway-env's IDM and label nobody aggressive."""
    mixture = MixtureConfig(sources={"bgap": 1.0, "stock": 1.0, "replay": 0.0}, classes=["paper"])
    env = DrawnTraffic({**_config(), "vehicles_count": 10}, 40, mixture)
    env.reset(seed=3)
    paper = {  # Table I (bgap/conf/behavior/paper.yaml): T, min gap, a, b, politeness, gain, b_safe
        core.CONSERVATIVE: (1.5, 5.0, 3.0, 6.0, 0.5, 0.2, 3.0),
        core.AGGRESSIVE: (1.2, 2.5, 6.0, 9.0, 0.0, 0.0, 9.0),
    }
    seen = set()
    for b, drawn in enumerate(env.drawn):
        labels = env.g[b, 1:, core.LABEL]
        if drawn.source == "stock":
            assert (labels != core.AGGRESSIVE).all()
            columns = [core.P_T, core.P_A, core.P_B, core.P_POLITENESS, core.P_GAIN]
            assert np.allclose(env.p[b, 1:, columns], IDM_DEFAULTS[columns][:, None])
            seen.add("stock")
            continue
        assert (labels == core.AGGRESSIVE).sum() == round(drawn.mix * 10)
        for i, factor in enumerate(drawn.scale):
            t, gap, a, brake, polite, gain, b_safe = paper[int(labels[i])]
            row = env.p[b, i + 1]
            assert row[core.P_T] == pytest.approx(t * factor)
            assert row[core.P_D0] == pytest.approx(gap * factor + 5.0)
            assert row[core.P_A] == pytest.approx(a * factor)
            assert row[core.P_B] == pytest.approx(brake * factor)
            assert row[core.P_POLITENESS] == pytest.approx(polite * factor)
            assert row[core.P_GAIN] == pytest.approx(gain * factor)
            assert row[core.P_BSAFE] == pytest.approx(b_safe * factor)
        seen.add("bgap")
    assert seen == {"bgap", "stock"}


def test_replayed_environments_play_training_scenes_only(tmp_path):
    """The replay member's windows, over 600 resets, all come from the table's training
    scenes (four of six), and every training scene is played."""
    table = scenes_table(tmp_path)
    train, test = split_scenes("sumo-idm-dense", range(6))
    assert table_name(table) == "sumo-idm-dense" and len(test) == 2
    mixture = MixtureConfig(sources={"bgap": 0.0, "stock": 0.0, "replay": 1.0}, tables=[table])
    env = MixtureHighway(_config(), 12, mixture, min_duration=4.0)
    (member,) = env.members
    assert member.training_scenes == train and member.test_scenes == test
    scene_of = {track: s for (s, _), track in member._track_of.items()}
    played = set()
    env.reset(seed=0)
    for _ in range(50):
        member._spawn(np.arange(12))
        tracks = member._rp[:, 1:, core.R_TRACK]
        played |= {member.replay.scenes[scene_of[t]].number for t in tracks[tracks >= 0]}
    assert played == set(train)


def test_a_test_side_replay_plays_the_held_out_scenes_only(tmp_path):
    """The other side of the split, in log mode as the study's evaluation may play it: 600
    windows, all from the two held-out scenes, both played."""
    table = scenes_table(tmp_path)
    _, test = split_scenes("sumo-idm-dense", range(6))
    env = SplitReplay(_config(), 12, table, 4.0, side="test", mode="log")
    scene_of = {track: s for (s, _), track in env._track_of.items()}
    env.reset(seed=5)
    played = set()
    for _ in range(50):
        env._spawn(np.arange(12))
        tracks = env._rp[:, 1:, core.R_TRACK]
        played |= {env.replay.scenes[scene_of[t]].number for t in tracks[tracks >= 0]}
    assert played == set(test)
    with pytest.raises(ConfigError, match="side='held' is invalid"):
        SplitReplay(_config(), 2, table, 4.0, side="held")


def test_members_share_the_environments_and_step_as_one(tmp_path):
    """The replay weight's share of the environments replays, the rest is shared among the
    vehicle counts; one step of the whole equals each member's own step from the same
    seeds; the SB3 adapter takes it."""
    table = scenes_table(tmp_path)
    mixture = MixtureConfig(vehicles=[5, 10], tables=[table])
    assert member_sizes(mixture, 20) == ([(5, 7), (10, 7)], [6])
    env = MixtureHighway(_config(), 20, mixture, min_duration=4.0)
    assert [m.num_envs for m in env.members] == [7, 7, 6]
    obs, info = env.reset(seed=10)
    assert obs.shape == (20, ROWS, 5) and info["speed"].shape == (20,)
    actions = np.random.default_rng(0).integers(0, 5, 20)
    whole = [env.step(actions) for _ in range(10)]
    again = MixtureHighway(_config(), 20, mixture, min_duration=4.0)
    again.reset(seed=10)
    for step in whole:  # the same seed, the same episodes
        obs, rewards, *_ = again.step(actions)
        assert np.array_equal(obs, step[0]) and np.array_equal(rewards, step[1])
    alone = MixtureHighway(_config(), 20, mixture, min_duration=4.0).members[1]
    alone.reset(seed=list(range(17, 24)))
    first = MixtureHighway(_config(), 20, mixture, min_duration=4.0)
    first.reset(seed=10)
    assert np.array_equal(first.step(actions)[0][7:14], alone.step(actions[7:14])[0])
    venv = SB3VecEnv(env)
    venv.reset()
    for _ in range(12):  # episodes of 4 s end: terminal observations pass through
        _, _, dones, infos = venv.step(np.full(20, 1))
    assert all("terminal_observation" in i for i, d in zip(infos, dones, strict=True) if d)


def test_a_replay_weight_without_tables_is_refused_in_one_line():
    with pytest.raises(ConfigError, match="mixture.tables"):
        MixtureHighway(_config(), 10, MixtureConfig())


def test_a_saved_state_resumes_the_same_episodes(tmp_path):
    """Ten steps after a state is saved, in the same environment and in a new one the state
    was loaded into: the same observations and rewards, automatic resets (each env's next
    draw) included."""
    mixture = MixtureConfig(vehicles=[5, 10], tables=[scenes_table(tmp_path)])
    env = MixtureHighway(_config(), 14, mixture, min_duration=4.0)
    env.reset(seed=7)
    rng = np.random.default_rng(1)
    for _ in range(3):
        env.step(rng.integers(0, 5, 14))
    state = env.state_dict()
    actions = [rng.integers(0, 5, 14) for _ in range(10)]  # 4 s episodes: resets within
    ahead = [env.step(a)[:2] for a in actions]
    again = MixtureHighway(_config(), 14, mixture, min_duration=4.0)
    again.load_state_dict(state)
    for a, (obs, rewards) in zip(actions, ahead, strict=True):
        o, r, *_ = again.step(a)
        assert np.array_equal(o, obs) and np.array_equal(r, rewards)


@pytest.mark.slow  # the default suite's time budget
def test_traffic_mixture_trains_through_the_one_door_and_refuses_highway_env(tmp_path):
    """``traffic=mixture`` composes, ``make_vector_env`` makes it as MixtureHighway (the
    replay weight's environments on the table's training side), a PPO training at the
    tiny profile runs on it in a run folder named for the mixture; highway-env, recording
    and too few environments are refused in one line."""
    from bgap.common.config import validate
    from bgap.experiments.config import compose
    from bgap.experiments.train import train
    from bgap.sim.simulators import make_vector_env

    table = scenes_table(tmp_path)
    # the road has the table's two lanes: the scripted egos (references) read one road
    overrides = ["traffic=mixture", f"traffic.mixture.tables=[{table}]", "traffic.min_duration=4",
                 "traffic.mixture.vehicles=[5,10]", "env.observed_vehicles=17", "profile=tiny",
                 "profile.n_envs=6", "agent=ppo", f"root={tmp_path}",
                 "env.lanes_count=2"]  # fmt: skip
    cfg = validate(compose("train", overrides))
    config = env_config(cfg)
    env = make_vector_env(config, 6)
    assert isinstance(env, MixtureHighway) and [m.num_envs for m in env.members] == [2, 2, 2]
    with pytest.raises(ConfigError, match="backend=vector only"):
        make_vector_env(config, 6, "highway")
    with pytest.raises(ConfigError, match="n_envs=2 is invalid"):
        make_vector_env(config, 2)
    folder = train(cfg, progress=False)
    assert folder.name.startswith("mixture-behavior_rich-drawn-tiny-s0-")
    assert (folder / "model.zip").is_file()


def test_the_added_columns_read_each_environments_own_road(tmp_path):
    """A replayed table's road (two lanes here) beside bgap's four: the observation options,
    the rule-based ego's suggestion included, read each environment on its own road."""
    from bgap.agents.observation import ObservationFeatures, WithFeatures

    mixture = MixtureConfig(vehicles=[5, 10], tables=[scenes_table(tmp_path)])
    env = MixtureHighway(_config(), 20, mixture, min_duration=4.0)
    assert env.env_lanes.tolist() == [4] * 14 + [2] * 6
    options = ["ttc", "rule"]
    wrapped = WithFeatures(env, ObservationFeatures(options, _config()))
    seen = wrapped.reset(seed=10)[0]
    raw = env.observations()
    for lanes, rows in ((4, slice(0, 14)), (2, slice(14, 20))):
        own = ObservationFeatures(options, {**_config(), "lanes_count": lanes})(raw[rows])
        np.testing.assert_array_equal(seen[rows], own)


def test_the_generalisation_preset_trains_stock_only_beside_and_tests_on_held_out_traffic(
    tmp_path,
):
    """``bgap.run experiment=generalisation``: the behaviour-rich policy trains on the
    mixture, the default one on its stock source alone at the same vehicle counts; both are
    tested on bgap's drivers in every density and on the tables' held-out scenes, every
    policy observing the 17 rows it trained with."""
    from bgap.common.config import validate
    from bgap.experiments.evaluate import cell_env_config, grid_cells
    from bgap.experiments.training import training_config
    from tests.configs import compose

    table = scenes_table(tmp_path)
    cfg = validate(
        compose(
            "run",
            [
                "experiment=generalisation",
                f"traffic.mixture.tables=[{table}]",
                f"grid.replays=[dense:{table}]",
            ],
        )
    )
    rich, stock = training_config(cfg, "behavior_rich"), training_config(cfg, "default")
    assert rich.traffic.mixture.sources == {"bgap": 0.5, "stock": 0.2, "replay": 0.3}
    assert stock.traffic.mixture.sources == {"stock": 1.0} and stock.traffic.mixture.tables == []
    assert stock.traffic.mixture.vehicles == rich.traffic.mixture.vehicles == [5, 10, 20, 30, 40]
    cells = grid_cells(cfg)
    assert [(c.density, bool(c.table)) for c in cells] == [
        ("sparse", False), ("dense", False), ("dense", True)
    ]  # fmt: skip
    configs = [cell_env_config(cfg, c) for c in cells]
    assert {c["observation"]["vehicles_count"] for c in configs} == {ROWS}
    assert [c["vehicles_count"] for c in configs[:2]] == [5, 40]  # the presets' counts
    sources = [c.get("traffic", {}).get("source", "simulated") for c in configs]
    assert sources == ["simulated", "simulated", "replay"]  # (simulated: no traffic key)
    assert configs[2]["traffic"]["scenes"] == "test" and configs[2]["traffic"]["mode"] == "reactive"


def test_a_table_of_another_road_is_refused_where_the_hand_built_egos_read_one(tmp_path):
    """The checkpoint rule's scripted references read every environment as the config's
    road: through the one door, a two-lane table beside bgap's four lanes is one line."""
    from bgap.sim.simulators import make_vector_env

    config = {**_config(), "traffic": {"source": "mixture", "min_duration": 4.0}}
    config["traffic"]["mixture"] = {"vehicles": [5, 10], "tables": [scenes_table(tmp_path)]}
    with pytest.raises(ConfigError, match="has 2 lanes where the road has 4"):
        make_vector_env(config, 20, "vector")
    config["lanes_count"] = 2  # the table's road everywhere: taken
    assert make_vector_env(config, 20, "vector").env_lanes.tolist() == [2] * 20
