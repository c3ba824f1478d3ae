"""A second simulator's trajectories: SUMO recorded into bgap's trajectory table."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from bgap.cmetric.io import load_trajectories
from bgap.datasets.sumo import SumoConfig, record
from bgap.sim.recorder import COLUMNS

SMALL = SumoConfig(lanes=3, length=1500.0, flow=0.5, warmup=45.0, duration=6.0, ego_position=600)


@pytest.fixture(scope="module")
def table() -> pd.DataFrame:
    return record(SMALL, episodes=2, seed=5)


def test_table_has_bgaps_schema_and_reads_as_trajectories(table):
    assert list(table.columns) == COLUMNS
    assert set(table.label) == {"aggressive", "conservative", "ego"}
    assert sorted(table.episode.unique()) == [0, 1]
    ego = table[table.is_ego]
    assert (ego.vehicle_id == 0).all() and (ego.label == "ego").all()
    assert ego.groupby("episode").frame.nunique().eq(round(SMALL.duration / 0.067)).all()
    assert table.lane.between(0, SMALL.lanes - 1).all()
    np.testing.assert_allclose(table.time, table.frame * 0.067, atol=1e-9)  # SUMO's ms clock
    load_trajectories(table)  # CMetric's validation passes


def test_positions_follow_the_recorded_speeds(table):
    # SUMO's default (Euler) update: x(t + dt) = x(t) + v(t + dt) dt along the road; steps
    # in which a driver brakes or dawdles depart by up to ~1 %, the typical step by far
    # less: a wrong clock (1/15 s instead of SUMO's 0.067 s) would shift every step 0.5 %
    one = table.sort_values(["episode", "vehicle_id", "frame"])
    same = one.groupby(["episode", "vehicle_id"])
    dx, dt = same.x.diff().dropna(), same.time.diff().dropna()
    moved = one.loc[dx.index, "vx"] * dt
    error = np.abs(dx - moved) / moved.clip(lower=0.1)
    assert np.median(error) < 1e-3 and error.max() < 0.02


def test_driver_types_set_the_speeds_sumo_defines(table):
    # desired speed = speedFactor x limit: 1.3 x 30 for aggressive, 0.85 x 30 conservative
    speed = table.groupby("label").speed.mean()
    assert speed["aggressive"] > 1.2 * speed["conservative"]
    assert speed["conservative"] < 0.85 * SMALL.speed_limit * 1.1


def test_same_seed_same_table_other_seed_other_table(table):
    again = record(SMALL, episodes=2, seed=5)
    pd.testing.assert_frame_equal(again, table)
    other = record(SMALL, episodes=1, seed=6)
    assert not other.equals(table[table.episode == 0])


def test_command_writes_a_dataset_and_refuses_bad_values(tmp_path):
    def datasets(*args):
        return subprocess.run(
            [sys.executable, "-m", "bgap.datasets", "sumo", *args],
            capture_output=True,
            text=True,
            timeout=300,
        )

    small = [
        "episodes=1",
        "sumo.warmup=30",
        "sumo.duration=3",
        "sumo.length=1500",
        "sumo.ego_position=500",
    ]
    done = datasets(*small, f"out={tmp_path / 'sumo'}")
    assert done.returncode == 0, done.stderr
    written = pd.read_parquet(tmp_path / "sumo" / "trajectories.parquet")
    assert len(written) > 0 and (tmp_path / "sumo" / "config.yaml").exists()
    bad = datasets("sumo.flow=2", f"out={tmp_path / 'bad'}")
    assert bad.returncode == 2 and "sumo.flow=2.0 is invalid" in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1 and not (tmp_path / "bad").exists()


@pytest.mark.slow
@pytest.mark.parametrize(
    "car_following, flow, floor",
    [("Krauss", 0.15, 0.90), ("Krauss", 0.6, 0.96), ("IDM", 0.15, 0.90), ("IDM", 0.6, 0.96)],
)
def test_tuned_cmetric_tells_sumos_driver_types_apart(car_following, flow, floor):
    """The pipeline's SUMO validation data (10 episodes, seeds 100-109) scored with the
    tuned preset, which SUMO never tuned. Measured with the preset re-searched in the
    retrained study (results/cmetric/report.md, 120 trials, mu 80 m): Krauss sparse 0.904,
    dense 0.962; IDM sparse 0.919, dense 0.961: issue 16's 0.9 in each condition, flagged
    vehicles at the median (the previous preset, mu 142 m: 0.926 / 0.971 / 0.926 / 0.970).
    The sparse conditions flag 20.2% (Krauss) and 21.2% (IDM) of SUMO's vehicles, many of
    them cars never within mu of another (the previous preset: 11.6% and 13.4%); the dense
    ones 1-1.5%. That is above the 10% bgap's own traffic is held to (0% flagged there) and
    it grew with the re-search, whose objective counts the flagged share on its search data
    only; this test allows 25%, so that a preset flagging more still fails."""
    from bgap.cmetric import score_trajectories
    from bgap.cmetric.params import CMetricConfig
    from bgap.cmetric.score import label_auc
    from bgap.common.presets import load_preset, preset_path

    tuned = load_preset(CMetricConfig, preset_path("cmetric", "tuned"))
    table = record(SumoConfig(car_following=car_following, flow=flow), episodes=10, seed=100)
    vehicles = score_trajectories(table, tuned).vehicles
    vehicles = vehicles[vehicles.label != "ego"]
    assert label_auc(vehicles) >= floor
    assert vehicles.flagged.mean() <= 0.25
