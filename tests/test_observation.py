"""Observation options (issue 32): closing speed, time to collision and the rule-based ego's
suggestion, against hand computations, against the simulators' own states on frames of both
backends, across the backends' parity, and through training, saving and evaluation."""

from __future__ import annotations

import numpy as np
import pytest

from bgap.agents.observation import TTC_HORIZON, ObservationFeatures, WithFeatures
from bgap.agents.rule_based import rule_based
from bgap.common.config import validate
from bgap.common.errors import ConfigError
from bgap.sim import core
from bgap.sim.vector import VectorHighway
from bgap.traffic.road import N_ACTIONS
from bgap.traffic.scenario import env_config
from tests.configs import compose
from tests.conftest import make_cfg

LANES = 4
X, Y, V = 200.0, 4.0 * LANES, 80.0  # highway-env's normalisation of x, y, vx


def _row(dx: float, dy: float, dvx: float) -> list[float]:
    return [1.0, dx / X, dy / Y, dvx / V, 0.0]


def test_closing_speed_and_time_to_collision_of_a_hand_built_frame():
    """Ego at 20 m/s in lane 1. Ahead in its lane, 30 m centre to centre at 15 m/s: closing
    at 5 m/s over a 25 m gap, 5 s. Behind in its lane, 20 m at 25 m/s: closing at 5 m/s over
    15 m, 3 s. Ahead in the next lane at 10 m/s: closing, but no lateral overlap. Ahead in
    its lane, faster: opening (closing -2 m/s), no collision course. Overlapping (4 m apart):
    in contact. Then an absent row."""
    ego = [1.0, 0.5, 4.0 / Y, 20.0 / V, 0.0]  # the ego's row is absolute
    obs = np.array([[
        ego, _row(30, 0, -5), _row(-20, 0, 5), _row(40, 4, -10), _row(50, 0.5, 2),
        _row(4, 1.0, 0), [0.0] * 5,
    ]], dtype=np.float32)  # fmt: skip
    out = ObservationFeatures(["closing", "ttc"], {"lanes_count": LANES})(obs)[0]
    assert out.shape == (7, 7)
    np.testing.assert_allclose(out[:, :5], obs[0])  # the paper's columns untouched
    closing = np.array([0, 5, 5, 10, -2, 0, 0]) / V
    np.testing.assert_allclose(out[:, 5], closing, atol=1e-6)
    ttc = np.array([1, 5 / TTC_HORIZON, 3 / TTC_HORIZON, 1, 1, 0, 0])
    np.testing.assert_allclose(out[:, 6], ttc, atol=1e-5)


def _reference(x, y, vx, obs, lanes):
    """Closing speed [m/s] and time to collision [s] of each observed row, from the
    simulator's own positions and velocities (the ego first): each row is matched to the
    vehicle at its offset, then the definitions are applied to the true state."""
    closing, ttc = np.zeros(len(obs)), np.full(len(obs), np.inf)
    for j in np.flatnonzero(obs[1:, 0] > 0.5) + 1:
        dx, dy = x[1:] - x[0], y[1:] - y[0]
        k = np.argmin(np.abs(dx - obs[j, 1] * X) + np.abs(dy - obs[j, 2] * 4.0 * lanes))
        assert abs(dx[k] - obs[j, 1] * X) < 1e-3 and abs(dy[k] - obs[j, 2] * 4 * lanes) < 1e-3
        closing[j] = -np.sign(dx[k]) * (vx[1:][k] - vx[0])
        gap = abs(dx[k]) - 5.0  # highway-env's vehicle length
        if abs(dy[k]) < 2.0:  # its width: the two overlap laterally
            ttc[j] = 0.0 if gap <= 0 else gap / closing[j] if closing[j] > 0 else np.inf
    return closing, ttc


