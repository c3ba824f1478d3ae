"""Benchmarks, run by hand (never by the test suite): they print figures.

    python tools/bench.py env        # policy steps/s of our environment vs highway-v0
    python tools/bench.py sim        # vectorised backend vs highway-env vs EnvPool (optional:
                                    # pip install -e ".[bench]"), both cores
    python tools/bench.py learn      # DQN gradient updates/s: SB3 (one training) vs the batched
                                    # learner with K = 1, 4, 10, 20 members, dense traffic
    python tools/bench.py evaluate   # evaluation's rollouts (100 seeded episodes a batch), envs
                                    # whose episode ended skipped vs simulated on
    python tools/bench.py cmetric    # CMetric vehicle-frames/s vs a networkx baseline (1 core:
                                    # OMP_NUM_THREADS=1 taskset -c 0 python tools/bench.py cmetric)
    python tools/bench.py cluster    # the same 4 trainings (a minute each) on a local Ray
                                    # cluster of 1 node, then 2 nodes (one CPU each; the
                                    # cluster extra)
    python tools/bench.py side       # 2 SB3 trainings side by side (bgap.train workers=2):
                                    # numba's default threads in each vs bgap.train's share

Figures are reported beside a baseline measured in the same run, since machines are noisy.
"""

from __future__ import annotations

if __name__ == "__main__":  # the kernels every bgap command computes with, before torch loads
    from bgap.runner.numerics import pin

    pin()

import argparse
import os
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from bgap.cmetric import score_trajectories
from bgap.cmetric.centrality import Scene, centralities
from bgap.cmetric.io import load_trajectories
from bgap.cmetric.params import CMetricConfig
from bgap.cmetric.reference import centralities_networkx
from bgap.common.config import validate
from bgap.common.presets import load_preset, preset_path
from bgap.datasets.config import compose as compose_scene
from bgap.experiments.config import compose as compose_training
from bgap.traffic.scenario import env_config, fast_mode

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run as a script: tools.*
from tools.cli import OneLineParser, positive  # noqa: E402


def steps_per_second(env, seconds: float, seed: int = 0) -> float:
    """Random ego actions, auto-reset, for about ``seconds`` of wall time."""
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        _, _, term, trunc, _ = env.step(int(rng.integers(env.action_space.n)))
        steps += 1
        if term or trunc:
            env.reset(seed=seed + steps)
    return steps / (time.perf_counter() - start)


def bench_env(seconds: float) -> None:
    # Imported here: each benchmark loads only what it measures (cmetric: no simulator).
    import gymnasium as gym
    import highway_env  # noqa: F401

    from bgap.envs import make_env

    print(f"{'scenario':<10}{'highway-v0':>14}{'bgap paper':>14}{'bgap stock':>14}{'ratio':>8}")
    for density in ("sparse", "dense"):
        paper_cfg = validate(compose_scene("simulate", [f"env={density}"]))
        stock_cfg = validate(compose_scene("simulate", [f"env={density}", "behavior=stock"]))
        ours = env_config(paper_cfg)
        keys = ("lanes_count", "vehicles_count", "duration", "policy_frequency")
        settings = {k: ours[k] for k in (*keys, "simulation_frequency")}  # the same road
        ref = steps_per_second(gym.make("highway-v0", config=settings), seconds)
        paper = steps_per_second(make_env(paper_cfg), seconds)
        stock = steps_per_second(make_env(stock_cfg), seconds)
        print(f"{density:<10}{ref:>14.1f}{paper:>14.1f}{stock:>14.1f}{paper / ref:>8.2f}")
    print("policy steps/s, random ego actions; ratio = bgap paper / highway-v0")


