"""gymnasium's own doors: ``gym.make`` (highway-env, one env) and ``gym.make_vec`` (the vector
backend, through the registration's ``vector_entry_point``)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector.utils import batch_space

import bgap
from bgap.common.errors import ConfigError
from bgap.sim.simulators import make_vector_env
from bgap.sim.vector import VectorHighway

ROOT = Path(__file__).resolve().parent.parent
B = 8


def test_make_vec_is_the_vector_backend_with_the_single_envs_spaces_batched():
    venv = gym.make_vec(bgap.ENV_ID, num_envs=B)
    env = gym.make(bgap.ENV_ID)
    assert isinstance(venv, VectorHighway) and venv.num_envs == B
    assert venv.spec.vector_entry_point == "bgap.sim.simulators:make_vec_highway"
    assert venv.single_observation_space == env.observation_space
    assert venv.single_action_space == env.action_space
    assert venv.observation_space == batch_space(env.observation_space, B)
    assert venv.action_space == batch_space(env.action_space, B)
    obs, _ = venv.reset(seed=0)
    assert obs in venv.observation_space
    # the highway-env copies stay one argument away
    sync = gym.make_vec(bgap.ENV_ID, num_envs=2, vectorization_mode="sync")
    assert type(sync.unwrapped.envs[0].unwrapped).__module__ == "bgap.envs.highway"
    assert sync.single_observation_space == env.observation_space


def _rollout(venv: gym.vector.VectorEnv, seeds: list[int], actions: np.ndarray) -> list:
    out = [venv.reset(seed=seeds)[0]]
    for action in actions:
        obs, reward, terminated, truncated, info = venv.step(action)
        done = terminated | truncated
        # the finished episodes' last observations (an object array, one per env)
        final = np.stack(list(info["final_obs"][done])) if done.any() else None
        out.append((obs, reward, terminated, truncated, final, info["crashed"]))
    return out


def test_make_vec_episodes_equal_the_vector_backends_own_rollout():
    seeds = [11 * b + 3 for b in range(B)]
    venv = gym.make_vec(bgap.ENV_ID, num_envs=B)
    steps = venv.max_steps + 2  # a whole episode, and past the automatic resets
    actions = np.random.default_rng(5).integers(0, 5, size=(steps, B))
    ours = _rollout(venv, seeds, actions)
    theirs = _rollout(make_vector_env({}, B, "vector"), seeds, actions)
    np.testing.assert_array_equal(ours[0], theirs[0])
    ended = 0
    for step, (a, b) in enumerate(zip(ours[1:], theirs[1:], strict=True)):
        for x, y in zip(a, b, strict=True):
            if x is None or y is None:
                assert x is None and y is None, step
            else:
                np.testing.assert_array_equal(x, y, err_msg=f"step {step}")
        ended += int((a[2] | a[3]).sum())
    assert ended >= B  # every env finished an episode at least once


def test_make_vec_honours_config_and_refuses_an_unknown_key_as_make_does():
    config = {"lanes_count": 2, "vehicles_count": 12, "observation": {"vehicles_count": 7}}
    venv = gym.make_vec(bgap.ENV_ID, num_envs=B, config=config)
    assert (venv.lanes, venv.n) == (2, 12)
    assert venv.observation_space.shape == (B, 7, 5)
    assert venv.single_observation_space == gym.make(bgap.ENV_ID, config=config).observation_space
    obs, _ = venv.reset(seed=0)
    lanes = []
    for action in np.random.default_rng(0).integers(0, 5, size=(20, B)):
        obs, _, _, _, info = venv.step(action)
        lanes.append(info["lane"])
    assert set(np.concatenate(lanes).tolist()) <= {0, 1}  # two lanes only
    # vehicles beyond the default's 5 observed rows are seen
    assert (obs[:, 5:, 0] > 0).any()
    for door in (gym.make, lambda *a, **k: gym.make_vec(*a, num_envs=2, **k)):
        with pytest.raises(ConfigError, match=r"'lanes_cont' is not .*'lanes_count'"):
            door(bgap.ENV_ID, config={"lanes_cont": 2})
    with pytest.raises(ConfigError, match="draws nothing"):
        gym.make_vec(bgap.ENV_ID, num_envs=2, render_mode="rgb_array")


def test_make_vec_trains_sb3_dqn_in_a_few_lines():
    from stable_baselines3 import DQN
    from stable_baselines3.common.vec_env import VecMonitor

    from bgap.sim.sb3 import SB3VecEnv

    env = VecMonitor(SB3VecEnv(gym.make_vec(bgap.ENV_ID, num_envs=B)))
    model = DQN("MlpPolicy", env, learning_starts=64, batch_size=32, seed=0, device="cpu")
    model.learn(total_timesteps=200)
    assert model.num_timesteps >= 200
    action, _ = model.predict(env.reset(), deterministic=True)
    assert action.shape == (B,)


def test_make_vec_with_the_module_prefixed_id_needs_no_import():
    done = subprocess.run(
        [
            sys.executable,
            "-c",
            "import gymnasium as gym; v = gym.make_vec('bgap:bgap/BehaviorHighway-v0', num_envs=3);"
            "print(type(v).__name__, v.reset(seed=0)[0].shape)",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "VectorHighway (3, 5, 5)"
