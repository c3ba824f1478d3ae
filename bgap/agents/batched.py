"""A batched DQN learner: K independent DQN trainings advanced in lock step in one process.

Member k has its own seed, Q and target networks, Adam state, prioritized replay buffer,
exploration schedule and random streams (and, in
:func:`bgap.experiments.train.train_batched`, its own environments, traffic and run folder).
Its update is the algorithm of
:class:`bgap.agents.dqn.DQN` (Stable-Baselines3's DQN with the MSE loss and prioritized
replay), counted the way SB3 counts it:

- one vector step of the member's ``E`` environments adds ``E`` to its ``num_timesteps``;
  actions are uniform before ``learning_starts``, then epsilon-greedy with one coin per
  vector step for all its environments (SB3's ``DQN.predict``);
- after each vector step ``_n_calls`` += 1, the target network is copied every
  ``max(target_update_interval // E, 1)`` calls, epsilon = final + (initial - final)
  exp(-t / decay) (or SB3's linear schedule);
- once ``num_timesteps > learning_starts``, ``gradient_steps`` updates per vector step (-1:
  one per transition), each: batch from the PER buffer (beta annealed over ``per_beta_steps``),
  MSE (or Huber) TD loss weighted by the importance weights, gradient norm clipped to
  ``max_grad_norm`` (per member), Adam (torch's formula), new priorities ``|delta| + eps``;
- a member whose episode budget is spent stops exactly where SB3's callback stops it: the
  transition of that step is not stored and no update follows.

Why written here rather than taken from a library: SB3 trains one network per process, and
``torch.func``'s model ensembling (``stack_module_state`` + ``vmap``) stacks the networks but
not the optimizer, the per-member gradient clipping or the replay. The K networks are stacked
into batched matrix products (``torch.baddbmm``; measured against ``vmap`` in
``python tools/bench.py learn``), so one forward and backward pass updates all members; Adam is
applied to the stacked tensors with a step count per member (``torch.optim.Adam`` keeps one
count for all, and a member that has finished or not started must not move).

Everything that is random draws from the member's own streams, seeded from its seed: its
initial parameters are those of SB3's ``DQN(..., seed=seed)`` (the same layer order under
``torch.manual_seed(seed)``); exploration and PER sampling use numpy Generators (SB3 uses the
global stream), so a member and an SB3 training of the same seed agree in their start and
their algorithm, not in their random draws.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
import torch
import torch.nn.functional as F

from bgap.agents.config import AgentConfig
from bgap.agents.per import SumTrees, check_replay_memory
from bgap.agents.stacked_qnets import (
    StackedAdam,
    default_device,
    initial_parameters,
    q_values,
    stacking_layout,
)
from bgap.common.errors import check


@dataclass(frozen=True)
class Schedule:
    """The per-run numbers of a training besides the agent's hyperparameters."""

    n_envs: int
    """Environments per member (E)."""
    total_steps: int
    """The training's step budget (SB3's total_timesteps: linear epsilon, PER beta)."""
    exploration_decay_steps: float | None
    """Exponential epsilon decay time constant [steps]; None: SB3's linear schedule."""
    exploration_fraction: float = 0.1
    """SB3's default: the linear schedule reaches its final epsilon at 10% of the budget."""


