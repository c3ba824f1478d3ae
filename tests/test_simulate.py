"""Trajectory recording and the `python -m bgap.simulate` command."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pandas as pd

from bgap.datasets.simulate import simulate
from bgap.sim.recorder import COLUMNS
from tests.conftest import make_cfg


def test_recording_has_every_frame_of_every_vehicle():
    cfg = make_cfg("env=sparse", "env.duration=4", "mix=0.4")
    table = simulate(cfg, episodes=2, progress=False)
    assert list(table.columns) == COLUMNS
    frames = 4 * 15 + 1  # reset frame + 15 Hz for 4 s (unless the ego crashed)
    per = table.groupby(["episode", "vehicle_id"]).size()
    assert per.max() == frames and len(per) == 2 * 6
    assert set(table.label) == {"ego", "aggressive", "conservative"}
    assert table.is_ego.sum() == table.groupby("episode").frame.nunique().sum()
    np.testing.assert_allclose(table.time, table.frame / 15.0)
    # velocity integrates position: finite differences agree with recorded vx
    one = table[(table.episode == 0) & (table.vehicle_id == 1)].sort_values("frame")
    dx = np.diff(one.x.to_numpy()) * 15.0
    np.testing.assert_allclose(dx, one.vx.to_numpy()[1:], rtol=0.05, atol=0.2)


def test_simulate_command_writes_dataset_config_and_gif(tmp_path):
    out = tmp_path / "run"
    cmd = [
        sys.executable,
        "-m",
        "bgap.simulate",
        "env=sparse",
        "mix=0.6",
        "episodes=1",
        "env.duration=3",
        "render=true",
        f"out={out}",
    ]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    table = pd.read_parquet(out / "trajectories.parquet")
    assert (table[~table.is_ego].groupby("vehicle_id").label.first() == "aggressive").sum() == 3
    assert "mix: 0.6" in (out / "config.yaml").read_text()
    assert "bgap.simulate" in (out / "command.txt").read_text()
    import imageio.v2 as imageio

    frames = imageio.mimread(out / "episode0.gif")
    assert len(frames) > 5 and np.asarray(frames[0]).mean() > 10  # drawn, not black


def test_simulate_command_rejects_bad_mix(tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "bgap.simulate", "mix=1.5", f"out={tmp_path}"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode != 0
    assert "mix=1.5 is invalid" in done.stderr


def test_the_first_picture_shows_every_vehicle_of_a_dense_scene():
    """The GIF's first frame, drawn by highway-env: one blob of the class colour per vehicle
    (highway-env's own view shows about 4 of 40)."""
    from scipy import ndimage

    from bgap.common.vocab import AGGRESSIVE, COLORS, CONSERVATIVE, EGO
    from bgap.datasets.simulate import record

    cfg = make_cfg("env=dense", "env.duration=1", "mix=0.5", "backend=highway")
    result = record(cfg, episodes=1, progress=False, render=True)
    image = np.asarray(result.images[0], dtype=int)
    first = result.trajectories[result.trajectories.frame == 0]
    for label, count in ((AGGRESSIVE, 20), (CONSERVATIVE, 20), (EGO, 1)):
        assert (first.label == label).sum() == count
        mask = (np.abs(image - np.array(COLORS[label])) < 40).all(axis=-1)
        _, blobs = ndimage.label(mask)
        assert blobs == count, (label, blobs)
