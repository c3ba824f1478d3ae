"""The batched DQN learner (bgap.agents.batched): the same algorithm as SB3's DQN, member by
member, whatever the batch; run folders like bgap.train's; exact resumes; clear errors."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from stable_baselines3.common.vec_env import DummyVecEnv

from bgap.agents.batched import BatchedDQN, Schedule, StackedReplay
from bgap.agents.config import AgentConfig
from bgap.agents.dqn import DQN
from bgap.agents.per import PrioritizedReplayBuffer, PrioritizedSamples
from bgap.agents.stacked_qnets import StackedAdam, initial_parameters

ROOT = Path(__file__).resolve().parent.parent
OBS = gym.spaces.Box(-1.0, 1.0, (5, 5), np.float32)


class _Spaces(gym.Env):
    observation_space, action_space = OBS, gym.spaces.Discrete(5)

    def reset(self, seed=None, options=None):
        return np.zeros((5, 5), np.float32), {}

    def step(self, action):
        return np.zeros((5, 5), np.float32), 0.0, False, False, {}


def _sb3(agent: AgentConfig, seed: int) -> DQN:
    return DQN(
        "MlpPolicy", DummyVecEnv([_Spaces] * 2), seed=seed, learning_rate=agent.learning_rate,
        gamma=agent.gamma, max_grad_norm=agent.max_grad_norm, learning_starts=0,
        policy_kwargs={"net_arch": list(agent.net_arch)}, device="cpu",
        replay_buffer_class=PrioritizedReplayBuffer,
    )  # fmt: skip


def _batches(k: int, updates: int, b: int = 32, seed: int = 0) -> tuple[list[dict], np.ndarray]:
    """A fixed stream of replay batches (K members x ``updates``) and importance weights."""
    rng = np.random.default_rng(seed)
    stream = [
        {
            "obs": rng.uniform(-1, 1, (k, b, 25)).astype(np.float32),
            "next_obs": rng.uniform(-1, 1, (k, b, 25)).astype(np.float32),
            "actions": rng.integers(5, size=(k, b)),
            "rewards": rng.uniform(-1, 1, (k, b)).astype(np.float32),
            "done_mask": (rng.random((k, b)) < 0.1).astype(np.float32),
        }
        for _ in range(updates)
    ]
    return stream, rng.uniform(0.3, 1.0, (updates, k, b))


def _learner(agent: AgentConfig, seeds: list[int]) -> BatchedDQN:
    return BatchedDQN(agent, Schedule(2, 1000, 100.0), seeds, 25, 5, device="cpu")


def _flat(net: dict[str, torch.Tensor]) -> np.ndarray:
    return np.concatenate([t.numpy().ravel() for t in net.values()])


def test_a_member_starts_from_sb3s_parameters_for_its_seed():
    agent = AgentConfig()
    learner = _learner(agent, [0, 7])
    for k, seed in enumerate((0, 7)):
        theirs = _sb3(agent, seed).policy.q_net.state_dict()
        ours = learner.member_network(k)
        assert ours.keys() == theirs.keys()
        for key in ours:
            torch.testing.assert_close(ours[key], theirs[key], rtol=0, atol=0)
    assert initial_parameters(0, [25, 256, 256, 5])[0].shape == (256, 25)


def test_batching_changes_nothing_but_speed_and_each_update_is_sb3s():
    """Fed the same batches, a member of a 4-member learner follows the parameters of the
    same member alone (1e-6 over 300 updates), and both follow SB3's DQN.train() on those
    batches (its Adam, clip_grad_norm_ and nn.Linear: an independent implementation)."""
    agent, seeds, updates = AgentConfig(), [3, 4, 5, 6], 300
    stream, weights = _batches(len(seeds), updates)
    batched = _learner(agent, seeds)
    alone = [_learner(agent, [s]) for s in seeds]
    for t in range(updates):
        batched.update(stream[t], weights[t], np.arange(len(seeds)))
        for k, single in enumerate(alone):
            one = {key: value[k : k + 1] for key, value in stream[t].items()}
            single.update(one, weights[t][k : k + 1], np.arange(1))
    for k, single in enumerate(alone):
        a, b = _flat(batched.member_network(k)), _flat(single.member_network(0))
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)
    # SB3 on member 0's batches
    model = _sb3(agent, seeds[0])
    model._setup_learn(10)
    steps = iter(range(updates))

    def sample(batch_size, env=None):
        t = next(steps)
        batch = {key: torch.as_tensor(value[0]) for key, value in stream[t].items()}
        return PrioritizedSamples(
            batch["obs"], batch["actions"].view(-1, 1), batch["next_obs"],
            batch["done_mask"].view(-1, 1), batch["rewards"].view(-1, 1), None,
            torch.as_tensor(weights[t][0], dtype=torch.float32).view(-1, 1), np.zeros(32, int),
        )  # fmt: skip

    model.replay_buffer.sample = sample
    model.replay_buffer.update_priorities = lambda *args: None
    model.train(gradient_steps=updates, batch_size=32)
    theirs = _flat({k: v.detach() for k, v in model.policy.q_net.state_dict().items()})
    np.testing.assert_allclose(_flat(batched.member_network(0)), theirs, rtol=0, atol=1e-5)


def test_members_outside_an_update_do_not_move_and_moving_ones_are_unaffected():
    agent = AgentConfig()
    stream, weights = _batches(3, 20)
    learner, alone = _learner(agent, [0, 1, 2]), _learner(agent, [1])
    before = [_flat(learner.member_network(k)) for k in range(3)]
    for t in range(20):  # only member 1 trains
        one = {key: value[1:2] for key, value in stream[t].items()}
        learner.update(one, weights[t][1:2], np.array([1]))
        alone.update(one, weights[t][1:2], np.arange(1))
    for k in (0, 2):
        np.testing.assert_array_equal(_flat(learner.member_network(k)), before[k])
    np.testing.assert_allclose(
        _flat(learner.member_network(1)), _flat(alone.member_network(0)), rtol=0, atol=1e-6
    )
    assert list(learner.optimizer.steps) == [0, 20, 0]
    # and a member that is behind in steps is updated with its own bias correction
    learner.update(stream[0], weights[0], np.arange(3))
    assert list(learner.optimizer.steps) == [1, 21, 1]


def test_stacked_adam_is_torchs_adam_bit_for_bit_in_lock_step_and_apart():
    """The in-place lock-step update and the per-count path against torch.optim.adam's
    functional update on the same stacked tensors (gradients with exact zeros, as a dead
    ReLU's): parameters and both moments equal to the last bit."""
    from torch.optim.adam import adam

    shapes = [(3, 25, 64), (3, 64), (3, 64, 5), (3, 5)]
    gen = torch.Generator().manual_seed(0)
    params = [torch.randn(s, generator=gen) * 0.1 for s in shapes]
    ours, ref = [t.clone() for t in params], [t.clone() for t in params]
    opt = StackedAdam(ours, lr=3e-4)
    m, v = [torch.zeros(s) for s in shapes], [torch.zeros(s) for s in shapes]
    counts = np.zeros(3, dtype=np.int64)
    masks = [np.array([True, True, True])] * 5 + [np.array([False, True, False])] * 3
    masks += [np.array([True, True, True])] * 4  # members at two counts: one update each
    for mask in masks:
        grads = [torch.randn(s, generator=gen) * (torch.rand(s, generator=gen) > 0.3)
                 for s in shapes]  # fmt: skip
        opt.step(ours, grads, mask)
        for k in np.flatnonzero(mask):  # the reference: torch's Adam, member by member
            p, mk, vk = [t[k] for t in ref], [t[k] for t in m], [t[k] for t in v]
            with torch.no_grad():
                steps = [torch.tensor(float(counts[k])) for _ in p]  # one each: adam adds 1
                adam(p, [g[k] for g in grads], mk, vk, [], steps, foreach=False, amsgrad=False,
                     beta1=0.9, beta2=0.999, lr=3e-4, weight_decay=0.0, eps=1e-8,
                     maximize=False)  # fmt: skip
            counts[k] += 1
    assert list(opt.steps) == list(counts) == [9, 12, 9]
    for a, b in zip((*ours, *opt.exp_avg, *opt.exp_avg_sq), (*ref, *m, *v), strict=True):
        assert torch.equal(a, b)


def test_prioritized_sampling_follows_the_priorities_and_sb3_buffers_weights():
    """Sample frequencies against P(i) = p_i / sum p (chi-square), importance weights against
    bgap's SB3 PrioritizedReplayBuffer on the same priorities."""
    from scipy import stats

    replay = StackedReplay(2, 2, 20, 3, alpha=0.6, beta0=0.4, prioritized=True)
    rng = np.random.default_rng(0)
    for _ in range(7):  # 7 of 10 positions filled: 14 transitions per member
        replay.add(np.arange(2), *(np.zeros((2, 2, 3)),) * 2, np.zeros((2, 2), int),
                   *(np.zeros((2, 2)),) * 3)  # fmt: skip
    priorities = rng.uniform(0.1, 3.0, (2, 7, 2))
    replay.priorities[:, :7] = priorities
    for k in range(2):
        replay.trees.rebuild(k, replay.priorities[k].reshape(-1))
    rngs = [np.random.default_rng(s) for s in (1, 2)]
    counts = np.zeros((2, 14))
    for _ in range(400):
        flat, weights = replay.sample(np.arange(2), 32, np.array([0.4, 0.7]), rngs)
        for k in range(2):
            counts[k] += np.bincount(flat[k], minlength=14)
    for k in range(2):
        p = priorities[k].ravel() / priorities[k].sum()
        assert stats.chisquare(counts[k], counts[k].sum() * p).pvalue > 1e-3
    reference = PrioritizedReplayBuffer(20, OBS, gym.spaces.Discrete(5), n_envs=2)
    reference.pos, reference.beta = 7, 0.7
    reference.priorities[:7] = priorities[1]
    probs = reference.probabilities()
    want = (14 * probs[flat[1]]) ** -0.7 / (14 * probs.min()) ** -0.7
    np.testing.assert_allclose(weights[1], want, rtol=1e-12)


def test_sum_trees_invert_the_cumulative_sum_after_many_updates():
    """After thousands of scattered writes (duplicates included) each member's tree holds the
    exact sums and minima of its leaves, and inverts the cumulative distribution where
    ``np.searchsorted`` on ``np.cumsum`` does (the sampler it replaces), draws a leaf with
    probability p_j / sum p (chi-square), and never an empty leaf."""
    from scipy import stats

    from bgap.agents.per import SumTrees

    rng = np.random.default_rng(3)
    k, n, filled = 3, 1000, 700  # 1,000 leaves: capacity 1,024, 300 leaves never written
    trees, leaves = SumTrees(k, n), np.zeros((k, n))
    for _ in range(200):
        idx = rng.integers(0, filled, (k, 64))
        values = rng.gamma(0.5, 1.0, (k, 64)) + 1e-6
        for m in range(k):
            leaves[m, idx[m]] = values[m]  # last write wins, as numpy's fancy assignment
        trees.set(np.arange(k), idx, leaves[np.arange(k)[:, None], idx])
    np.testing.assert_allclose(trees.total(np.arange(k)), leaves.sum(axis=1), rtol=1e-12)
    positive = np.where(leaves > 0, leaves, np.inf)
    np.testing.assert_array_equal(trees.smallest(np.arange(k)), positive.min(axis=1))
    u = rng.random((k, 100_000))
    found = trees.find(np.arange(k), u)
    cdf = np.cumsum(leaves, axis=1)
    want = np.stack(
        [np.searchsorted(c, x * c[-1], side="right") for c, x in zip(cdf, u, strict=True)]
    )
    assert np.mean(found == want) > 0.9999  # rounding of the two sums at a boundary
    assert (leaves[np.arange(k)[:, None], found] > 0).all()
    for m in range(k):
        counts = np.bincount(found[m], minlength=n)[:filled]
        p = leaves[m, :filled] / leaves[m].sum()
        keep = p * u.shape[1] >= 5  # the chi-square test's expected counts
        observed = np.append(counts[keep], counts[~keep].sum())
        expected = np.append(p[keep], p[~keep].sum()) * u.shape[1]
        assert stats.chisquare(observed, expected).pvalue > 1e-3
    rebuilt = SumTrees(k, n)
    for m in range(k):
        rebuilt.rebuild(m, leaves[m])
    np.testing.assert_allclose(rebuilt.sum, trees.sum, rtol=1e-12)
    np.testing.assert_array_equal(rebuilt.min, trees.min)


def _overrides(tmp: Path, name: str) -> list[str]:
    return [
        "profile=tiny", "profile.checkpoint_every=40", "env=sparse", "learner=batched",
        "seeds=[0]", "policies=[behavior_rich,default]", f"run_dir={tmp / name}",
    ]  # fmt: skip


def test_batched_training_writes_sb3_run_folders_and_resumes_a_kill_exactly(tmp_path):
    """Two members (both policies: two traffic groups) in one learner: each gets bgap.train's run
    folder with a model.zip that SB3's DQN.load reads and bgap.evaluate plays; kill -9 in the
    middle and a rerun with resume=true ends every member where an uninterrupted run does."""
    from bgap.common.config import validate
    from bgap.common.errors import ConfigError
    from bgap.experiments.batched import train_batched
    from bgap.experiments.evaluate import evaluate
    from bgap.experiments.training import member_configs
    from tests.configs import compose

    def configs(name: str, *more: str):
        return member_configs(validate(compose("train", [*_overrides(tmp_path, name), *more])))

    runs = train_batched(configs("whole"), progress=False)
    assert len(runs) == 2 and len({r.parent for r in runs}) == 1
    for run in runs:
        for name in ("config.yaml", "command.txt", "model.zip", "checkpoints/learner.pt", "tb"):
            assert (run / name).exists(), (run, name)
    # the SB3 model is the learner's member: same greedy actions
    state = torch.load(runs[0] / "checkpoints/learner.pt", weights_only=False)
    learner = _learner(AgentConfig(), [state["seed"]])
    learner.load_member_state(0, state)
    model = DQN.load(runs[0] / "model.zip", device="cpu")
    obs = np.random.default_rng(0).uniform(-1, 1, (64, 5, 5)).astype(np.float32)
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0],
                                  learner.greedy(obs[None])[0])  # fmt: skip
    assert model.num_timesteps == 300 and model._n_updates == learner.n_updates[0] > 0
    # bgap.evaluate plays it like any SB3-trained model
    cfg = validate(compose("evaluate", ["env=sparse", "grid=single", "workers=1"]))
    episodes = evaluate(cfg, {"member": str(runs[0])}, episodes=2, progress=False)
    assert len(episodes) == 2 and episodes.crashed.notna().all()

    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    args = [sys.executable, "-m", "bgap.train", *_overrides(tmp_path, "cut")]
    child = subprocess.Popen(args, cwd=tmp_path, env=env, stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    while child.poll() is None and time.time() < deadline:
        if list((tmp_path / "cut").glob("*/checkpoints/state.pkl")):
            break
        time.sleep(0.02)
    child.send_signal(signal.SIGKILL)
    child.wait()
    assert not list((tmp_path / "cut").glob("*/model.zip"))
    with pytest.raises(ConfigError, match="resume=true"):  # not without being asked
        train_batched(configs("cut"), progress=False)
    resumed = train_batched(configs("cut", "resume=true"), progress=False)
    for run, other in zip(runs, resumed, strict=True):
        assert run.name == other.name
        a = DQN.load(run / "model.zip", device="cpu")
        b = DQN.load(other / "model.zip", device="cpu")
        for p, q in zip(a.policy.parameters(), b.policy.parameters(), strict=True):
            np.testing.assert_array_equal(p.detach().numpy(), q.detach().numpy())
    # finished members are reused beside new ones, and every member's folder is returned
    more = train_batched(configs("whole", "seeds=[0,1]"), progress=False)
    assert len(more) == 4 and set(runs) <= set(more)
    for run in runs:
        a = DQN.load(run / "model.zip", device="cpu")
        assert a.num_timesteps == 300
    # a member's folder holding another training is refused, naming what differs
    one = validate(compose("train", ["profile=tiny", "env=sparse", "learner=batched",
                                     f"run_dir={runs[0]}", "agent.gamma=0.9"]))  # fmt: skip
    with pytest.raises(ConfigError, match="agent.gamma"):
        train_batched([one], progress=False)


def test_bad_batches_are_clear_errors():
    from bgap.common.config import validate
    from bgap.common.errors import ConfigError
    from bgap.experiments.batched import train_batched
    from tests.configs import compose

    with pytest.raises(ConfigError, match="at least one"):
        _learner(AgentConfig(), [])
    a = validate(compose("train", ["profile=tiny", "env=sparse", "learner=batched"]))
    b = validate(compose("train", ["profile=tiny", "env=sparse", "env.observed_vehicles=7"]))
    with pytest.raises(ConfigError, match="same observation shape"):
        train_batched([a, b], progress=False)
    c = validate(compose("train", ["profile=tiny", "env=sparse", "agent.gamma=0.5"]))
    with pytest.raises(ConfigError, match="same agent"):
        train_batched([a, c], progress=False)


def test_a_whole_training_on_sb3s_random_streams_is_sb3s_training(tmp_path):
    """One member drawing exploration and replay samples from SB3's streams
    (``sb3_streams``) retraces SB3's DQN training with the same seed: the same action in
    every step, the same transitions, and parameters within float noise after 300 updates.
    (Uniform replay: with PER, float-level TD differences move a sampling probability by
    ~1e-7 and, some hundred updates in, one draw picks another index; README.)"""
    import pickle

    from bgap.common.config import validate
    from bgap.experiments.batched import train_batched
    from bgap.experiments.train import train
    from tests.configs import compose

    overrides = ["profile=quick", "profile.train_steps=800", "profile.eval_every_episodes=0",
                 "env=sparse", "seed=3", "agent.replay=uniform"]  # fmt: skip
    sb3 = train(validate(compose("train", [*overrides, f"run_dir={tmp_path}/sb3"])), False)
    ours = train_batched(
        [validate(compose("train", [*overrides, "learner=batched", f"run_dir={tmp_path}/b"]))],
        progress=False,
        sb3_streams=True,
    )[0]
    replay = pickle.loads((sb3 / "checkpoints/replay.pkl").read_bytes())
    state = torch.load(ours / "checkpoints/learner.pt", weights_only=False)
    steps = replay.pos
    assert steps == state["replay"]["pos"] == 400
    np.testing.assert_array_equal(replay.actions[:steps, :, 0], state["replay"]["actions"][:steps])
    np.testing.assert_allclose(
        replay.observations[:steps].reshape(steps, 2, -1), state["replay"]["obs"][:steps]
    )
    a, b = DQN.load(sb3 / "model.zip", device="cpu"), DQN.load(ours / "model.zip", device="cpu")
    assert a._n_updates == b._n_updates == 300
    for p, q in zip(a.policy.q_net.parameters(), b.policy.q_net.parameters(), strict=True):
        np.testing.assert_allclose(p.detach().numpy(), q.detach().numpy(), rtol=0, atol=1e-4)


def test_batched_members_are_validated_during_training(tmp_path):
    """Periodic validation (profile.eval_every_episodes) plays each member as a model: its
    evaluations.csv holds its rows beside the idle and rule-based egos' (the pipeline's
    rehearsals train so; a member seen as a model needs its observation space)."""
    import pandas as pd

    from bgap.common.config import validate
    from bgap.experiments.batched import train_batched
    from bgap.experiments.training import member_configs
    from tests.configs import compose

    more = ["profile.eval_every_episodes=2", "profile.eval_during_training=1",
            "policies=[behavior_rich]"]  # fmt: skip
    cfgs = member_configs(validate(compose("train", [*_overrides(tmp_path, "v"), *more])))
    for run in train_batched(cfgs, progress=False):
        table = pd.read_csv(run / "evaluations.csv")
        assert len(table) >= 1 and {"collision_pct", "rule_avg_speed"} <= set(table.columns)