class StackedReplay:
    """K prioritized replay buffers (:class:`bgap.agents.per.PrioritizedReplayBuffer`'s
    algorithm and SB3's layout: ``buffer_size // E`` positions x E envs, flat index
    position * E + env) as stacked numpy arrays."""

    def __init__(
        self,
        k: int,
        n_envs: int,
        buffer_size: int,
        obs_dim: int,
        alpha: float,
        beta0: float,
        prioritized: bool,
        eps: float = 1e-6,
    ) -> None:
        self.k, self.n_envs = k, n_envs
        self.size = max(buffer_size // n_envs, 1)  # SB3's ReplayBuffer
        check_replay_memory(buffer_size, obs_dim, k)
        shape = (k, self.size, n_envs)
        self.obs = np.zeros((*shape, obs_dim), dtype=np.float32)
        self.next_obs = np.zeros((*shape, obs_dim), dtype=np.float32)
        self.actions = np.zeros(shape, dtype=np.int64)
        self.rewards = np.zeros(shape, dtype=np.float32)
        self.dones = np.zeros(shape, dtype=np.float32)
        self.timeouts = np.zeros(shape, dtype=np.float32)
        self.priorities = np.zeros(shape, dtype=np.float64)
        self.max_priority = np.ones(k)
        self.pos = np.zeros(k, dtype=np.int64)
        self.full = np.zeros(k, dtype=bool)
        self.alpha, self.beta0, self.eps, self.prioritized = alpha, beta0, eps, prioritized
        self.trees = SumTrees(k, self.size * n_envs)  # the priorities, for O(log N) sampling

    ARRAYS = (
        "obs",
        "next_obs",
        "actions",
        "rewards",
        "dones",
        "timeouts",
        "priorities",
        "max_priority",
        "pos",
        "full",
    )

    def add(self, members: np.ndarray, obs, next_obs, actions, rewards, dones, timeouts) -> None:
        """One vector step of each of ``members`` (arrays (len(members), E, ...))."""
        pos = self.pos[members]
        entering = (self.max_priority[members] ** self.alpha)[:, None]  # each member's E envs
        self.priorities[members, pos] = entering
        self.trees.set(members, pos[:, None] * self.n_envs + np.arange(self.n_envs), entering)
        new = {
            "obs": obs,
            "next_obs": next_obs,
            "actions": actions,
            "rewards": rewards,
            "dones": dones,
            "timeouts": timeouts,
        }
        for name, value in new.items():
            getattr(self, name)[members, pos] = value
        self.pos[members] = (pos + 1) % self.size
        self.full[members] |= self.pos[members] == 0

    def sample(
        self,
        members: np.ndarray,
        batch: int,
        betas: np.ndarray,
        rngs: list[np.random.Generator] | None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Flat indices (len(members), batch) drawn with P(i) = p_i / sum p (each member's sum
        tree inverts its cumulative distribution at uniform draws from its own stream), and the
        importance weights (N P(i))^-beta / max_j (N P(j))^-beta (uniform sampling and
        weights 1 without prioritisation). ``rngs=None``: one member, drawn from numpy's
        global stream exactly as :class:`bgap.agents.per.PrioritizedReplayBuffer` (or SB3's
        ``ReplayBuffer``) draws."""
        filled = np.where(self.full[members], self.size, self.pos[members]) * self.n_envs
        if rngs is None and not self.prioritized:  # SB3's ReplayBuffer.sample
            positions = self.size if self.full[members[0]] else self.pos[members[0]]
            rows = np.random.randint(0, positions, size=batch)  # noqa: NPY002
            envs = np.random.randint(0, high=self.n_envs, size=(batch,))  # noqa: NPY002
            return (rows * self.n_envs + envs)[None], np.ones((1, batch))
        if rngs is None:
            (k,), (n,) = members, filled
            probs = self.priorities[k].reshape(-1)[:n]
            probs = probs / probs.sum()
            flat = np.random.choice(n, size=batch, p=probs)  # noqa: NPY002 (as SB3's path)
            weights = (n * probs[flat]) ** (-betas[0])
            weights /= (n * probs.min()) ** (-betas[0])
            return flat[None], weights[None]
        u = np.stack([rngs[k].random(batch) for k in members])  # each member's own stream
        if not self.prioritized:
            return (u * filled[:, None]).astype(np.int64), np.ones((len(members), batch))
        flat = self.trees.find(members, u)
        total = self.trees.total(members)[:, None]
        probs = self.trees.sum[members[:, None], flat + self.trees.capacity] / total
        p_min = self.trees.smallest(members)[:, None] / total
        n = filled[:, None]
        weights = (n * probs) ** (-betas[:, None]) / (n * p_min) ** (-betas[:, None])
        return flat, weights

    def gather(self, members: np.ndarray, flat: np.ndarray) -> dict[str, np.ndarray]:
        pos, env = np.divmod(flat, self.n_envs)
        m = members[:, None]
        return {
            "obs": self.obs[m, pos, env],
            "next_obs": self.next_obs[m, pos, env],
            "actions": self.actions[m, pos, env],
            "rewards": self.rewards[m, pos, env],
            "done_mask": self.dones[m, pos, env] * (1 - self.timeouts[m, pos, env]),
        }

    def update_priorities(self, members: np.ndarray, flat: np.ndarray, td: np.ndarray) -> None:
        if not self.prioritized:
            return
        p = np.abs(td.astype(np.float64)) + self.eps
        pos, env = np.divmod(flat, self.n_envs)
        self.priorities[members[:, None], pos, env] = p**self.alpha
        self.trees.set(members, flat, self.priorities[members[:, None], pos, env])
        self.max_priority[members] = np.maximum(self.max_priority[members], p.max(axis=1))

    def member_state(self, k: int) -> dict[str, Any]:
        return {name: np.copy(getattr(self, name)[k]) for name in self.ARRAYS}

    def load_member_state(self, k: int, state: dict[str, Any]) -> None:
        for name in self.ARRAYS:
            target = getattr(self, name)
            if np.shape(target[k]) != np.shape(state[name]):
                raise ValueError(
                    f"saved replay {name} has shape {np.shape(state[name])}, this learner "
                    f"{np.shape(target[k])}"
                )
            target[k] = state[name]
        self.trees.rebuild(k, self.priorities[k].reshape(-1))


class BatchedDQN:
    """K DQN members (same hyperparameters ``agent``, own seeds) in stacked tensors.

    Args:
        agent: the hyperparameters (``conf/agent``), shared by all members.
        schedule: environments per member and the budget the schedules run over.
        seeds: one per member.
        obs_dim, n_actions: flattened observation size and number of discrete actions.
        device: torch device (default: CUDA when available).
        sb3_streams: draw exploration and replay samples from the random streams SB3's DQN
            uses (numpy's global stream, seeded by the caller, and an action space seeded
            with the seed) instead of the member's own: one member only, for comparing a
            whole training with SB3's step for step (tests; no resume).
    """

    def __init__(
        self,
        agent: AgentConfig,
        schedule: Schedule,
        seeds: list[int],
        obs_dim: int,
        n_actions: int,
        device: torch.device | str | None = None,
        sb3_streams: bool = False,
    ) -> None:
        check(len(seeds) >= 1, "seeds", seeds, "a batched learner needs at least one member")
        check(not sb3_streams or len(seeds) == 1, "seeds", seeds, "sb3_streams: one member")
        check(
            agent.train_freq == 1,
            "agent.train_freq",
            agent.train_freq,
            "the batched learner trains after every vector step (train_freq=1)",
        )
        self.agent, self.schedule, self.seeds = agent, schedule, list(seeds)
        self.k, self.n_envs, self.n_actions = len(seeds), schedule.n_envs, n_actions
        self.device = torch.device(device) if device is not None else default_device()
        sizes = [obs_dim, *agent.net_arch, n_actions]
        members = [stacking_layout(initial_parameters(s, sizes)) for s in seeds]
        self.params = [torch.stack(ts).to(self.device) for ts in zip(*members, strict=True)]
        self.target = [p.clone() for p in self.params]
        self.optimizer = StackedAdam(self.params, agent.learning_rate)
        self.replay = StackedReplay(
            self.k,
            self.n_envs,
            agent.buffer_size,
            obs_dim,
            agent.per_alpha,
            agent.per_beta0,
            prioritized=agent.replay == "per",
        )
        self.num_timesteps = np.zeros(self.k, dtype=np.int64)
        self.n_calls = np.zeros(self.k, dtype=np.int64)
        self.n_updates = np.zeros(self.k, dtype=np.int64)
        self.exploration_rate = np.zeros(self.k)  # SB3 starts at 0 (actions random anyway)
        self.last_loss = np.full(self.k, np.nan)
        self.action_rngs = [np.random.default_rng([s, 1]) for s in seeds]
        self.replay_rngs = [np.random.default_rng([s, 2]) for s in seeds]
        self.sb3_streams = sb3_streams
        self.action_space = gym.spaces.Discrete(n_actions)
        self.action_space.seed(seeds[0])

    # ------------------------------------------------------------------ acting
    def _tensor(self, array: np.ndarray, dtype=torch.float32) -> torch.Tensor:
        return torch.as_tensor(array, dtype=dtype, device=self.device)

    def greedy(self, obs: np.ndarray, members: np.ndarray | None = None) -> np.ndarray:
        """argmax_a Q_k(obs, a) for each member's observations (len(members), E', ...)."""
        members = np.arange(self.k) if members is None else np.asarray(members)
        x = self._tensor(np.asarray(obs).reshape(len(members), -1, self.replay.obs.shape[-1]))
        with torch.no_grad():
            params = self.params if len(members) == self.k else [p[members] for p in self.params]
            return q_values(params, x).argmax(-1).cpu().numpy()

    def act(self, obs: np.ndarray, members: np.ndarray) -> np.ndarray:
        """Actions (K, E) of the vector step for ``members`` (others: greedy, unused)."""
        warm = self.num_timesteps >= self.agent.learning_starts
        actions = np.zeros((self.k, self.n_envs), dtype=np.int64)
        if warm[members].any():
            actions[:] = self.greedy(obs)
        for k in members:
            if self.sb3_streams:  # SB3's _sample_action and DQN.predict, draw for draw
                coin = warm[k] and np.random.rand() < self.exploration_rate[k]  # noqa: NPY002
                if not warm[k] or coin:
                    actions[k] = [self.action_space.sample() for _ in range(self.n_envs)]
                continue
            rng = self.action_rngs[k]
            if not warm[k] or rng.random() < self.exploration_rate[k]:
                actions[k] = rng.integers(self.n_actions, size=self.n_envs)
        return actions

    # ------------------------------------------------------------------ learning
    def observe(
        self, members: np.ndarray, obs, next_obs, actions, rewards, terminated, truncated
    ) -> None:
        """Store the vector step's transitions of ``members`` (SB3's _store_transition:
        ``next_obs`` holds the final observation where an episode ended) and advance their
        counters and schedules (SB3's _on_step)."""
        dones = (terminated | truncated).astype(np.float32)
        timeouts = (truncated & ~terminated).astype(np.float32)
        flat = (len(members), self.n_envs, -1)
        self.replay.add(
            members, obs.reshape(flat), next_obs.reshape(flat), actions, rewards, dones, timeouts
        )
        self.n_calls[members] += 1
        every = max(self.agent.target_update_interval // self.n_envs, 1)
        copy = members[self.n_calls[members] % every == 0]
        if len(copy):
            for t, p in zip(self.target, self.params, strict=True):
                t[copy] = p[copy]
        self.exploration_rate[members] = self._epsilon(self.num_timesteps[members])

    def _epsilon(self, t: np.ndarray) -> np.ndarray:
        a, s = self.agent, self.schedule
        if s.exploration_decay_steps:
            decay = np.exp(-t / s.exploration_decay_steps)
            return a.exploration_final + (a.exploration_initial - a.exploration_final) * decay
        progress = np.minimum(1.0, t / s.total_steps / s.exploration_fraction)
        return a.exploration_initial + progress * (a.exploration_final - a.exploration_initial)

    def gradient_steps(self) -> int:
        g = self.agent.gradient_steps
        return g if g >= 0 else self.n_envs

    def train(self, members: np.ndarray) -> None:
        """SB3's train() after a vector step, for the ``members`` past ``learning_starts``."""
        members = members[self.num_timesteps[members] > self.agent.learning_starts]
        if len(members) == 0:
            return
        frac = np.minimum(1.0, self.num_timesteps[members] / max(1, self.schedule.total_steps))
        betas = self.replay.beta0 + frac * (1.0 - self.replay.beta0)
        losses = []
        for _ in range(self.gradient_steps()):
            rngs = None if self.sb3_streams else self.replay_rngs
            flat, weights = self.replay.sample(members, self.agent.batch_size, betas, rngs)
            batch = self.replay.gather(members, flat)
            loss, td = self.update(batch, weights, members)
            self.replay.update_priorities(members, flat, td)
            losses.append(loss)
        self.n_updates[members] += self.gradient_steps()
        self.last_loss[members] = np.mean(losses, axis=0)

    def update(
        self, batch: dict[str, np.ndarray], weights: np.ndarray, members: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """One gradient step of ``members`` on their batches (len(members), B, ...); every
        other member is left unchanged. Returns each member's loss and TD errors."""
        k, b = self.k, weights.shape[1]
        index = torch.as_tensor(members, device=self.device)
        full = len(members) == k

        def stacked(value: np.ndarray, dtype=torch.float32, fill: float = 0.0) -> torch.Tensor:
            """(len(members), B, d) -> (K, B, d), other members' rows ``fill``."""
            value = self._tensor(np.asarray(value).reshape(len(members), b, -1), dtype)
            if full:
                return value
            out = torch.full((k, b, value.shape[-1]), fill, dtype=dtype, device=self.device)
            out[index] = value
            return out

        obs, next_obs = stacked(batch["obs"]), stacked(batch["next_obs"])
        actions = stacked(batch["actions"], torch.int64)
        rewards, done_mask = stacked(batch["rewards"])[..., 0], stacked(batch["done_mask"])[..., 0]
        w = stacked(weights, fill=1.0)[..., 0]
        mask = torch.zeros(k, dtype=torch.bool, device=self.device)
        mask[index] = True
        params = [p.requires_grad_(True) for p in self.params]
        with torch.no_grad():
            next_q = q_values(self.target, next_obs).max(dim=-1).values
            target = rewards + (1 - done_mask) * self.agent.gamma * next_q
        current = q_values(params, obs).gather(-1, actions).squeeze(-1)
        if self.agent.loss == "mse":
            per_sample = F.mse_loss(current, target, reduction="none")
        else:
            per_sample = F.smooth_l1_loss(current, target, reduction="none")
        loss = (per_sample * w).mean(dim=1)
        grads = torch.autograd.grad((loss * mask).sum(), params)
        for p in params:
            p.requires_grad_(False)
        # torch.nn.utils.clip_grad_norm_ per member: the norm of its parameters' norms
        norms = torch.stack(
            [torch.linalg.vector_norm(g, dim=tuple(range(1, g.dim()))) for g in grads], 1
        )
        norm = torch.linalg.vector_norm(norms, dim=1)
        coef = torch.clamp(self.agent.max_grad_norm / (norm + 1e-6), max=1.0)
        for g in grads:  # in place: autograd.grad's tensors are ours
            g.mul_(coef.view((-1,) + (1,) * (g.dim() - 1)))
        self.optimizer.step(self.params, grads, np.isin(np.arange(k), members))
        td = (current - target).detach()[index]
        return loss.detach()[index].cpu().numpy(), td.cpu().numpy()

    # ------------------------------------------------------------------ members' state
    def member_network(self, k: int, target: bool = False) -> dict[str, torch.Tensor]:
        """Member k's Q-network as SB3's ``q_net`` state dict (``q_net.{2i}.weight``, ...)."""
        source = self.target if target else self.params
        tensors = stacking_layout([t[k].detach().cpu() for t in source])  # its own inverse
        out = {}
        for i in range(len(tensors) // 2):
            out[f"q_net.{2 * i}.weight"] = tensors[2 * i].contiguous()
            out[f"q_net.{2 * i}.bias"] = tensors[2 * i + 1].clone()
        return out

    COUNTERS = ("num_timesteps", "n_calls", "n_updates", "exploration_rate", "last_loss")

    def member_state(self, k: int) -> dict[str, Any]:
        """Everything member k's next updates depend on (a checkpoint)."""
        return {
            "seed": self.seeds[k],
            "params": [p[k].detach().cpu().clone() for p in self.params],
            "target": [p[k].detach().cpu().clone() for p in self.target],
            "adam": {
                "step": int(self.optimizer.steps[k]),
                "exp_avg": [m[k].cpu().clone() for m in self.optimizer.exp_avg],
                "exp_avg_sq": [v[k].cpu().clone() for v in self.optimizer.exp_avg_sq],
            },
            "replay": self.replay.member_state(k),
            "counters": {name: getattr(self, name)[k].item() for name in self.COUNTERS},
            "rngs": {
                "action": self.action_rngs[k].bit_generator.state,
                "replay": self.replay_rngs[k].bit_generator.state,
            },
        }

    def load_member_state(self, k: int, state: dict[str, Any]) -> None:
        check(
            state["seed"] == self.seeds[k],
            "seed",
            self.seeds[k],
            f"the checkpoint is of seed {state['seed']}",
        )
        for name, tensors in (
            ("params", self.params),
            ("target", self.target),
            ("exp_avg", self.optimizer.exp_avg),
            ("exp_avg_sq", self.optimizer.exp_avg_sq),
        ):
            saved = state[name] if name in ("params", "target") else state["adam"][name]
            for t, s in zip(tensors, saved, strict=True):
                if t[k].shape != s.shape:
                    raise ValueError(
                        f"saved network has a {tuple(s.shape)} tensor where this learner has "
                        f"{tuple(t[k].shape)} (another net_arch or observation)"
                    )
                t[k] = s.to(self.device)
        self.optimizer.steps[k] = state["adam"]["step"]
        self.replay.load_member_state(k, state["replay"])
        for name, value in state["counters"].items():
            getattr(self, name)[k] = value
        self.action_rngs[k].bit_generator.state = state["rngs"]["action"]
        self.replay_rngs[k].bit_generator.state = state["rngs"]["replay"]
