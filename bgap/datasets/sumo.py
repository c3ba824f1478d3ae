"""Labelled trajectories from a second simulator: SUMO on a straight multi-lane highway.

Data bgap never generated, for validating CMetric (it validates, it never tunes: the
driver types below were fixed before any search ran) and for calibrating to traffic that
is not bgap's own. SUMO is an optional extra (``pip install -e ".[sumo]"``: the
``eclipse-sumo`` and ``libsumo`` wheels); it runs headless in-process through libsumo.

The scene: one straight edge of ``lanes`` lanes and ``length`` metres at ``speed_limit``.
Two flows, aggressive and conservative drivers in the share ``mix``, enter at its start
for ``warmup`` seconds; then one ego car (SUMO's default driver) is inserted at
``ego_position`` and every vehicle is recorded every step for ``duration`` seconds into
bgap's trajectory table (:mod:`bgap.sim.recorder`'s columns; ``x`` along the road, ``y``
across it, lanes changed over ``lane_change_duration`` seconds instead of SUMO's default
instant jump). SUMO's clock counts milliseconds, so the step is 1/``fps`` rounded to
the millisecond (15 Hz: 0.067 s) and the table's ``time`` is SUMO's own. Each episode is a
new SUMO run with its own seed.

The driver types are SUMO's own parameters (sumo.dlr.de, "Vehicle Type Parameter Defaults"
and "Lane-Changing Models"): speed factor (desired speed over the limit), tau (desired time
headway), accel / decel, minGap, sigma (driver imperfection), and the LC2013 lane-change
model's eagerness for speed gain, assertiveness, cooperativeness and keep-right.
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from bgap.common.errors import ConfigError, check
from bgap.sim.recorder import COLUMNS

CAR_FOLLOWING = ("Krauss", "IDM")


@dataclass
class SumoDriver:
    """One driver type, in SUMO's own parameters."""

    speed_factor: float = 1.0
    speed_dev: float = 0.1
    tau: float = 1.0
    accel: float = 2.6
    decel: float = 4.5
    min_gap: float = 2.5
    sigma: float = 0.5
    lc_speed_gain: float = 1.0
    lc_assertive: float = 1.0
    lc_cooperative: float = 1.0
    lc_keep_right: float = 1.0

    def __post_init__(self) -> None:
        # SUMO's own ranges (its vType documentation): it would reject these at start-up,
        # after the output folder was made, with a message in SUMO's terms
        for key in ("speed_factor", "tau", "accel", "decel"):
            check(getattr(self, key) > 0, key, getattr(self, key), "must be > 0")
        for key in ("speed_dev", "min_gap", "lc_speed_gain", "lc_cooperative", "lc_keep_right"):
            check(getattr(self, key) >= 0, key, getattr(self, key), "must be >= 0")
        check(0 <= self.sigma <= 1, "sigma", self.sigma, "must lie in [0, 1] (driver imperfection)")
        check(self.lc_assertive > 0, "lc_assertive", self.lc_assertive, "must be > 0")

    def vtype(self, name: str, car_following: str) -> str:
        return (
            f'<vType id="{name}" carFollowModel="{car_following}" '
            f'speedFactor="{self.speed_factor}" speedDev="{self.speed_dev}" tau="{self.tau}" '
            f'accel="{self.accel}" decel="{self.decel}" minGap="{self.min_gap}" '
            f'sigma="{self.sigma}" lcSpeedGain="{self.lc_speed_gain}" '
            f'lcAssertive="{self.lc_assertive}" lcCooperative="{self.lc_cooperative}" '
            f'lcKeepRight="{self.lc_keep_right}"/>'
        )