def synthetic_log(minutes: float = 60.0, vehicles: int = 40, fps: int = 15, seed: int = 0):
    """A 4-lane ring-road log: speeds 20-38 m/s drifting slowly, a 2 s lane change every ~20 s
    per vehicle. Benchmark data only: it has the size and sparsity of real logs."""

    rng = np.random.default_rng(seed)
    n_frames = int(minutes * 60 * fps)
    dt = 1.0 / fps
    ring = 1200.0
    speed = np.clip(
        rng.uniform(20, 38, vehicles)
        + np.cumsum(rng.normal(0, 0.05, (n_frames, vehicles)), axis=0),
        10,
        45,
    )
    x = (rng.uniform(0, ring, vehicles) + np.cumsum(speed * dt, axis=0)) % ring
    lane = np.zeros((n_frames, vehicles))
    current = rng.integers(0, 4, vehicles).astype(float)
    for f in range(n_frames):  # lane targets change at random, approached at 2 m/s laterally
        switch = rng.random(vehicles) < 1.0 / (20 * fps)
        current = np.where(switch, np.clip(current + rng.choice([-1, 1], vehicles), 0, 3), current)
        lane[f] = current
    y = 4.0 * lane
    for f in range(1, n_frames):
        y[f] = y[f - 1] + np.clip(4.0 * lane[f] - y[f - 1], -2.0 * dt, 2.0 * dt)
    vy = np.vstack([np.zeros((1, vehicles)), np.diff(y, axis=0) / dt])
    frames = np.repeat(np.arange(n_frames), vehicles)
    return pd.DataFrame(
        {
            "frame": frames,
            "time": frames * dt,
            "vehicle_id": np.tile(np.arange(vehicles), n_frames),
            "x": x.ravel(),
            "y": y.ravel(),
            "vx": speed.ravel(),
            "vy": vy.ravel(),
        }
    )


def bench_cmetric(seconds: float) -> None:
    """One-hour, 40-vehicle, 15 Hz log: our full scoring vs networkx centralities per frame."""

    cfg = CMetricConfig()
    log = synthetic_log()
    rows = len(log)
    presets = {"default": cfg}
    for name in ("robust", "tuned"):  # the shipped presets, tuned once the pipeline wrote it
        if preset_path("cmetric", name).exists():
            presets[name] = load_preset(CMetricConfig, preset_path("cmetric", name))
    times = {}
    for name, preset in presets.items():
        score_trajectories(log[log.frame < 100], preset)  # compile outside the clock
        start = time.perf_counter()
        score_trajectories(log, preset)
        times[name] = time.perf_counter() - start
    full = times["default"]

    # The baseline gets the same frames, as many as fit in `seconds`.
    n_frames = int(log.frame.max()) + 1
    scene = Scene.from_table(load_trajectories(log))
    take = 50
    start = time.perf_counter()
    while True:
        part = Scene(
            scene.frames[:take],
            scene.times[:take],
            scene.vehicle_ids,
            scene.x[:take],
            scene.y[:take],
            scene.speed[:take],
            scene.present[:take],
        )
        t0 = time.perf_counter()
        ref = centralities_networkx(part, cfg.mu)
        nx_time = time.perf_counter() - t0
        if time.perf_counter() - start > seconds or take >= n_frames:
            break
        take = min(n_frames, take * 2)
    t0 = time.perf_counter()
    ours = centralities(part, cfg.mu)
    ours_time = time.perf_counter() - t0
    assert np.allclose(ours[0], ref[0], equal_nan=True) and np.array_equal(ours[1], ref[1])
    vf = part.present.sum()
    print(f"log: {rows:,} vehicle-frames ({n_frames:,} frames x 40 vehicles, 15 Hz, 1 h)")
    for name, seconds_taken in times.items():
        print(
            f"bgap full scoring (graphs, fits, styles), cmetric={name}: {seconds_taken:6.2f} s "
            f"{rows / seconds_taken:12,.0f} vf/s  ({seconds_taken / full:.2f} x default's time)"
        )
    print(f"on the first {take:,} frames, centralities only (identical results):")
    print(f"  networkx per frame : {vf / nx_time:12,.0f} vf/s")
    print(f"  bgap (numba)       : {vf / ours_time:12,.0f} vf/s")
    print(
        f"  ratio bgap/networkx: {nx_time / ours_time:12,.0f} x (centralities); "
        f"{(rows / full) / (vf / nx_time):,.0f} x (full scoring vs networkx centralities)"
    )


