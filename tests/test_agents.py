"""Prioritized replay and the DQN update."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch as th

from bgap.agents.dqn import DQN
from bgap.agents.per import PrioritizedReplayBuffer


def toy_buffer(n: int = 4, alpha: float = 1.0, size: int | None = None) -> PrioritizedReplayBuffer:
    """``n`` transitions (reward k at index k) in a buffer of ``size`` (default n)."""
    space = gym.spaces.Box(-1, 1, (2,), np.float32)
    buf = PrioritizedReplayBuffer(
        size or n, space, gym.spaces.Discrete(2), device="cpu", alpha=alpha, eps=0.0
    )
    for k in range(n):
        obs = np.full((1, 2), k, np.float32)
        buf.add(obs, obs, np.array([[0]]), np.array([float(k)]), np.array([False]), [{}])
    return buf


def test_sampling_frequencies_follow_priorities():
    np.random.seed(0)  # noqa: NPY002  (the buffer samples from numpy's global stream, as SB3)
    buf = toy_buffer()
    buf.update_priorities(np.arange(4), np.array([1.0, 2.0, 3.0, 4.0]))
    np.testing.assert_allclose(buf.probabilities(), [0.1, 0.2, 0.3, 0.4])
    counts = np.zeros(4)
    for _ in range(400):
        s = buf.sample(100)
        counts += np.bincount(s.indices, minlength=4)
        # the sampled rows are the transitions at those indices (reward k at index k)
        np.testing.assert_array_equal(s.rewards.numpy().ravel(), s.indices)
    np.testing.assert_allclose(counts / counts.sum(), [0.1, 0.2, 0.3, 0.4], atol=0.01)


def test_alpha_flattens_priorities():
    buf = toy_buffer(alpha=0.5)
    buf.update_priorities(np.arange(4), np.array([1.0, 4.0, 9.0, 16.0]))
    np.testing.assert_allclose(buf.probabilities(), np.array([1, 2, 3, 4]) / 10)


@pytest.mark.parametrize("beta", [0.4, 1.0])
def test_importance_weights(beta):
    np.random.seed(1)  # noqa: NPY002
    buf = toy_buffer()
    buf.update_priorities(np.arange(4), np.array([1.0, 2.0, 3.0, 4.0]))
    buf.beta = beta
    s = buf.sample(64)
    p = np.array([0.1, 0.2, 0.3, 0.4])[s.indices]
    expected = (4 * p) ** -beta / (4 * 0.1) ** -beta  # normalised by the largest weight
    np.testing.assert_allclose(s.weights.numpy().ravel(), expected, rtol=1e-6)
    assert s.weights.max() <= 1.0


def test_new_transitions_get_the_largest_priority():
    buf = toy_buffer(n=4, size=8)
    buf.update_priorities(np.array([0, 1]), np.array([5.0, 0.5]))
    obs = np.zeros((1, 2), np.float32)
    buf.add(obs, obs, np.array([[1]]), np.array([0.0]), np.array([False]), [{}])
    assert buf.priorities[4, 0] == pytest.approx(5.0)


def make_dqn(replay: str = "per", loss: str = "mse", **kw) -> DQN:
    env = gym.make("CartPole-v1")
    return DQN(
        "MlpPolicy",
        env,
        learning_starts=32,
        batch_size=16,
        buffer_size=500,
        loss=loss,
        replay_buffer_class=PrioritizedReplayBuffer if replay == "per" else None,
        policy_kwargs={"net_arch": [16]},
        seed=0,
        device="cpu",
        **kw,
    )


def test_dqn_with_per_runs_end_to_end_and_updates_priorities():
    model = make_dqn()
    model.learn(200)
    buf = model.replay_buffer
    assert model._n_updates >= 40  # (200 - 32 learning_starts) / train_freq 4
    filled = buf.priorities[: buf.pos, 0]
    assert len(np.unique(filled)) > 20  # TD errors, not the initial max priority
    assert buf.beta > buf.beta0  # annealing toward 1
    before = buf.priorities.copy()
    model.train(gradient_steps=1, batch_size=16)
    assert not np.array_equal(before, buf.priorities)


def test_uniform_replay_still_works():
    model = make_dqn(replay="uniform")
    model.learn(100)
    assert model._n_updates > 0


def test_loss_is_mse_on_a_hand_made_batch():
    current = th.tensor([[1.0], [3.0]])
    target = th.tensor([[0.0], [0.0]])
    assert make_dqn(loss="mse").td_loss(current, target).item() == pytest.approx(5.0)
    # Huber: 0.5 * 1^2 and 3 - 0.5
    assert make_dqn(loss="huber").td_loss(current, target).item() == pytest.approx(1.5)
    weighted = make_dqn(loss="mse").td_loss(current, target, th.tensor([[1.0], [0.0]]))
    assert weighted.item() == pytest.approx(0.5)


def test_train_step_uses_the_configured_loss(monkeypatch):
    model = make_dqn(loss="mse")
    model.learn(40)
    seen = []
    original = DQN.td_loss

    def spy(self, current, target, weights=None):
        value = original(self, current, target, weights)
        seen.append((value.item(), ((current - target) ** 2 * weights).mean().item()))
        return value

    monkeypatch.setattr(DQN, "td_loss", spy)
    model.train(gradient_steps=3, batch_size=16)
    assert len(seen) == 3
    for value, mse in seen:
        assert value == pytest.approx(mse, rel=1e-5)


def test_exponential_exploration_schedule():
    model = make_dqn(exploration_decay_steps=50.0)
    model.learn(100)
    expected = 0.05 + 0.95 * np.exp(-model.num_timesteps / 50.0)
    assert model.exploration_rate == pytest.approx(expected)