@dataclass
class SumoConfig:
    """The SUMO scene and its two driver types (defaults: our fixed validation types)."""

    lanes: int = 4
    length: float = 5000.0
    speed_limit: float = 30.0
    flow: float = 0.3
    """Vehicles per second entering the road, all lanes together (each class's flow is a
    per-second insertion probability in SUMO, so at most 1)."""
    mix: float = 0.5
    """Share of aggressive drivers in the flow."""
    car_following: str = "Krauss"
    warmup: float = 150.0
    duration: float = 60.0
    fps: float = 15.0
    lane_change_duration: float = 3.0
    ego_position: float = 2000.0
    aggressive: SumoDriver = field(
        default_factory=lambda: SumoDriver(
            speed_factor=1.3,
            speed_dev=0.1,
            tau=0.6,
            accel=3.5,
            decel=6.0,
            min_gap=1.5,
            sigma=0.5,
            lc_speed_gain=5.0,
            lc_assertive=3.0,
            lc_cooperative=0.2,
            lc_keep_right=0.2,
        )
    )
    conservative: SumoDriver = field(
        default_factory=lambda: SumoDriver(
            speed_factor=0.85,
            speed_dev=0.05,
            tau=1.8,
            accel=1.5,
            decel=3.0,
            min_gap=3.0,
            sigma=0.2,
            lc_speed_gain=0.3,
            lc_assertive=0.8,
            lc_cooperative=1.0,
            lc_keep_right=3.0,
        )
    )

    def __post_init__(self) -> None:
        check(self.lanes >= 1, "sumo.lanes", self.lanes, "must be >= 1")
        check(0 < self.flow <= 1, "sumo.flow", self.flow, "must be in (0, 1] vehicles per second")
        check(0 <= self.mix <= 1, "sumo.mix", self.mix, "must be in [0, 1]")
        check(
            self.car_following in CAR_FOLLOWING,
            "sumo.car_following",
            self.car_following,
            f"use one of {CAR_FOLLOWING}",
        )
        check(
            0 < self.ego_position < self.length,
            "sumo.ego_position",
            self.ego_position,
            "must lie on the road",
        )
        for key in ("length", "speed_limit", "duration", "fps", "warmup"):
            check(getattr(self, key) > 0, f"sumo.{key}", getattr(self, key), "must be > 0")


def sumo_home() -> Path:
    """SUMO's installation (the ``eclipse-sumo`` wheel); a clear error without it."""
    try:
        # Imported here: SUMO is an optional extra (pip install -e '.[sumo]').
        import sumo
    except ImportError:
        raise ConfigError(
            "source=sumo needs SUMO: pip install -e '.[sumo]' (eclipse-sumo and libsumo)"
        ) from None
    return Path(sumo.SUMO_HOME)


def _network(folder: Path, cfg: SumoConfig) -> Path:
    """A straight edge a -> b, built with SUMO's netconvert."""
    (folder / "n.nod.xml").write_text(
        f'<nodes><node id="a" x="0" y="0"/><node id="b" x="{cfg.length}" y="0"/></nodes>'
    )
    (folder / "e.edg.xml").write_text(
        f'<edges><edge id="ab" from="a" to="b" numLanes="{cfg.lanes}" '
        f'speed="{cfg.speed_limit}"/></edges>'
    )
    net = folder / "net.xml"
    subprocess.run(
        [
            str(sumo_home() / "bin" / "netconvert"),
            "-n",
            str(folder / "n.nod.xml"),
            "-e",
            str(folder / "e.edg.xml"),
            "-o",
            str(net),
            "--no-turnarounds",
        ],
        check=True,
        capture_output=True,
    )
    return net


def _routes(folder: Path, cfg: SumoConfig) -> Path:
    """The two driver types, the ego's type, and one flow per class."""
    flows = []
    for label, share in (("aggressive", cfg.mix), ("conservative", 1 - cfg.mix)):
        if share > 0:
            flows.append(
                f'<flow id="{label}" type="{label}" route="r" begin="0" end="1e9" '
                f'probability="{cfg.flow * share}" '
                'departLane="random" departSpeed="desired"/>'
            )
    routes = folder / "r.rou.xml"
    routes.write_text(
        "<routes>"
        + cfg.aggressive.vtype("aggressive", cfg.car_following)
        + cfg.conservative.vtype("conservative", cfg.car_following)
        + f'<vType id="ego" carFollowModel="{cfg.car_following}"/>'
        + '<route id="r" edges="ab"/>'
        + "".join(flows)
        + "</routes>"
    )
    return routes