def _vector_steps_per_second(config: dict, num_envs: int, seconds: float) -> float:
    # Imported here: each benchmark loads only what it measures (cmetric: no simulator).
    from bgap.sim.vector import VectorHighway

    venv = VectorHighway(config, num_envs)
    venv.reset(seed=0)
    rng = np.random.default_rng(0)
    venv.step(rng.integers(5, size=num_envs))  # compile / load the cached kernels
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        venv.step(rng.integers(5, size=num_envs))
        steps += num_envs
    return steps / (time.perf_counter() - start)


def _envpool_steps_per_second(
    n: int, rows: int, num_envs: int, threads: int, seconds: float
) -> float | None:
    try:
        # Imported here: EnvPool is the optional bench extra (pip install -e '.[bench]').
        import envpool
    except ImportError:
        return None
    env = envpool.make_gymnasium(
        "Highway-v0",
        num_envs=num_envs,
        batch_size=num_envs,
        num_threads=threads,
        seed=0,
        lanes_count=4,
        vehicles_count=n,
        observation_vehicles_count=rows,
        duration=60,
        max_episode_steps=60,
        simulation_frequency=15,
        policy_frequency=1,
    )
    env.reset()
    rng = np.random.default_rng(0)
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        env.step(rng.integers(5, size=num_envs))
        steps += num_envs
    return steps / (time.perf_counter() - start)


def bench_sim(seconds: float, num_envs: int = 64, threads: int = 2) -> None:
    """Policy steps/s, random ego actions, dense and sparse, of highway-env (one env, the
    reference), bgap's vectorised backend (``num_envs`` envs on ``threads`` threads) and
    EnvPool's C++ Highway-v0 at the same settings (when installed); then the vector backend
    in the opt-in fast mode (:func:`bgap.traffic.scenario.fast_mode`, 10 Hz instead of 15)."""
    # Imported here: each benchmark loads only what it measures (cmetric: no simulator).
    import numba

    from bgap.envs import make_env

    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    print(f"{num_envs} envs, {threads} threads, random ego actions, policy steps/s")
    head = f"{'scenario':<9}{'highway-env':>13}{'vector':>11}{'EnvPool':>11}"
    fast_head = f"{'fast':>9}{'fast/highway':>14}{'fast/EnvPool':>14}"
    print(f"{head}{'vector/highway':>16}{'vector/EnvPool':>16}{fast_head}")
    configs: dict[str, dict] = {}
    for density in ("dense", "sparse"):
        cfg = validate(compose_scene("simulate", [f"env={density}"]))
        config = env_config(cfg)
        ref = steps_per_second(make_env(cfg), seconds)
        vec = _vector_steps_per_second(config, num_envs, seconds)
        pool = _envpool_steps_per_second(
            cfg.env.vehicles_count, cfg.env.observed_vehicles, num_envs, threads, seconds
        )
        fast = _vector_steps_per_second(fast_mode(config), num_envs, seconds)
        pool_s = f"{pool:>11.0f}" if pool else f"{'n/a':>11}"
        ratio = f"{vec / pool:>16.2f}" if pool else f"{'n/a':>16}"
        fast_ratio = f"{fast / pool:>14.2f}" if pool else f"{'n/a':>14}"
        print(
            f"{density:<9}{ref:>13.1f}{vec:>11.0f}{pool_s}{vec / ref:>16.0f}{ratio}"
            f"{fast:>9.0f}{fast / ref:>14.0f}{fast_ratio}"
        )
        configs[density] = config
    print("EnvPool has no behaviour classes (its traffic is highway-env's stock IDM).")
    print("fast: the vector backend at 10 Hz (bgap.scenario.fast_mode), the others at 15 Hz.")
    _print_phase_split(configs, num_envs, seconds)


