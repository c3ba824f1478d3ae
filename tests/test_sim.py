"""The vectorised backend (bgap.sim) against highway-env, its reference."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from highway_env.vehicle.behavior import IDMVehicle

from bgap.envs import make_env
from bgap.sim import core
from bgap.sim.highway_scenes import scene_from_highway
from bgap.sim.vector import VectorHighway
from bgap.traffic.behaviors import BehaviorVehicle
from bgap.traffic.road import IDLE
from bgap.traffic.scenario import env_config, fast_mode
from tests.conftest import make_cfg

PARITY = Path(__file__).resolve().parent.parent / "results/parity"


def _twin(*overrides: str, seed: int = 0):
    """A highway-env episode and a one-env vector backend loaded with the same scene."""
    cfg = make_cfg(*overrides)
    env = make_env(cfg)
    env.reset(seed=seed)
    venv = VectorHighway(env_config(cfg), 1)
    venv.reset(seed=0)
    venv.load_scene(0, scene_from_highway(env))
    return env, venv


def _gap(env, venv) -> tuple[float, float]:
    ref = scene_from_highway(env)
    pos = np.abs(ref.f[:, [core.X, core.Y]] - venv.f[0][:, [core.X, core.Y]]).max()
    speed = np.abs(ref.f[:, core.SPEED] - venv.f[0][:, core.SPEED]).max()
    return float(pos), float(speed)


@pytest.mark.parametrize("mix", [0.0, 0.5, 1.0])
def test_loaded_dense_scene_follows_highway_env_for_10_seconds(mix):
    env, venv = _twin("env=dense", f"mix={mix}", seed=3)
    for _ in range(10):  # 10 policy steps = 10 simulated seconds, idle ego
        obs, reward, term, trunc, _ = env.step(IDLE)
        vobs, vreward, vterm, vtrunc, _ = venv.step(np.array([IDLE]))
        pos, speed = _gap(env, venv)
        assert pos < 0.5 and speed < 0.1  # the tolerance ...
        assert pos < 1e-9 and speed < 1e-9  # ... and in fact the same arithmetic
        np.testing.assert_allclose(vobs[0], obs, atol=1e-6)
        assert vreward[0] == pytest.approx(reward) and vterm[0] == term
        if term:
            break


@pytest.mark.parametrize("density,behavior", [("sparse", "paper"), ("dense", "stock")])
def test_random_ego_episode_matches_step_for_step(density, behavior):
    """Lane changes, meta-actions, collisions and episode ends agree, not only idle driving."""
    env, venv = _twin(f"env={density}", f"behavior={behavior}", "mix=0.5", seed=1)
    rng = np.random.default_rng(0)
    lane_changes = 0
    for _ in range(60):
        a = int(rng.integers(5))
        before = scene_from_highway(env).g[1:, core.TARGET_LANE]
        obs, reward, term, trunc, info = env.step(a)
        vobs, vreward, vterm, vtrunc, vinfo = venv.step(np.array([a]))
        assert (vterm[0], vtrunc[0]) == (term, trunc)
        assert vreward[0] == pytest.approx(reward)
        assert bool(vinfo["lane_change"][0]) == info["lane_change"]
        if term or trunc:
            np.testing.assert_allclose(vinfo["final_obs"][0], obs, atol=1e-6)
            break
        assert max(_gap(env, venv)) < 1e-6
        lane_changes += int((scene_from_highway(env).g[1:, core.TARGET_LANE] != before).sum())
    assert lane_changes > 0  # the episode exercised MOBIL


def _scripted_scene(blocker_behind: bool):
    """Lane 0 (leftmost): a fast conservative driver 25 m behind a slow car; lane 1 free, or
    (with ``blocker_behind``) a fast car right behind the gap so the change is unsafe."""
    cfg = make_cfg("env=sparse", "env.vehicles_count=0", "env.duration=20")
    env = make_env(cfg)
    env.reset(seed=0)
    u = env.unwrapped
    road = u.road
    u.vehicle.position = np.array([0.0, 12.0])  # the ego far behind, in lane 3

    def add(x: float, lane: int, speed: float, target: float, label: str) -> BehaviorVehicle:
        v = BehaviorVehicle(road, np.array([x, 4.0 * lane]), 0.0, speed)
        v.target_speed, v.timer = target, 0.99
        v.bgap_label, v.bgap_id = label, len(road.vehicles)
        v.POLITENESS, v.LANE_CHANGE_MAX_BRAKING_IMPOSED = 0.0, 2.0
        road.vehicles.append(v)
        return v

    add(300.0, 0, 28.0, 30.0, "conservative")  # wants to pass
    add(325.0, 0, 15.0, 15.0, "conservative")  # slow leader
    if blocker_behind:
        add(292.0, 1, 33.0, 35.0, "aggressive")  # closing in on the gap in lane 1
    for v in road.vehicles:
        v.lane_index = road.network.get_closest_lane_index(v.position, v.heading)
        v.lane = road.network.get_lane(v.lane_index)
        if isinstance(v, IDMVehicle):
            v.target_lane_index = v.lane_index
    return env


@pytest.mark.parametrize("blocked", [False, True])
def test_mobil_decisions_agree_in_scripted_scenes(blocked):
    env = _scripted_scene(blocked)
    n = 3 if blocked else 2
    venv = VectorHighway(env_config(make_cfg("env=sparse", f"env.vehicles_count={n}")), 1)
    venv.reset(seed=0)
    venv.load_scene(0, scene_from_highway(env))
    passer = env.unwrapped.road.vehicles[1]
    env.step(IDLE)  # 15 frames: the passer's MOBIL runs once (its timer starts at 0.99 s)
    venv.step(np.array([IDLE]))
    assert venv.g[0, 1, core.TARGET_LANE] == passer.target_lane_index[2]
    # MOBIL sends the passer to lane 1 unless the safety criterion forbids it.
    assert passer.target_lane_index[2] == (0 if blocked else 1)


def test_initial_scenes_have_highway_envs_distribution():
    """Same spawn distribution (not the same random stream): 200 resets per backend."""
    cfg = make_cfg("env=dense", "mix=0.5")
    env = make_env(cfg)
    ref = []
    for seed in range(200):
        env.reset(seed=seed)
        ref.append(scene_from_highway(env))
    venv = VectorHighway(env_config(cfg), 200)
    venv.reset(seed=0)

    def stats(f, g, p):
        bg = slice(1, None)
        return {
            "gap": np.diff(f[bg, core.X]).mean(),
            "ego_lead": f[1, core.X] - f[0, core.X],
            "speed": f[bg, core.SPEED].mean(),
            "lane": g[bg, core.LANE].mean(),
            "aggr_target": f[bg, core.TARGET_SPEED][g[bg, core.LABEL] == core.AGGRESSIVE].mean(),
            "cons_target": f[bg, core.TARGET_SPEED][g[bg, core.LABEL] == core.CONSERVATIVE].mean(),
            "delta": p[bg, core.P_DELTA].mean(),
            "aggressive": (g[bg, core.LABEL] == core.AGGRESSIVE).sum(),
        }

    a = pd.DataFrame([stats(s.f, s.g, s.p) for s in ref])
    b = pd.DataFrame([stats(venv.f[k], venv.g[k], venv.p[k]) for k in range(200)])
    for col in a:
        se = np.sqrt(a[col].var() / len(a) + b[col].var() / len(b)) + 1e-12
        assert abs(a[col].mean() - b[col].mean()) < 4 * se, col


def _numpy_spawn(venv: VectorHighway, b: int, rng: np.random.Generator, k: int) -> None:
    """The scene draw as numpy code (VectorHighway._spawn before it was compiled), the
    reference core.spawn must reproduce draw for draw."""
    from bgap.sim.highway_params import IDM_DEFAULTS, PARAM_COLUMNS, column_value
    from bgap.traffic.behaviors import DRIVER_ATTRIBUTES, is_stock

    cfg, lanes, n = venv.config, venv.lanes, venv.n
    f, g, p = venv.f[b], venv.g[b], venv.p[b]
    f[:], g[:] = 0.0, 0
    p[:] = IDM_DEFAULTS
    spread = np.exp(-5 / 40 * lanes)
    lane_id = cfg.get("initial_lane_id")
    ego_lane = int(lane_id) if lane_id is not None else int(rng.integers(lanes))
    offset = float(cfg["ego_spacing"]) * (12 + 25.0) * spread
    x = 3 * offset + offset * rng.uniform(0.9, 1.1)
    f[0, core.X], f[0, core.Y], f[0, core.SPEED] = x, core.LANE_WIDTH * ego_lane, 25.0
    g[0, core.LANE] = g[0, core.TARGET_LANE] = ego_lane
    idx = core.speed_to_index(25.0, venv.speeds)
    g[0, core.SPEED_INDEX], f[0, core.TARGET_SPEED] = idx, venv.speeds[idx]
    g[0, core.LABEL] = core.EGO
    labels = rng.permutation(np.array([core.AGGRESSIVE] * k + [core.CONSERVATIVE] * (n - k)))
    lanes_bg = rng.integers(lanes, size=n)
    speeds = rng.uniform(0.7 * core.SPEED_LIMIT, 0.8 * core.SPEED_LIMIT, size=n)
    offsets = (1 / float(cfg["vehicles_density"])) * (12 + speeds) * spread
    xs = x + np.cumsum(offsets * rng.uniform(0.9, 1.1, size=n))
    sl = slice(1, n + 1)
    f[sl, core.X], f[sl, core.Y], f[sl, core.SPEED] = xs, core.LANE_WIDTH * lanes_bg, speeds
    f[sl, core.TARGET_SPEED] = speeds
    f[sl, core.TIMER] = ((xs + core.LANE_WIDTH * lanes_bg) * np.pi) % core.LANE_CHANGE_DELAY
    g[sl, core.LANE] = g[sl, core.TARGET_LANE] = lanes_bg
    g[sl, core.LABEL] = labels
    deltas = rng.uniform(3.5, 4.5, size=n)
    for code, name in ((core.CONSERVATIVE, "conservative"), (core.AGGRESSIVE, "aggressive")):
        rows = np.flatnonzero(labels == code) + 1
        if rows.size == 0:
            continue
        params = venv.config["behavior"][name]
        p[rows, core.P_DELTA] = deltas[rows - 1]
        for key, (attr, convert) in DRIVER_ATTRIBUTES.items():
            if params.get(key) is not None:
                p[rows, PARAM_COLUMNS[attr]] = column_value(attr, float(convert(params[key])))
        if params.get("v0") is not None:
            s = float(params.get("v0_spread") or 0.0)
            f[rows, core.TARGET_SPEED] = float(params["v0"]) * rng.uniform(1 - s, 1 + s, rows.size)
        if not is_stock(params):
            p[rows, core.P_OWN] = 1.0
            p[rows, core.P_VMAX] = BehaviorVehicle.MAX_SPEED


@pytest.mark.parametrize(
    "overrides, keys",
    [
        (("env=dense", "behavior=paper"), {"mix_sampling": "uniform"}),
        (("env=sparse", "behavior=stock", "mix=0.4"), {}),
        (
            ("env=sparse", "behavior=calibrated", "behavior.converged=true", "mix=1.0"),
            {"initial_lane_id": 2},
        ),
        (("env=dense", "mix=0.0"), {"lanes_count": 3, "ego_spacing": 1.5}),
    ],
)
def test_compiled_scene_draw_is_the_numpy_draw(overrides, keys):
    """core.spawn (numpy's Generator algorithms on each env's PCG64 stream, through its ctypes
    interface) draws the numpy version's scenes from the same streams bit for bit: every
    field of every vehicle, and the stream left where numpy leaves it, so the next reset's
    scene is the same too."""
    config = {**env_config(make_cfg(*overrides)), **keys}
    venv, ref = VectorHighway(config, 1), VectorHighway(config, 1)
    for seed in range(40):
        venv.reset(seed=seed)
        rng = np.random.default_rng(seed)
        _numpy_spawn(ref, 0, rng, int(venv.n_aggressive[0]))
        for name in ("f", "g", "p"):
            np.testing.assert_array_equal(getattr(venv, name), getattr(ref, name), err_msg=name)
        assert venv._rngs[0].bit_generator.state == rng.bit_generator.state


def test_vector_env_api_seeding_and_autoreset():
    cfg = make_cfg("env=sparse", "env.duration=3")
    venv = VectorHighway(env_config(cfg), 4)
    obs1, _ = venv.reset(seed=[5, 6, 5, 7])
    assert venv.observation_space.contains(obs1)
    np.testing.assert_array_equal(obs1[0], obs1[2])  # same seed, same scene
    assert not np.array_equal(obs1[0], obs1[1])
    obs2, _ = VectorHighway(env_config(cfg), 4).reset(seed=[5, 6, 5, 7])
    np.testing.assert_array_equal(obs1, obs2)
    for _ in range(3):
        obs, _, term, trunc, info = venv.step(np.full(4, IDLE))
    assert trunc.all() and not term.any()  # duration 3 s at 1 Hz
    assert info["_final_obs"].all() and venv.steps.tolist() == [0, 0, 0, 0]
    assert not np.array_equal(obs, np.stack(info["final_obs"]))  # fresh scenes returned


def test_bad_input_is_rejected_clearly():
    cfg = env_config(make_cfg("env=sparse"))
    with pytest.raises(ValueError, match="mix"):
        VectorHighway({**cfg, "mix": 1.5}, 2)
    with pytest.raises(ValueError, match="observation.absolute"):
        VectorHighway({**cfg, "observation": {**cfg["observation"], "absolute": True}}, 2)
    with pytest.raises(ValueError, match="2 seeds for 3 envs"):
        VectorHighway(cfg, 3).reset(seed=[1, 2])


def test_simulate_vector_writes_the_recorder_schema():
    from bgap.cmetric.io import load_trajectories
    from bgap.datasets.simulate import simulate

    ref = simulate(make_cfg("env=sparse", "env.duration=4"), episodes=1, progress=False)
    vec = simulate(
        make_cfg("env=sparse", "env.duration=4", "backend=vector"), episodes=2, progress=False
    )
    assert list(vec.columns) == list(ref.columns)
    assert (vec.dtypes == ref.dtypes).all()
    assert len(vec) == 2 * len(ref)  # 6 vehicles x 61 frames per episode
    assert set(vec.label) == {"ego", "aggressive", "conservative"}
    load_trajectories(vec)  # passes CMetric's input validation


def test_sb3_adapter_hands_sb3_the_finished_episodes_last_observation():
    """SB3's conventions on top of the vector env: same steps, ``terminal_observation`` is
    the finished episode's last observation (not the next episode's first), time-outs are
    marked as such, and DQN stores them as time-outs, not as terminal states."""
    from stable_baselines3.common.vec_env import VecMonitor

    from bgap.agents.dqn import DQN
    from bgap.sim.sb3 import SB3VecEnv

    config = env_config(make_cfg("env=sparse", "env.duration=3"))
    ref = VectorHighway(config, 2)
    ref_obs, _ = ref.reset(seed=[4, 5])
    adapter = SB3VecEnv(VectorHighway(config, 2))
    adapter.seed(4)  # SB3: env k takes seed 4 + k
    np.testing.assert_array_equal(adapter.reset(), ref_obs)
    for step in range(3):
        actions = np.array([IDLE, core.LANE_LEFT if step == 0 else IDLE])
        obs, rewards, dones, infos = adapter.step(actions)
        ref_obs, ref_rewards, term, trunc, ref_info = ref.step(actions)
        np.testing.assert_array_equal(obs, ref_obs)
        np.testing.assert_allclose(rewards, ref_rewards, rtol=1e-6)
        np.testing.assert_array_equal(dones, term | trunc)
    assert dones.all() and trunc.all()  # 3 s at 1 Hz: time-outs
    for b in range(2):
        np.testing.assert_array_equal(infos[b]["terminal_observation"], ref_info["final_obs"][b])
        assert not np.array_equal(infos[b]["terminal_observation"], obs[b])
        assert infos[b]["TimeLimit.truncated"]

    venv = VecMonitor(SB3VecEnv(VectorHighway(config, 2)))
    venv.seed(0)
    model = DQN("MlpPolicy", venv, learning_starts=50, buffer_size=1000, seed=0, device="cpu")
    model.learn(60)
    buffer = model.replay_buffer
    ends = buffer.dones[: buffer.pos].astype(bool)
    timeouts = buffer.timeouts[: buffer.pos].astype(bool)
    lengths = np.array([e["l"] for e in model.ep_info_buffer])
    assert ends.sum() == len(lengths) and not timeouts[~ends].any()
    # Episodes cut by the 3 s limit are time-outs; those that crashed earlier are not.
    assert timeouts[ends].sum() > 0 and (~timeouts[ends]).sum() >= (lengths < 3).sum()


def test_the_benchmarks_phase_by_phase_step_is_the_kernels_step():
    """bgap.sim.phases cuts a step into batched phase kernels for the benchmark's split: it
    must advance every env exactly as core.step_batch does, resets included."""
    from bgap.sim.phases import PHASES, step_in_phases

    config = env_config(make_cfg("env=sparse", "mix=0.5", "env.duration=4"))
    whole, cut = VectorHighway(config, 6), VectorHighway(config, 6)
    whole.reset(seed=3)
    cut.reset(seed=3)
    rng, clock, ended = np.random.default_rng(0), {}, 0
    for _ in range(10):  # 4 s episodes: every env resets at least twice
        actions = rng.integers(5, size=6)
        obs, rewards, terminated, truncated, _ = whole.step(actions)
        obs_cut, rewards_cut, done = step_in_phases(cut, actions, clock)
        np.testing.assert_array_equal(done, terminated | truncated)
        ended += int(done.sum())
        np.testing.assert_array_equal(obs_cut, obs)
        np.testing.assert_array_equal(rewards_cut, rewards)
        for name in ("f", "g", "p", "steps"):
            np.testing.assert_array_equal(getattr(cut, name), getattr(whole, name))
    assert ended >= 12 and set(clock) == set(PHASES) and all(v > 0 for v in clock.values())


def test_the_fast_mode_passes_the_parity_study_and_5_hz_does_not():
    """The fast mode against the parity stage's highway-env episodes (committed, 15 Hz): the
    same seeds, mixes and duration on the vector backend, every rate inside its interval.
    The same comparison at 5 Hz must fail somewhere, or this check could not tell."""
    from bgap.experiments import parity

    stored = pd.read_csv(PARITY / "episodes.csv")
    highway = stored[stored.backend == "highway"]
    seeds = sorted(highway.seed.unique())
    assert len(seeds) >= 100 and sorted(highway.mix.unique()) == [0.0, 0.5, 1.0]
    duration = float(
        yaml.safe_load((PARITY.parents[1] / "params.yaml").read_text())["parity"]["duration"]
    )

    def agreeing(mode) -> pd.Series:
        frames = [highway]
        for mix in (0.0, 0.5, 1.0):
            config = env_config(make_cfg("env=dense", f"mix={mix}", f"env.duration={duration}"))
            df = parity.run(mode(config), seeds, "vector")
            df["mix"], df["backend"] = mix, "vector"
            frames.append(df)
        table = parity.compare(pd.concat(frames))
        return table[table.backend == "vector"].set_index(["mix", "metric"]).overlap

    fast = agreeing(fast_mode)
    assert len(fast) == 11 and fast.all(), fast[~fast]
    assert not agreeing(lambda config: {**config, "simulation_frequency": 5}).all()


def test_a_finished_env_is_left_as_it_is():
    """Action FINISHED: that env's state does not move and it is not reset; the others step
    exactly as they would have."""
    from bgap.common.vocab import FINISHED

    config = env_config(make_cfg("env=dense", "mix=0.5"))
    a, b = VectorHighway(config, 3), VectorHighway(config, 3)
    a.reset(seed=[1, 2, 3])
    b.reset(seed=[1, 2, 3])
    kept = a.f[1].copy(), a.g[1].copy()
    a.step(np.array([IDLE, FINISHED, IDLE]))
    b.step(np.array([IDLE, IDLE, IDLE]))
    assert np.array_equal(a.f[1], kept[0]) and np.array_equal(a.g[1], kept[1])
    assert not np.array_equal(b.f[1], kept[0])
    for env in (0, 2):
        assert np.array_equal(a.f[env], b.f[env]) and np.array_equal(a.g[env], b.g[env])


@pytest.mark.parametrize("traffic", ["dense", "replay"])
def test_rollouts_that_skip_finished_envs_play_the_same_episodes(tmp_path, monkeypatch, traffic):
    """The vector backend skips envs whose counted episode is over (issue 36): every episode
    and every recorded frame is what the rollout that kept simulating them gave, in simulated
    and in replayed traffic, with a policy that ends many episodes early."""
    from bgap.agents.policies import rollout

    config = env_config(make_cfg("env=dense", "env.duration=12", "mix=0.5"))
    if traffic == "replay":
        recorded = rollout(config, "idle", [3, 4], "vector", record=True).trajectories
        table = tmp_path / "trajectories.parquet"
        recorded.to_parquet(table)
        replay = [
            "traffic=replay",
            f"traffic.table={table}",
            "traffic.min_duration=5",
            "backend=vector",
        ]
        # replayed traffic is played, not recorded: the evaluation's schema composes it
        from bgap.common.config import validate
        from tests.configs import compose

        config = env_config(
            validate(compose("evaluate", ["env=dense", "env.duration=12", *replay]))
        )
    seeds = list(range(24))
    skipped = rollout(config, "random", seeds, "vector", record=traffic != "replay")
    monkeypatch.setattr(VectorHighway, "skips_finished", False)
    played = rollout(config, "random", seeds, "vector", record=traffic != "replay")
    pd.testing.assert_frame_equal(skipped.episodes, played.episodes)
    assert skipped.episodes.steps.nunique() > 1  # some envs finished early and were skipped
    if traffic != "replay":
        pd.testing.assert_frame_equal(skipped.trajectories, played.trajectories)


def test_both_backends_count_the_same_overtakes():
    """A fast ego (FASTER, then keeping its speed) in sparse traffic from the same scene on
    both backends: the vehicles it passes, step by step, are the same count, and it passes
    some; the rollout's ``overtakes`` column sums them when asked."""
    from bgap.traffic.road import FASTER

    env, venv = _twin("env=sparse", "mix=0.0", seed=4)
    total = 0
    for k in range(40):
        a = FASTER if k < 3 else IDLE
        obs, reward, term, trunc, info = env.step(a)
        _, _, vterm, vtrunc, vinfo = venv.step(np.array([a]))
        assert int(vinfo["overtakes"][0]) == info["overtakes"], k
        total += info["overtakes"]
        if term or trunc:
            break
    assert total > 0
    config = env_config(make_cfg("env=sparse", "mix=0.0", "env.duration=10"))
    from bgap.agents.policies import rollout

    rows = rollout(config, "rule", range(20), overtakes=True).episodes
    assert "overtakes" in rows and (rows.overtakes >= 0).all() and rows.overtakes.sum() > 0
    assert "overtakes" not in rollout(config, "rule", range(2)).episodes
