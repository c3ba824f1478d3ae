"""Configs compose from conf/, and bad values fail at compose time with clear messages."""

from __future__ import annotations

import pytest
from hydra.errors import ConfigCompositionException, MissingConfigException
from omegaconf.errors import ValidationError

from bgap.common.config import validate
from bgap.common.errors import ConfigError
from bgap.traffic.scenario import env_config
from tests.configs import compose
from tests.conftest import make_cfg


def test_groups_compose():
    cfg = make_cfg("env=dense", "mix=0.6", "radius=90", "behavior=stock", "reward=highway")
    assert (cfg.env.vehicles_count, cfg.env.observed_vehicles) == (40, 40)
    assert cfg.mix == 0.6 and cfg.radius == 90.0
    assert cfg.behavior.aggressive.is_stock and cfg.behavior.conservative.is_stock
    d = env_config(cfg)
    assert d["perception_radius"] == 90.0 and d["vehicles_count"] == 40
    assert d["lane_change_reward"] == 0.0 and d["normalize_reward"] is True
    paper = make_cfg()
    assert paper.behavior.aggressive.v0 == 40.0 and paper.behavior.conservative.politeness == 0.5
    assert paper.env.duration == 60 and paper.env.simulation_frequency == 15


@pytest.mark.parametrize(
    "override,match",
    [
        ("mix=1.5", "mix=1.5 is invalid"),
        ("mix=-0.1", "mix"),
        ("radius=-1", "radius=-1"),
        ("radius=0", "radius"),
        ("behavior.aggressive.politeness=2", "politeness"),
        ("episodes=0", "episodes"),
        ("seed=-3", "seed=-3 is invalid"),
        ("policy=nowhere/model.zip", "policy='nowhere/model.zip' is invalid"),
        ("render=true", "render=True is invalid.*backend=highway"),
    ],
)
def test_out_of_range_values_name_the_key(override, match):
    extra = ["backend=vector"] if override.startswith("render") else []
    with pytest.raises(ConfigError, match=match):
        validate(compose("simulate", [override, *extra]))


@pytest.mark.parametrize("override", ["foo=1", "env.lanes=3", "reward.crash=-1"])
def test_unknown_keys_fail_at_compose(override):
    with pytest.raises(ConfigCompositionException, match="Could not override"):
        compose("simulate", [override])


def test_wrong_types_fail_at_compose():
    with pytest.raises((ConfigCompositionException, ValidationError)):
        compose("simulate", ["env.vehicles_count=many"])


def test_unknown_group_option_lists_the_choices():
    with pytest.raises(MissingConfigException, match="dense"):
        compose("simulate", ["env=medium"])


def test_the_pipeline_reaches_a_cluster_through_the_environment(monkeypatch):
    """BGAP_CLUSTER_ADDRESS / BGAP_CLUSTER_STORAGE fill cluster.address and cluster.storage
    when a command leaves them empty (dvc repro's stages, whose commands must not change);
    a value on the command line wins; neither changes a run folder's name."""
    from bgap.common.config import validate
    from bgap.experiments.run import results_dir
    from tests.configs import compose

    here = validate(compose("run", ["profile=tiny"]))
    monkeypatch.setenv("BGAP_CLUSTER_ADDRESS", "auto")
    monkeypatch.setenv("BGAP_CLUSTER_STORAGE", "/shared/bgap")
    there = validate(compose("run", ["profile=tiny"]))
    assert (there.cluster.address, there.cluster.storage) == ("auto", "/shared/bgap")
    given = validate(compose("run", ["profile=tiny", "cluster.address=local"]))
    assert given.cluster.address == "local"
    assert results_dir(here) == results_dir(there)


@pytest.mark.parametrize(
    ("val_seed", "refused"), [(90_000, False), (90_001, True), (109_999, True), (110_000, False)]
)
def test_seed_blocks_at_the_gap(val_seed, refused):
    """Validation and test seed blocks (eval_seed 100000) must start 10,000 apart, either way
    round: one seed closer is refused, naming both."""
    cfg = compose("train", [f"val_seed={val_seed}"])
    if not refused:
        validate(cfg)
        return
    says = f"val_seed={val_seed} is invalid: must be at least 10000 away from eval_seed=100000"
    with pytest.raises(ConfigError, match=says):
        validate(cfg)


def test_a_config_reads_no_file_until_its_command_loads_it(tmp_path):
    """A replayed table no episode can come from (a CSV without trajectory columns): building
    the config (a worker's, a trial's) reads nothing and passes; the command's load refuses
    it in one line, for the environment's table as for every grid table."""
    from bgap.common.config import load
    from bgap.common.errors import TrajectoryError

    table = tmp_path / "table.csv"
    table.write_text("a,b\n1,2\n")
    for overrides in (
        ["traffic=replay", f"traffic.table={table}"],
        [f"grid.replays=[{table}]"],
    ):
        cfg = compose("evaluate", ["baselines=[idle]", *overrides])
        validate(cfg)
        with pytest.raises(TrajectoryError, match=r"table\.csv"):
            load(cfg)