def _sumo_command(cfg: SumoConfig, net: Path, routes: Path, dt: float, seed: int) -> list[str]:
    """SUMO's command line: the road, the flows, the step, the seed and the lane changes."""
    options = {
        "-n": net,
        "-r": routes,
        "--step-length": dt,
        "--seed": seed,
        "--lanechange.duration": cfg.lane_change_duration,
        "--default.action-step-length": dt,
    }
    pairs = [text for key, value in options.items() for text in (key, str(value))]
    return ["sumo", *pairs, "--no-step-log", "--no-warnings"]


def _as_table(rows: list[tuple], times: list[float], episode: int, lanes: int) -> pd.DataFrame:
    """The recorded rows as bgap's trajectory table: the ego is vehicle 0, time from SUMO's
    clock, lanes numbered from the left."""
    table = pd.DataFrame(rows, columns=["sumo_id", "frame", "x", "y", "vx", "vy", "lane", "label"])
    ids = ["ego", *sorted(set(table.sumo_id) - {"ego"})]  # the ego is vehicle 0
    table["vehicle_id"] = table.sumo_id.map({v: i for i, v in enumerate(ids)}).astype(np.int32)
    table["episode"] = np.int32(episode)
    table["time"] = (np.asarray(times) - times[0])[table.frame]  # SUMO's clock
    table["is_ego"] = table.label == "ego"
    table["speed"] = np.hypot(table.vx, table.vy)
    # SUMO numbers lanes from the right; bgap (highway-env) from the left
    table["lane"] = (lanes - 1 - table.lane).astype(np.int16)
    table["crashed"] = False
    return table.drop(columns="sumo_id")


def record_episode(cfg: SumoConfig, seed: int, episode: int) -> pd.DataFrame:
    """One SUMO run: warm-up, the ego's insertion, ``duration`` seconds recorded."""
    # Imported here: SUMO is an optional extra (pip install -e '.[sumo]').
    import libsumo as traci

    folder = Path(tempfile.mkdtemp(prefix="bgap-sumo-"))
    try:
        net, routes = _network(folder, cfg), _routes(folder, cfg)
        dt = round(1.0 / cfg.fps, 3)  # SUMO's clock counts milliseconds: 15 Hz is 0.067 s
        traci.start(_sumo_command(cfg, net, routes, dt, seed))
        for _ in range(int(round(cfg.warmup / dt))):
            traci.simulationStep()
        traci.vehicle.add(
            "ego",
            "r",
            typeID="ego",
            depart="now",
            departLane="free",
            departPos=str(cfg.ego_position),
            departSpeed="desired",
        )
        rows, times = [], []
        frame, waited = 0, 0
        while frame < int(round(cfg.duration / dt)):
            traci.simulationStep()
            ids = traci.vehicle.getIDList()
            if "ego" not in ids:
                if frame > 0:
                    break  # the ego left the road: the episode ends
                waited += 1  # the ego waits for a gap to enter
                if waited * dt > 60.0:
                    raise RuntimeError(
                        f"SUMO seed {seed}: the ego found no gap at {cfg.ego_position} m in "
                        "60 s; lower sumo.flow or move sumo.ego_position"
                    )
                continue
            times.append(traci.simulation.getTime())
            for v in ids:
                x, y = traci.vehicle.getPosition(v)
                speed = traci.vehicle.getSpeed(v)
                rows.append(
                    (
                        v,
                        frame,
                        x,
                        y,
                        speed,
                        traci.vehicle.getLateralSpeed(v),
                        traci.vehicle.getLaneIndex(v),
                        traci.vehicle.getTypeID(v),
                    )
                )
            frame += 1
        traci.close()
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return _as_table(rows, times, episode, cfg.lanes)


def record(cfg: SumoConfig, episodes: int, seed: int, progress=None) -> pd.DataFrame:
    """``episodes`` SUMO runs with seeds ``seed + k`` (episode ``k``)."""

    parts = []
    for k in range(episodes):
        parts.append(record_episode(cfg, seed + k, k))
        if progress is not None:
            progress(1)
    return pd.concat(parts, ignore_index=True)[COLUMNS]
