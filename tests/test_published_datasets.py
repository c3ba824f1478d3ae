"""The highD and NGSIM readers, on small files written by hand in those formats (the
datasets' own documentation: column names, units, coordinate frames), with the converted
positions, speeds, lanes and scenes computed by hand."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from bgap.cmetric.io import TrajectoryError, load_trajectories
from bgap.sim.recorder import COLUMNS

FPS = 25


def _highd(folder, prefix="01"):
    """One recording: on the lower carriageway (direction 2, moving +x in image coordinates)
    a car in lane area 5 (centre y 20 m) and a truck in lane area 6 (y 24 m); on the upper one
    (direction 1, moving -x) a car in lane area 3 (y 8 m, next to the median) and a car in
    lane area 2 (y 4 m). Five frames from 1; boxes 5 m x 2 m (trucks 15 m)."""
    rows = []
    for vid, lane_area, y_centre, vx, x0, length in (
        (1, 5, 20.0, 30.0, 100.0, 5.0),
        (2, 6, 24.0, 22.0, 60.0, 15.0),
        (3, 3, 8.0, -33.0, 300.0, 5.0),
        (4, 2, 4.0, -25.0, 250.0, 5.0),
    ):
        for frame in range(1, 6):
            centre = x0 + vx * (frame - 1) / FPS
            rows.append(
                dict(frame=frame, id=vid, x=centre - length / 2, y=y_centre - 1.0, width=length,
                     height=2.0, xVelocity=vx, yVelocity=0.0, xAcceleration=0.0, laneId=lane_area)
            )  # fmt: skip
    pd.DataFrame(rows).to_csv(folder / f"{prefix}_tracks.csv", index=False)
    pd.DataFrame(
        dict(id=[1, 2, 3, 4], width=[5.0, 15, 5, 5], height=2.0, numFrames=5,
             **{"class": ["Car", "Truck", "Car", "Car"]}, drivingDirection=[2, 2, 1, 1])
    ).to_csv(folder / f"{prefix}_tracksMeta.csv", index=False)  # fmt: skip
    pd.DataFrame(dict(id=[1], frameRate=[FPS], speedLimit=[-1.0])).to_csv(
        folder / f"{prefix}_recordingMeta.csv", index=False
    )


def test_highd_recording_becomes_two_scenes_in_bgaps_frame(tmp_path):
    from bgap.datasets import highd

    _highd(tmp_path)
    table = highd.read(tmp_path / "01_tracks.csv")
    assert list(table.columns) == COLUMNS
    load_trajectories(table)  # CMetric reads it as is
    first = table[table.frame == 0].set_index("vehicle_id")
    # a scene per carriageway: direction 1 -> episode 0, direction 2 -> episode 1
    assert first.episode.to_dict() == {1: 1, 2: 1, 3: 0, 4: 0}
    # box centres; direction 1 turned by 180 degrees: it moves towards +x too
    assert first.loc[1, ["x", "y", "vx"]].tolist() == pytest.approx([100.0, 20.0, 30.0])
    assert first.loc[3, ["x", "y", "vx"]].tolist() == pytest.approx([-300.0, -8.0, 33.0])
    assert (table.vx > 0).all() and table.speed.tolist() == pytest.approx(table.vx.tolist())
    # lanes from the driver's left: the lane next to the median on the upper carriageway
    assert first.lane.to_dict() == {1: 0, 2: 1, 3: 0, 4: 1}
    last = table[table.vehicle_id == 1].iloc[-1]
    assert last.frame == 4 and last.time == pytest.approx(4 / FPS)
    assert last.x == pytest.approx(100.0 + 30.0 * 4 / FPS)
    assert first.label.to_dict() == {1: "car", 2: "truck", 3: "car", 4: "car"}


def test_highd_folder_reads_every_recording_and_defects_are_one_line_errors(tmp_path):
    from bgap.datasets import highd

    _highd(tmp_path, "01")
    _highd(tmp_path, "02")
    table = highd.read(tmp_path)
    assert sorted(table.episode.unique()) == [0, 1, 2, 3]
    (tmp_path / "02_tracksMeta.csv").unlink()
    with pytest.raises(TrajectoryError, match="02_tracksMeta.csv: no such file"):
        highd.read(tmp_path)
    with pytest.raises(TrajectoryError, match="not a highD tracks file"):
        highd.read(tmp_path / "01_recordingMeta.csv")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(TrajectoryError, match="no highD recording"):
        highd.read(empty)


def _ngsim_rows():
    """Two locations; at us-101 a car in Lane_ID 1 (leftmost) moving 3 ft per frame (30 ft/s)
    and drifting 0.5 ft per frame to the right, and a truck in Lane_ID 2; one row repeated."""
    rows = []
    for location, vid, cls, lane, x0, dx, dy in (
        ("us-101", 7, 2, 1, 6.0, 3.0, 0.5),
        ("us-101", 9, 3, 2, 18.0, 2.0, 0.0),
        ("i-80", 7, 2, 3, 30.0, 4.0, 0.0),
    ):
        for k in range(4):
            rows.append(
                dict(Vehicle_ID=vid, Frame_ID=100 + k, Total_Frames=4, Global_Time=0,
                     Local_X=x0 + dy * k, Local_Y=50.0 + dx * k, Global_X=0, Global_Y=0,
                     v_Length=15, v_Width=6, v_Class=cls, v_Vel=dx * 10, v_Acc=0,
                     Lane_ID=lane, Preceding=0, Following=0, Space_Headway=0,
                     Time_Headway=0, Location=location)
            )  # fmt: skip
    return pd.DataFrame(rows + rows[:1])


def test_ngsim_file_in_metres_scenes_per_location(tmp_path):
    from bgap.datasets import ngsim

    path = tmp_path / "trajectories.csv"
    _ngsim_rows().to_csv(path, index=False)
    table = ngsim.read(path)
    assert list(table.columns) == COLUMNS and len(table) == 12  # the repeated row once
    load_trajectories(table)
    car = table[(table.episode == 1) & (table.vehicle_id == 7)]  # i-80 < us-101: episode 1
    assert car.x.tolist() == pytest.approx([0.3048 * (50.0 + 3.0 * k) for k in range(4)])
    assert car.y.iloc[0] == pytest.approx(0.3048 * 6.0)
    assert car.vx.tolist() == pytest.approx([30 * 0.3048] * 4)  # 3 ft per 0.1 s
    assert car.vy.tolist() == pytest.approx([5 * 0.3048] * 4)
    assert car.time.tolist() == pytest.approx([0.0, 0.1, 0.2, 0.3])
    assert car.lane.iloc[0] == 0 and car.label.iloc[0] == "car"
    truck = table[(table.episode == 1) & (table.vehicle_id == 9)]
    assert truck.label.iloc[0] == "truck" and truck.lane.iloc[0] == 1
    # the original release's whitespace-separated .txt, no header: the same table
    txt = tmp_path / "trajectories.txt"
    rows = _ngsim_rows().drop(columns="Location")
    rows[rows.index < 8].to_csv(txt, sep=" ", header=False, index=False)
    plain = ngsim.read(txt)
    assert plain.x.tolist() == pytest.approx(table[table.episode == 1].x.tolist())
    with pytest.raises(TrajectoryError, match=r"missing NGSIM column\(s\) \['Lane_ID'\]"):
        _ngsim_rows().drop(columns="Lane_ID").to_csv(path, index=False)
        ngsim.read(path)


def test_command_converts_a_highd_folder_and_needs_a_path(tmp_path):
    _highd(tmp_path)

    def datasets(*args):
        return subprocess.run(
            [sys.executable, "-m", "bgap.datasets", *args],
            capture_output=True,
            text=True,
            timeout=300,
        )

    done = datasets("highd", str(tmp_path), f"out={tmp_path / 'out'}")
    assert done.returncode == 0, done.stderr
    written = pd.read_parquet(tmp_path / "out" / "trajectories.parquet")
    assert len(written) == 20 and written.episode.nunique() == 2
    import yaml
    from omegaconf import OmegaConf

    from bgap.common.config import compose
    from bgap.datasets.config import SCHEMAS

    composed = compose("datasets", ["source=highd", f"path={tmp_path}", f"out={tmp_path / 'out'}"],
                       SCHEMAS)  # fmt: skip
    saved = yaml.safe_load((tmp_path / "out" / "config.yaml").read_text())
    assert saved == OmegaConf.to_container(composed, resolve=True)  # the config it used
    assert "2 scenes" in done.stdout
    bad = datasets("ngsim", f"out={tmp_path / 'bad'}")
    assert bad.returncode == 2 and "path=None is invalid" in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1 and not (tmp_path / "bad").exists()
    assert np.isfinite(written[["x", "y", "vx", "vy"]].to_numpy()).all()


def test_highd_classes_coded_as_numbers_are_read_as_text(tmp_path):
    """A tracksMeta file whose class column holds codes (1, 2) instead of Car/Truck, as
    some exports write it: the labels are the codes as text, not an AttributeError."""
    from bgap.datasets import highd

    _highd(tmp_path)
    meta = pd.read_csv(tmp_path / "01_tracksMeta.csv")
    meta["class"] = [1, 2, 1, 1]
    meta.to_csv(tmp_path / "01_tracksMeta.csv", index=False)
    table = highd.read(tmp_path / "01_tracks.csv")
    first = table[table.frame == 0].set_index("vehicle_id")
    assert first.label.to_dict() == {1: "1", 2: "2", 3: "1", 4: "1"}


def test_sumo_fcd_as_xml2csv_writes_it_reads_and_scores(tmp_path):
    """SUMO's floating car data (``--fcd-output``) converted by its ``xml2csv.py``: fields
    separated by semicolons, columns prefixed by their XML element, vehicles named by
    strings, 0.1-s time steps, speed and angle (not velocity components). Read as the same
    table in bgap's names, with velocities from the positions, and scored the same."""
    from bgap.cmetric import score_trajectories

    rows = []
    for vid, y, speed, x0 in (("flow0.0", -1.6, 30.0, 0.0), ("flow0.1", -4.8, 25.0, 20.0),
                              ("veh7", -1.6, 28.0, 50.0)):  # fmt: skip
        for k in range(40):  # 4 s
            rows.append({"timestep_time": round(0.1 * k, 2), "vehicle_angle": 90.0,
                         "vehicle_id": vid, "vehicle_lane": f"E0_{int(y < -3)}",
                         "vehicle_pos": x0 + speed * 0.1 * k, "vehicle_slope": 0.0,
                         "vehicle_speed": speed, "vehicle_type": "DEFAULT_VEHTYPE",
                         "vehicle_x": x0 + speed * 0.1 * k, "vehicle_y": y})  # fmt: skip
    fcd = pd.DataFrame(rows)
    fcd.to_csv(tmp_path / "fcd.csv", sep=";", index=False)
    ours = fcd.rename(columns={"timestep_time": "time", "vehicle_x": "x", "vehicle_y": "y"})
    ours = ours[["time", "vehicle_id", "x", "y"]]
    read = load_trajectories(tmp_path / "fcd.csv", fps=10)
    same = load_trajectories(ours, fps=10)
    pd.testing.assert_frame_equal(read[same.columns], same)
    by_vehicle = read.groupby("vehicle_id").vx.median()
    assert by_vehicle.to_dict() == pytest.approx({"flow0.0": 30.0, "flow0.1": 25.0, "veh7": 28.0})
    scores = score_trajectories(tmp_path / "fcd.csv", fps=10).vehicles
    pd.testing.assert_frame_equal(scores, score_trajectories(ours, fps=10).vehicles)
    assert sorted(scores.vehicle_id) == ["flow0.0", "flow0.1", "veh7"]