def bench_evaluate(seconds: float, episodes: int = 100) -> None:
    """Evaluation's rollouts (:func:`bgap.sim.rollout.rollout`, one batch of ``episodes``
    seeded episodes per cell and policy, as ``bgap.evaluate`` plays them) with envs whose
    episode ended skipped (``FINISHED``, the default) against the same rollouts with them
    simulated on (the baseline, in the same run): episodes/s of each and their ratio, dense
    and sparse, for the baselines and an untrained DQN (its forward pass costs what a trained
    one's does). The episodes are the same (tests/test_sim.py); ``seconds`` bounds each
    measurement's repetitions."""
    # Imported here: each benchmark loads only what it measures (cmetric: no simulator).
    from bgap.agents.policies import rollout
    from bgap.experiments.train import make_training_env
    from bgap.experiments.training import build_model
    from bgap.runner.threads import set_threads
    from bgap.sim.vector import VectorHighway

    set_threads(1)  # as bgap.evaluate's workers

    def rate(config: dict, policy, skip: bool) -> tuple[float, float]:
        VectorHighway.skips_finished = skip
        seeds, played, start = range(episodes), 0, time.perf_counter()
        while True:
            ep = rollout(config, policy, seeds, "vector").episodes
            played += len(ep)
            if time.perf_counter() - start >= seconds:
                break
        finished = 1 - ep.steps.mean() / ep.steps.max()  # env-steps a full batch wastes
        return played / (time.perf_counter() - start), finished

    print(
        f"{episodes} episodes per batch, episodes/s; 'ended early': the share of the "
        "batch's env-steps after an env's episode ended"
    )
    print(
        f"{'scenario':<9}{'policy':<9}{'simulated on':>14}{'skipped':>10}{'ratio':>8}"
        f"{'ended early':>13}"
    )
    try:
        for density in ("dense", "sparse"):
            cfg = validate(compose_training("train", [f"env={density}"]))
            config = env_config(cfg)
            with tempfile.TemporaryDirectory() as tmp:
                env = make_training_env(cfg, 1, seed=0)
                model = build_model(cfg, env, Path(tmp))
                rollout(config, model, range(2), "vector")  # compile / load the kernels
                for name, policy in (
                    ("idle", "idle"),
                    ("rule", "rule"),
                    ("random", "random"),
                    ("dqn", model),
                ):
                    base, _ = rate(config, policy, False)
                    fast, early = rate(config, policy, True)
                    print(
                        f"{density:<9}{name:<9}{base:>14.1f}{fast:>10.1f}{fast / base:>8.2f}"
                        f"{early:>13.1%}"
                    )
    finally:
        VectorHighway.skips_finished = True


def _print_phase_split(configs: dict[str, dict], num_envs: int, seconds: float) -> None:
    """Where a vector step's time goes: each phase as its own batched kernel
    (:mod:`bgap.sim.phases`), in ns per env-step and as a share of the phases' sum."""
    # Imported here: each benchmark loads only what it measures (cmetric: no simulator).
    from bgap.sim.phases import PHASES, phase_split
    from bgap.sim.vector import VectorHighway

    print(f"\nvector backend per phase, {num_envs} envs (ns per env-step, % of the sum)")
    print(f"{'phase':<24}" + "".join(f"{d:>20}" for d in configs))
    splits = {d: phase_split(VectorHighway(c, num_envs), seconds) for d, c in configs.items()}
    for phase in PHASES:
        cells = "".join(
            f"{splits[d][phase]:>12.0f} {100 * splits[d][phase] / sum(splits[d].values()):>6.1f}%"
            for d in configs
        )
        print(f"{phase:<24}{cells}")
    print("(each phase a kernel of its own here: the fused step above skips their launches)")


def _learn_config(policy: str = "behavior_rich"):
    """Dense traffic, the default agent at the paper's replay ratio (one update per
    transition: ``gradient_steps=-1``)."""

    return validate(
        compose_training("train", ["env=dense", f"policy={policy}", "agent.gradient_steps=-1"])
    )