def _check_frame(features, obs, x, y, vx, lanes) -> int:
    out = features(obs)
    closing, ttc = _reference(x, y, vx, obs, lanes)
    present = obs[:, 0] > 0.5
    present[0] = False
    np.testing.assert_allclose(out[present, 5], closing[present] / V, atol=1e-5)
    want = np.minimum(ttc, TTC_HORIZON) / TTC_HORIZON
    np.testing.assert_allclose(out[present, 6], want[present], atol=1e-4)
    assert (out[~(obs[:, 0] > 0.5), 5:] == 0).all() and out[0, 6] == 1.0
    return int((out[present, 6] < 1).sum())


def test_the_columns_match_the_simulators_states_on_frames_of_both_backends():
    """Dense traffic, a random ego: every observed vehicle's closing speed and time to
    collision, computed from the observation, equal the ones computed from the simulator's
    own positions and velocities (highway-env's vehicles; the vector backend's state)."""
    from bgap.envs import make_env

    cfg = make_cfg("env=dense", "mix=0.5")
    config = env_config(cfg)
    features = ObservationFeatures(["closing", "ttc"], config)
    rng = np.random.default_rng(0)
    courses = 0
    env = make_env(cfg)
    obs, _ = env.reset(seed=2)
    for _ in range(12):
        vehicles = env.unwrapped.road.vehicles
        x, y = (np.array([v.position[i] for v in vehicles]) for i in (0, 1))
        vx = np.array([v.velocity[0] for v in vehicles])
        courses += _check_frame(features, obs, x, y, vx, LANES)
        obs, _, term, trunc, _ = env.step(int(rng.integers(N_ACTIONS)))
        if term or trunc:
            break
    venv = VectorHighway(config, 2)
    obs, _ = venv.reset(seed=5)
    for _ in range(12):
        for b in range(2):
            f = venv.f[b]
            alive = np.isfinite(f[:, core.X])
            vx = f[alive, core.SPEED] * np.cos(f[alive, core.HEADING])
            courses += _check_frame(features, obs[b], f[alive, core.X], f[alive, core.Y], vx,
                                    LANES)  # fmt: skip
        obs, *_ = venv.step(rng.integers(N_ACTIONS, size=2))
    assert courses > 0  # some frames had a vehicle on a collision course within 10 s


def test_the_rule_columns_are_the_rule_based_egos_choice_in_the_egos_row():
    config = env_config(make_cfg("env=dense"))
    venv = VectorHighway(config, 4)
    obs, _ = venv.reset(seed=1)
    out = ObservationFeatures(["rule"], config)(obs)
    assert out.shape == (*obs.shape[:2], 5 + N_ACTIONS)
    assert (out[:, 1:, 5:] == 0).all() and (out[:, 0, 5:].sum(axis=1) == 1).all()
    np.testing.assert_array_equal(out[:, 0, 5:].argmax(axis=1), rule_based(config)(obs))


@pytest.mark.parametrize(
    "options",
    [pytest.param(["closing", "ttc"], marks=pytest.mark.slow), ["closing", "ttc", "rule"]],
)
def test_the_backends_agree_on_the_added_columns(options):
    """highway-env's episode and the vector backend loaded with its scene (tests/test_sim.py's
    parity), each observed through the options: the same columns, step after step, also in
    the observation an episode ended in."""
    from bgap.envs import make_env
    from bgap.sim.highway_scenes import scene_from_highway

    cfg = make_cfg("env=dense", "mix=0.5")
    config = env_config(cfg)
    env = make_env(cfg)
    env.reset(seed=3)
    venv = WithFeatures(VectorHighway(config, 1), ObservationFeatures(options, config))
    venv.reset(seed=0)
    venv.env.load_scene(0, scene_from_highway(env))
    features = ObservationFeatures(options, config)
    assert venv.single_observation_space.shape == (config["observation"]["vehicles_count"],
                                                   5 + features.columns)  # fmt: skip
    rng = np.random.default_rng(3)
    for _ in range(10):
        action = int(rng.integers(N_ACTIONS))
        obs, _, term, trunc, _ = env.step(action)
        vobs, _, vterm, vtrunc, info = venv.step(np.array([action]))
        mine = info["final_obs"][0] if vterm[0] or vtrunc[0] else vobs[0]
        np.testing.assert_allclose(mine, features(obs), atol=1e-5)
        assert mine.shape == venv.single_observation_space.shape
        if term or trunc:
            break


