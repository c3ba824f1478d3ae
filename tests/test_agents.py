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


def test_loss_is_mse_on_a_hand_made_batch():
    current = th.tensor([[1.0], [3.0]])
    target = th.tensor([[0.0], [0.0]])
    assert make_dqn(loss="mse").td_loss(current, target).item() == pytest.approx(5.0)
    # Huber: 0.5 * 1^2 and 3 - 0.5
    assert make_dqn(loss="huber").td_loss(current, target).item() == pytest.approx(1.5)
    weighted = make_dqn(loss="mse").td_loss(current, target, th.tensor([[1.0], [0.0]]))
    assert weighted.item() == pytest.approx(0.5)


@pytest.mark.parametrize("replay,loss", [("per", "mse"), ("uniform", "huber")])
def test_a_gradient_step_equals_the_papers_update_written_out(replay, loss):
    """DQN.train against the update written out in plain torch on the same batch: TD target
    from the target network, (importance-weighted) loss, clipped gradient, Adam step, and
    the new priorities |TD error| + eps."""
    import copy

    import torch.nn.functional as F

    model = make_dqn(replay=replay, loss=loss, max_grad_norm=0.5)
    model.learn(60)
    buf = model.replay_buffer
    reference = copy.deepcopy(model.policy)  # networks and optimizer, before the step
    saved = (buf.priorities.copy(), buf.max_priority) if replay == "per" else None
    stream = np.random.get_state()  # noqa: NPY002  (both buffers sample from it)
    model.train(gradient_steps=1, batch_size=16)

    np.random.set_state(stream)  # noqa: NPY002
    if saved is not None:
        after = buf.priorities.copy()
        buf.priorities[:], buf.max_priority = saved
    batch = buf.sample(16)
    with th.no_grad():
        next_q = reference.q_net_target(batch.next_observations).max(dim=1).values[:, None]
        target = batch.rewards + (1 - batch.dones) * model.gamma * next_q
    current = reference.q_net(batch.observations).gather(1, batch.actions.long())
    if loss == "mse":
        per_sample = (current - target) ** 2
    else:
        per_sample = F.huber_loss(current, target, reduction="none", delta=1.0)
    weights = batch.weights if replay == "per" else th.ones_like(per_sample)
    reference.optimizer.zero_grad()
    (per_sample * weights).mean().backward()
    th.nn.utils.clip_grad_norm_(reference.parameters(), 0.5)
    reference.optimizer.step()
    for ours, theirs in zip(model.policy.parameters(), reference.parameters(), strict=True):
        th.testing.assert_close(ours, theirs, rtol=1e-6, atol=1e-7)
    if saved is not None:
        td = (current - target).detach().numpy().ravel()
        rows, cols = np.divmod(batch.indices, buf.n_envs)
        np.testing.assert_allclose(after[rows, cols], (np.abs(td) + buf.eps) ** buf.alpha, 1e-5)


def test_exponential_exploration_schedule():
    model = make_dqn(exploration_decay_steps=50.0)
    model.learn(100)
    expected = 0.05 + 0.95 * np.exp(-model.num_timesteps / 50.0)
    assert model.exploration_rate == pytest.approx(expected)