def _sb3_rate(seconds: float) -> tuple[float, float]:
    """Gradient updates/s and transitions/s of SB3's DQN (bgap.train's model), one training,
    after ``learning_starts``."""

    # Imported here: each benchmark loads only what it measures (cmetric: no torch).
    import torch

    from bgap.experiments.train import make_training_env
    from bgap.experiments.training import build_model

    torch.set_num_threads(1)  # as bgap.train
    cfg = _learn_config()
    env = make_training_env(cfg, cfg.profile.n_envs, seed=0)
    with tempfile.TemporaryDirectory() as tmp:
        model = build_model(cfg, env, Path(tmp))
        model.tensorboard_log = None
        model.learn(cfg.agent.learning_starts + 200)  # warm: past learning_starts, compiled
        updates, steps, start, chunk = (
            model._n_updates,
            model.num_timesteps,
            time.perf_counter(),
            200,
        )
        while time.perf_counter() - start < seconds:
            model.learn(chunk, reset_num_timesteps=False)
        elapsed = time.perf_counter() - start
        rates = (model._n_updates - updates) / elapsed, (model.num_timesteps - steps) / elapsed
    env.close()
    return rates


def _batched_rate(k: int, seconds: float, device: str | None = None) -> tuple[float, float]:
    """Member gradient updates/s and transitions/s of a K-member batched learner: the
    training loop of :func:`bgap.experiments.train.train_batched` (act, simulate all members'
    envs in one vector env, store, update) without its bookkeeping (episode statistics,
    checkpoints)."""
    # Imported here: each benchmark loads only what it measures (cmetric: no torch).
    from bgap.agents.batched import BatchedDQN, Schedule
    from bgap.experiments.batched import final_observations
    from bgap.sim.simulators import make_vector_env

    cfg = _learn_config()
    e = cfg.profile.n_envs
    venv = make_vector_env(env_config(cfg, cfg.mix_sampling), k * e, "vector")
    obs, _ = venv.reset(seed=list(range(k * e)))
    space = venv.single_observation_space
    learner = BatchedDQN(
        cfg.agent,
        Schedule(e, cfg.profile.train_steps, cfg.agent.exploration_decay_steps),
        list(range(k)),
        int(np.prod(space.shape)),
        5,
        device=device,
    )
    members = np.arange(k)
    obs = obs.reshape(k, e, *space.shape)

    def step() -> None:
        nonlocal obs
        actions = learner.act(obs, members)
        new, rewards, term, trunc, info = venv.step(actions.reshape(-1))
        final = final_observations(new, term | trunc, info)
        learner.num_timesteps += e
        shape = (k, e)
        learner.observe(
            members,
            obs,
            final.reshape(k, e, -1),
            actions,
            rewards.reshape(shape),
            term.reshape(shape),
            trunc.reshape(shape),
        )
        obs = new.reshape(obs.shape)
        learner.train(members)

    while learner.n_updates[0] < 20:  # past learning_starts, kernels compiled
        step()
    updates, steps, start = (
        learner.n_updates.sum(),
        learner.num_timesteps.sum(),
        time.perf_counter(),
    )
    while time.perf_counter() - start < seconds:
        step()
    elapsed = time.perf_counter() - start
    return (learner.n_updates.sum() - updates) / elapsed, (
        learner.num_timesteps.sum() - steps
    ) / elapsed