def test_options_are_checked_ordered_and_left_out_of_old_run_names():
    from bgap.experiments.training import run_name, training_identity

    plain = validate(compose("train", ["profile=tiny"]))
    assert "observation" not in training_identity(plain)["agent"]  # run folders keep names
    ttc = validate(compose("train", ["profile=tiny", "observation=ttc"]))
    reordered = validate(compose("train", ["profile=tiny", "agent.observation=[ttc,closing]"]))
    assert ttc.agent.observation == reordered.agent.observation == ["closing", "ttc"]
    assert run_name(ttc) == run_name(reordered) != run_name(plain)
    with pytest.raises(ConfigError, match="is not an observation option"):
        validate(compose("train", ["agent.observation=[ttc,speed]"]))
    with pytest.raises(ConfigError, match="names an option twice"):
        validate(compose("train", ["agent.observation=[ttc,ttc]"]))


@pytest.mark.parametrize("learner", ["sb3", pytest.param("batched", marks=pytest.mark.slow)])
def test_a_learner_with_options_trains_saves_and_is_evaluated_on_the_paper_observation(
    tmp_path, learner
):
    """Tiny trainings with every option: the model file records its options and reads the
    wider observation; evaluation (which simulates the paper's observation) plays it with
    the columns added, beside a model without options, reproducibly."""
    from bgap.agents.policies import as_policy, load_model
    from bgap.experiments.evaluate import Cell, evaluate
    from bgap.experiments.train import train

    extra = ["seeds=[0]"] if learner == "batched" else []
    cfg = validate(compose("train", ["profile=tiny", "env=sparse", "observation=ttc_rule",
                                     "backend=vector", f"learner={learner}", f"root={tmp_path}",
                                     *extra]))  # fmt: skip
    run = train(cfg, progress=False)
    model = load_model(run)
    assert model.observation_features == ["closing", "ttc", "rule"]
    assert model.observation_space.shape == (cfg.env.observed_vehicles, 5 + 2 + N_ACTIONS)
    policy, rows = as_policy(model, env_config(cfg))
    venv = VectorHighway(env_config(cfg), 3)
    obs, _ = venv.reset(seed=0)
    assert rows == obs.shape[1] and policy(obs, None).shape == (3,)
    cells = [Cell(0.5, "sparse", 180.0)]
    first = evaluate(cfg, {"m": str(run), "rule": "rule"}, cells, episodes=3, progress=False)
    again = evaluate(cfg, {"m": str(run), "rule": "rule"}, cells, episodes=3, progress=False)
    assert len(first) == 6 and first.equals(again)


def test_rows_on_roads_of_other_lanes_read_each_their_own_road():
    """``lanes`` per row (the mixture's replayed tables may have other roads than bgap's):
    each row's columns, the rule-based ego's choice included, are those of an environment
    of its own lanes, computed alone."""
    options = ["closing", "ttc", "rule"]
    four = env_config(make_cfg("env=dense"))
    three = {**four, "lanes_count": 3}
    obs4, _ = VectorHighway(four, 2).reset(seed=2)
    obs3, _ = VectorHighway(three, 2).reset(seed=3)
    mixed = ObservationFeatures(options, four)(np.concatenate([obs4, obs3]), [4, 4, 3, 3])
    alone = [ObservationFeatures(options, c)(o) for c, o in ((four, obs4), (three, obs3))]
    np.testing.assert_array_equal(mixed, np.concatenate(alone))
    assert not np.array_equal(alone[1], ObservationFeatures(options, four)(obs3))  # it matters
