"""The vector backend's step cut into its phases, for ``python tools/bench.py sim``'s split.

:func:`bgap.sim.core.step_batch` runs a whole policy step per environment inside one
parallel loop, so no clock can see inside it. Here each phase of a frame is its own batched
kernel (parallel over environments), called in the order :func:`bgap.sim.core.frame` runs
them; environments are independent, so the state after every frame is the same as
``step_batch``'s (``tests/test_sim.py`` asserts it bit for bit). What is measured is the
phases' cost; the launches between them add a little that ``step_batch`` does not pay.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numba as nb
import numpy as np

from bgap.sim import core
from bgap.sim.core import ACC, CRASHED, EGO, LABEL, LANE, SPEED, STEER, TARGET_LANE, TARGET_SPEED

PHASES = (
    "decisions (MOBIL)",
    "controllers",
    "IDM",
    "kinematics",
    "collisions",
    "observation",
    "reward+info",
    "resets",
)
"""The per-step phases, in the order a step runs them."""

_par = nb.njit(cache=True, parallel=True, nogil=True, error_model="numpy")


@_par
def decide_all(f, g, p, actions, speeds, lanes, first, order, rank):
    """Lane decisions in every env: the ego's meta-action on the first frame of a step
    (``core.ego_act``), then each background driver's ``change_lane_policy`` (MOBIL) in road
    order, as ``core.idm_act`` makes them. A driver's decision writes only its own target
    lane, and steering and IDM read no other driver's decision: they can follow in passes
    of their own."""
    n_env, n = f.shape[0], f.shape[1]
    for b in nb.prange(n_env):
        if first:
            core.ego_act(f, g, b, actions[b], speeds, lanes)
        core.sort_by_x(f, b, n, order[b], rank[b])
        for i in range(n):
            if g[b, i, LABEL] != EGO and not g[b, i, CRASHED]:
                core.change_lane_policy(f, g, p, b, n, i, lanes, order[b], rank[b])


@_par
def control_all(f, g):
    """Steering controllers of every vehicle, and the ego's speed controller."""
    n_env, n = f.shape[0], f.shape[1]
    for b in nb.prange(n_env):
        for i in range(n):
            if g[b, i, LABEL] == EGO:
                f[b, i, STEER] = core.steering_control(f, b, i, g[b, i, TARGET_LANE])
                f[b, i, ACC] = core.KP_A * (f[b, i, TARGET_SPEED] - f[b, i, SPEED])
            elif not g[b, i, CRASHED]:
                f[b, i, STEER] = core.steering_control(f, b, i, g[b, i, TARGET_LANE])


@_par
def idm_all(f, g, p, order, rank):
    """IDM accelerations of the background (the rest of ``core.idm_act``)."""
    n_env, n = f.shape[0], f.shape[1]
    for b in nb.prange(n_env):
        for i in range(n):
            if g[b, i, LABEL] == EGO or g[b, i, CRASHED]:
                continue
            front, _ = core.neighbours(f, b, n, i, g[b, i, LANE], order[b], rank[b])
            acc = core.acceleration(f, g, p, b, i, i, front)
            if g[b, i, LANE] != g[b, i, TARGET_LANE]:
                front, _ = core.neighbours(f, b, n, i, g[b, i, TARGET_LANE], order[b], rank[b])
                acc = min(acc, core.acceleration(f, g, p, b, i, i, front))
            amax = p[b, i, core.P_AMAX]
            f[b, i, ACC] = min(max(acc, -amax), amax)


@_par
def move_all(f, g, p, dt, lanes):
    """``Road.step``'s vehicle updates in every env: the bicycle model
    (``core.vehicle_step``)."""
    n_env, n = f.shape[0], f.shape[1]
    for b in nb.prange(n_env):
        for i in range(n):
            core.vehicle_step(f, g, p, b, i, dt, lanes)


@_par
def collide_all(f, g, dt, order, rank, pairs, pa, pb):
    """``Road.step``'s collision checks in every env (``core.collisions``)."""
    n_env, n = f.shape[0], f.shape[1]
    for b in nb.prange(n_env):
        core.sort_by_x(f, b, n, order[b], rank[b])
        core.collisions(f, g, b, n, dt, order[b], pairs[b], pa[b], pb[b])


def step_in_phases(venv: Any, actions: np.ndarray, clock: dict[str, float] | None = None):
    """``venv.step(actions)`` (a :class:`bgap.sim.vector.VectorHighway`), its phases run one
    after another; with ``clock``, each phase's seconds are added to ``clock[phase]``."""
    clock = {} if clock is None else clock

    def timed(phase: str, run: Callable[[], Any]) -> Any:
        start = time.perf_counter()
        out = run()
        clock[phase] = clock.get(phase, 0.0) + time.perf_counter() - start
        return out

    f, g, p, n_env, n = venv.f, venv.g, venv.p, venv.num_envs, venv.n + 1
    order = np.tile(np.arange(n), (n_env, 1))
    rank = order.copy()
    pairs = np.empty((n_env, n * (n - 1) // 2), np.int64)
    pa, pb = np.empty((n_env, 4, 2)), np.empty((n_env, 4, 2))
    actions = np.asarray(actions, dtype=np.int64).reshape(n_env)
    before = g[:, 0, TARGET_LANE].copy()
    for k in range(venv.frames_per_step):
        timed(
            "decisions (MOBIL)",
            lambda k=k: decide_all(f, g, p, actions, venv.speeds, venv.lanes, k == 0, order, rank),
        )
        timed("controllers", lambda: control_all(f, g))
        timed("IDM", lambda: idm_all(f, g, p, order, rank))
        timed("kinematics", lambda: move_all(f, g, p, venv.dt, venv.lanes))
        timed("collisions", lambda: collide_all(f, g, venv.dt, order, rank, pairs, pa, pb))
    venv.steps += 1
    obs = timed("observation", venv._observe)
    rewards, terms = timed("reward+info", lambda: venv._rewards(before))
    done = (terms["collision_reward"] > 0) | (venv.steps >= venv.max_steps)
    timed("reward+info", lambda: venv._info(terms["lane_change_reward"] > 0))
    if done.any():
        timed("resets", lambda: venv._spawn(np.flatnonzero(done)))
        obs = timed("resets", venv._observe)  # the new scenes' first observation
    return obs, rewards, done


def phase_split(venv: Any, seconds: float, seed: int = 0) -> dict[str, float]:
    """Nanoseconds per env-step of each phase, over about ``seconds`` of random-action
    stepping of ``venv``."""
    rng = np.random.default_rng(seed)
    venv.reset(seed=seed)
    step_in_phases(venv, rng.integers(5, size=venv.num_envs))  # compile outside the clock
    clock: dict[str, float] = {}
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        step_in_phases(venv, rng.integers(5, size=venv.num_envs), clock)
        steps += venv.num_envs
    return {phase: 1e9 * clock.get(phase, 0.0) / steps for phase in PHASES}