def bench_learn(seconds: float, ks: tuple[int, ...] = (1, 4, 10, 20), threads: int = 0) -> None:
    """Gradient updates/s of SB3's DQN (one training) and of the batched learner with K
    members (member-updates/s), dense traffic, one update per transition; and the wall time
    of a study of 40 trainings x 180,000 transitions at each rate."""

    # Imported here: each benchmark loads only what it measures (cmetric: no torch).
    import torch

    from bgap.agents.stacked_qnets import default_device

    threads = threads or os.cpu_count() or 1
    study = 40 * 180_000  # transitions = updates at the paper's replay ratio
    sb3_updates, sb3_steps = _sb3_rate(seconds)
    torch.set_num_threads(threads)
    device = default_device()
    print(
        f"dense traffic, one gradient update per transition; batched learner on {device}, "
        f"{threads} torch threads"
    )
    print(f"{'learner':<16}{'updates/s':>11}{'transitions/s':>15}{'study 40x180k':>15}")
    print(
        f"{'SB3 DQN':<16}{sb3_updates:>11.0f}{sb3_steps:>15.0f}{study / sb3_updates / 3600:>14.1f}h"
    )
    rates = {}
    for k in ks:
        updates, steps = _batched_rate(k, seconds, str(device))
        rates[k] = updates
        name = f"batched K={k}"
        print(f"{name:<16}{updates:>11.0f}{steps:>15.0f}{study / updates / 3600:>14.1f}h")
    if 10 in rates:
        print(f"speedup K=10: {rates[10] / sb3_updates:.2f}x")
    _print_replay_rates(max(ks), seconds)


def _cumsum_sample(priorities: np.ndarray, u: np.ndarray) -> np.ndarray:
    """The sampler the sum trees replaced (the baseline): each member's cumulative sum,
    inverted with ``searchsorted``; O(K N) per gradient step."""
    cdf = np.cumsum(priorities, axis=1)
    return np.stack(
        [np.searchsorted(c, x * c[-1], side="right") for c, x in zip(cdf, u, strict=True)]
    )


def _print_replay_rates(k: int, seconds: float, n: int = 15_000, batch: int = 32) -> None:
    """Prioritized sampling and priority updates per gradient step of K full buffers of the
    paper's size: the cumulative-sum sampler against the stacked sum trees."""
    from bgap.agents.per import SumTrees

    rng = np.random.default_rng(0)
    priorities = rng.gamma(0.5, 1.0, (k, n)) + 1e-6
    trees, members = SumTrees(k, n), np.arange(k)
    for m in members:
        trees.rebuild(m, priorities[m])

    def cumsum_step() -> None:
        flat = _cumsum_sample(priorities, rng.random((k, batch)))
        priorities[members[:, None], flat] = rng.gamma(0.5, 1.0, (k, batch)) + 1e-6

    def tree_step() -> None:
        flat = trees.find(members, rng.random((k, batch)))
        trees.set(members, flat, rng.gamma(0.5, 1.0, (k, batch)) + 1e-6)

    rates = {}
    for name, step in (("cumulative sum", cumsum_step), ("sum trees", tree_step)):
        step()  # compiled (numba) before the clock starts
        count, start = 0, time.perf_counter()
        while time.perf_counter() - start < seconds / 2:
            step()
            count += 1
        rates[name] = count / (time.perf_counter() - start)
    print(f"PER sample + update, K={k} buffers of {n:,}, batch {batch} (gradient steps/s):")
    for name, rate in rates.items():
        print(f"  {name:<16}{rate:>9.0f}  {1e3 / rate:.2f} ms each")
    print(f"  sum trees: {rates['sum trees'] / rates['cumulative sum']:.1f}x")


def bench_cluster(seconds: float, trainings: int = 4) -> None:
    """``trainings`` SB3 trainings (seeds 0, 1, ...; sparse, vector backend; each about
    ``seconds`` of one core) as Ray tasks on a local cluster of one node, then of two
    (``ray.cluster_utils.Cluster``: separate node processes, one CPU each, a head without
    CPUs for the driver). Prints each wall time, with the cluster's start-up apart, and the
    ratio of the throughputs."""
    from ray.cluster_utils import Cluster

    from bgap.experiments.train import trainings as train_all
    from bgap.experiments.training import member_configs

    steps = max(300, int(seconds * 150))  # ~150 steps/s for one training on one core
    walls = {}
    for nodes in (1, 2):
        start = time.perf_counter()
        cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 0})
        for _ in range(nodes):
            cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        up = time.perf_counter() - start
        with tempfile.TemporaryDirectory() as tmp:
            cfg = validate(
                compose_training(
                    "train",
                    [
                        "profile=tiny",
                        f"profile.train_steps={steps}",
                        "env=sparse",
                        "backend=vector",
                        f"seeds=[{','.join(map(str, range(trainings)))}]",
                        f"run_dir={tmp}/runs",
                        f"cluster.address={cluster.address}",
                    ],
                )
            )
            start = time.perf_counter()
            train_all(member_configs(cfg), progress=False)
            walls[nodes] = time.perf_counter() - start
        cluster.shutdown()
        print(
            f"{nodes} node(s): {trainings} trainings of {steps} steps in {walls[nodes]:.1f} s "
            f"({trainings * steps / walls[nodes]:.0f} steps/s; the cluster started in "
            f"{up:.1f} s)",
            flush=True,
        )
    print(f"2 nodes / 1 node throughput: {walls[1] / walls[2]:.2f}x")


