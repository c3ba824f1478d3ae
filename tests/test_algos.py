"""The learners beside DQN (issue 32): QR-DQN (sb3-contrib) and PPO (SB3) through bgap's
training, saving, loading and evaluation; resuming a killed training: tests/test_inputs.py."""

from __future__ import annotations

from functools import partial

import numpy as np
import pytest
import torch as th

from bgap.common.config import validate
from bgap.common.errors import ConfigError
from tests.configs import compose


def test_the_per_sample_quantile_loss_averages_to_sb3_contribs():
    """bgap's per-sample quantile Huber loss (needed for importance weights) against
    sb3-contrib's batch loss: their mean over the batch is the library's number, for equal
    and unequal numbers of current and target quantiles, and kappa = 1."""
    from sb3_contrib.common.utils import quantile_huber_loss

    from bgap.agents.qrdqn import quantile_huber_per_sample

    gen = th.Generator().manual_seed(0)
    for n, m in ((11, 11), (25, 7)):
        current, target = th.randn(16, n, generator=gen), 3 * th.randn(16, m, generator=gen)
        per_sample = quantile_huber_per_sample(current, target)
        assert per_sample.shape == (16,)
        want = quantile_huber_loss(current, target, sum_over_quantiles=True)
        assert th.allclose(per_sample.mean(), want, rtol=1e-6)


@pytest.mark.parametrize("algo,cls", [("qrdqn", "QRDQN"), ("ppo", "PPO")])
def test_each_algorithm_trains_saves_loads_and_is_evaluated(tmp_path, algo, cls):
    """``agent=<algo>`` at the tiny profile: a run folder with model.zip and its TensorBoard
    log under the algorithm's name; the model loads as its own class (recognised from the
    file) and plays the same seeded episodes twice alike."""
    from bgap.agents.policies import load_model
    from bgap.experiments.evaluate import Cell, evaluate
    from bgap.experiments.train import train
    from bgap.experiments.training import run_name

    cfg = validate(compose("train", [f"agent={algo}", "profile=tiny", "env=sparse",
                                     f"root={tmp_path}"]))  # fmt: skip
    dqn = validate(compose("train", ["profile=tiny", "env=sparse", f"root={tmp_path}"]))
    assert run_name(cfg) != run_name(dqn)  # another training, another folder
    run = train(cfg, progress=False)
    assert (run / "model.zip").exists() and any((run / "tb").glob(f"{algo}_*"))
    model = load_model(run / "model.zip")
    assert type(model).__name__ == cls
    cells = [Cell(0.5, "sparse", 180.0)]
    first = evaluate(cfg, {"m": str(run)}, cells, episodes=3, progress=False)
    again = evaluate(cfg, {"m": str(run)}, cells, episodes=3, progress=False)
    assert len(first) == 3 and first.equals(again)
    assert np.isfinite(first.avg_speed).all()
    # read as another algorithm's (a QR-DQN file named dqn:): one line, not a traceback
    other = "dqn"
    with pytest.raises(ConfigError, match="is not a readable model") as err:
        load_model(f"{other}:{run / 'model.zip'}")
    assert "\n" not in str(err.value)


def test_the_batched_learner_refuses_other_algorithms_and_names_are_kept():
    """learner=batched is DQN's alone (one line naming the way out); a DQN training's run
    folder keeps the name it had before the algorithms' settings existed."""
    from bgap.experiments.training import training_identity

    with pytest.raises(ConfigError, match="trains DQN only; agent.algo=ppo trains with learner"):
        validate(compose("train", ["agent=ppo", "learner=batched"]))
    identity = training_identity(validate(compose("train", ["profile=tiny"])))
    assert "algo" not in identity["agent"] and "n_quantiles" not in identity["agent"]


def _observations(rows: int = 8, batch: int = 6, present: int = 5) -> th.Tensor:
    """bgap's layout: presence first, the ego in row 0, ``present`` - 1 others, then absent
    rows of zeros."""
    gen = th.Generator().manual_seed(1)
    obs = th.rand(batch, rows, 5, generator=gen) * 2 - 1
    obs[:, :, 0] = 1.0
    obs[:, present:] = 0.0
    return obs


def test_ego_attention_reads_the_other_vehicles_as_a_set_and_ignores_absent_rows():
    """Any order of rows 1..V-1 (absent rows moved among them too) gives the same features;
    anything written into absent rows changes nothing; an ego alone gives finite features;
    moving a present vehicle, or swapping the ego with another row, changes them."""
    import gymnasium as gym

    from bgap.agents.attention import EgoAttention

    th.manual_seed(0)
    extractor = EgoAttention(gym.spaces.Box(-1, 1, (8, 5)), embed_dim=16, heads=2).eval()
    obs = _observations()
    base = extractor(obs)
    for seed in range(5):
        perm = th.randperm(7, generator=th.Generator().manual_seed(seed)) + 1
        shuffled = obs[:, th.cat([th.tensor([0]), perm])]
        assert th.allclose(extractor(shuffled), base, atol=1e-6)
    garbage = obs.clone()
    garbage[:, 5:, 1:] = th.rand(6, 3, 4) * 5  # features of absent rows (presence stays 0)
    assert th.allclose(extractor(garbage), base, atol=1e-6)
    alone = obs.clone()
    alone[:, 1:] = 0.0
    assert th.isfinite(extractor(alone)).all()
    moved = obs.clone()
    moved[:, 2, 1] += 0.3
    assert not th.allclose(extractor(moved), base, atol=1e-4)
    swapped = obs[:, [1, 0, 2, 3, 4, 5, 6, 7]]
    assert not th.allclose(extractor(swapped), base, atol=1e-4)