def _transitions_per_second(seconds: float) -> float:
    return _sb3_rate(seconds)[1]


def bench_side(seconds: float, trainings: int = 2) -> None:
    """Transitions/s of ``trainings`` SB3 trainings side by side, one spawned process each as
    in ``bgap.train workers=N``: first with numba's default threads in every process (one per
    core, as bgap.train ran them before 2026-12-04), then in bgap.train's pool (the cores
    shared out). Prints both sums and their ratio."""
    from concurrent.futures import ProcessPoolExecutor
    from functools import partial
    from multiprocessing import get_context

    import numba

    from bgap.runner.pools import process_pool
    from bgap.runner.threads import cores_per_process, set_threads

    pools = {
        f"numba's default ({numba.config.NUMBA_NUM_THREADS} threads each)": ProcessPoolExecutor(
            trainings, get_context("spawn"), initializer=partial(set_threads, 1)
        ),
        f"bgap.train's share ({cores_per_process(trainings)} each)": process_pool(trainings),
    }
    rates = []
    for name, pool in pools.items():
        with pool:
            rates.append(sum(pool.map(_transitions_per_second, [seconds] * trainings)))
        print(
            f"{trainings} trainings side by side, {name}: {rates[-1]:.0f} transitions/s", flush=True
        )
    print(f"share / default: {rates[1] / rates[0]:.2f}x")


def main(argv: list[str] | None = None) -> None:
    parser = OneLineParser(
        prog="tools/bench.py",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("what", choices=sorted(BENCHES))
    parser.add_argument(
        "--seconds",
        type=positive(float),
        default=None,
        help="wall time per measurement (default 10; cluster: about 60 of one core per training)",
    )
    parser.add_argument("--envs", type=positive(int), default=64, help="sim: batched environments")
    parser.add_argument(
        "--threads", type=positive(int), default=2, help="sim: threads for both peers"
    )
    parser.add_argument(
        "--members",
        type=positive(int),
        nargs="+",
        default=[1, 4, 10, 20],
        help="learn: values of K",
    )
    parser.add_argument(
        "--trainings",
        type=positive(int),
        default=None,
        help="cluster: trainings per cluster (default 4); side: trainings side by side (default 2)",
    )
    args = parser.parse_args(argv)
    # a cluster task's start costs seconds: a minute of work per task keeps it a small part
    args.seconds = args.seconds or (60.0 if args.what == "cluster" else 10.0)
    if args.what == "sim":
        bench_sim(args.seconds, num_envs=args.envs, threads=args.threads)
    elif args.what == "learn":
        bench_learn(args.seconds, tuple(args.members))
    elif args.what == "cluster":
        bench_cluster(args.seconds, args.trainings or 4)
    elif args.what == "side":
        bench_side(args.seconds, args.trainings or 2)
    else:
        BENCHES[args.what](args.seconds)


BENCHES: dict[str, Callable[[float], None]] = {
    "env": bench_env,
    "cmetric": bench_cmetric,
    "sim": bench_sim,
    "learn": bench_learn,
    "evaluate": bench_evaluate,
    "cluster": bench_cluster,
    "side": bench_side,
}

if __name__ == "__main__":
    main()