@pytest.mark.parametrize("algo", ["dqn", "ppo"])
def test_an_attention_network_trains_and_loads_with_its_extractor(tmp_path, algo):
    """``agent.extractor=attention``: the policy's features extractor is ego attention; the
    saved model loads and acts as the trained one; the batched learner refuses it."""
    from bgap.agents.attention import EgoAttention
    from bgap.agents.policies import load_model
    from bgap.experiments.train import train

    overrides = [f"agent={algo}", "agent.extractor=attention", "agent.attention_dim=16",
                 "profile=tiny", "env=sparse", f"root={tmp_path}"]  # fmt: skip
    run = train(validate(compose("train", overrides)), progress=False)
    model = load_model(run / "model.zip")
    assert any(isinstance(m, EgoAttention) for m in model.policy.modules())
    obs = _observations(rows=5, batch=4).numpy()
    assert (model.predict(obs, deterministic=True)[0] == load_model(run).predict(
        obs, deterministic=True)[0]).all()  # fmt: skip
    refusal = "stacks plain MLPs only" if algo == "dqn" else "trains DQN only"
    with pytest.raises(ConfigError, match=refusal):
        validate(compose("train", [*overrides, "learner=batched"]))


@pytest.mark.slow
def test_sb3_trainings_side_by_side_learn_what_they_learn_alone(tmp_path, monkeypatch):
    """bgap.train seeds=[0,1] with the SB3 learner in two processes (workers=2) and one after
    the other (workers=1): the same parameters, in the same per-training folders; each
    folder's command.txt is the command that started them, not the worker process's."""
    from bgap.agents.policies import load_model
    from bgap.common.cli import ENV_COMMAND, own_command, run
    from bgap.experiments.train import trainings
    from bgap.experiments.training import member_configs

    monkeypatch.setenv(ENV_COMMAND, "")  # restored after the test: run() sets it
    dirs = {}
    for workers in (1, 2):
        overrides = ["agent=ppo", "profile=tiny", "profile.train_steps=5000", "env=sparse",
                     "seeds=[0,1]", "backend=vector", f"workers={workers}"]  # fmt: skip
        cfg = validate(compose("train", [*overrides, f"run_dir={tmp_path}/w{workers}"]))
        members = member_configs(cfg)
        dirs[workers] = run("test", partial(trainings, members, False), "")
    assert [d.name for d in dirs[1]] == ["sparse-behavior_rich-s0", "sparse-behavior_rich-s1"]
    assert {(d / "command.txt").read_text() for d in dirs[2]} == {own_command() + "\n"}
    for alone, side in zip(dirs[1], dirs[2], strict=True):
        a, b = (load_model(d).policy.state_dict() for d in (alone, side))
        assert all(th.equal(a[k], b[k]) for k in a)
    s0, s1 = (load_model(d).policy.state_dict() for d in dirs[2])
    assert not all(th.equal(s0[k], s1[k]) for k in s0)  # two seeds, two trainings


def test_the_recipe_objective_scores_both_policies_against_the_rule_based_ego():
    """Hand-built figures: below 0 exactly when both of issue 32's rules hold; a policy under
    0.95 x the rule-based ego's speed puts the recipe behind every one that keeps the pace."""
    from bgap.analysis.stats import rule_objective

    def f(pct, per100, speed):
        return {"collision_pct": pct, "per_100km": per100, "avg_speed": speed}

    rule, stock_rule = f(3.0, 2.0, 27.0), f(0.0, 0.0, 22.0)
    # behaviour-rich 1.5 per 100 km (0.5 under the rule's), default 0.5% (0.5 under 0 + 1)
    assert rule_objective(f(2.0, 1.5, 26.0), rule, f(0.5, 0.3, 21.0), stock_rule) == -0.5
    # the default policy's 2% is 1 point over its allowance: the worse excess counts
    assert rule_objective(f(2.0, 1.5, 26.0), rule, f(2.0, 1.0, 21.0), stock_rule) == 1.0
    # 25.0 m/s < 0.95 x 27 = 25.65: 1000 + the shortfall, 2.53% of the floor
    slow = rule_objective(f(0.0, 0.0, 25.0), rule, f(0.0, 0.0, 21.0), stock_rule)
    assert slow == pytest.approx(1000 + 100 * (25.65 - 25.0) / 25.65)


def test_the_stock_rule_and_the_speed_floor_by_hand():
    """keeps_up: at most 1 point more collisions than the rule-based ego at >= 0.95 x its
    speed (20.9 m/s for 22); speed_shortfall: 0 at or above the floor, else % of it."""
    from bgap.analysis.stats import keeps_up, speed_shortfall

    assert keeps_up(1.0, 20.9, 0.0, 22.0) and not keeps_up(1.1, 21.0, 0.0, 22.0)
    assert not keeps_up(0.0, 20.8, 0.0, 22.0)  # safe, but under 20.9
    assert speed_shortfall(20.9, 22.0) == 0.0 and speed_shortfall(30.0, 22.0) == 0.0
    assert speed_shortfall(19.0, 22.0) == pytest.approx(100 * 1.9 / 20.9)
