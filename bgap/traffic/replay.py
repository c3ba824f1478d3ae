"""Replayed traffic: a trajectory table as the ego's surroundings.

    traffic=replay traffic.table=PATH traffic.mode=log|reactive

Any table the trajectory reader takes (:func:`bgap.common.tables.load_trajectories`) with a
``lane`` column. Its vehicles are resampled to the simulation frequency; an episode is a
window of one scene in which the ego takes the place of one recorded vehicle (removed from
the replay) at that vehicle's position and speed, and lasts while that vehicle stays in the
recorded section: at most ``env.duration``, at least ``traffic.min_duration`` (shorter
candidates are never drawn). ``log``: recorded vehicles follow their log whatever the ego
does. ``reactive``: a recorded vehicle whose leader is the ego, or a vehicle that already
switched, closer than its IDM desired gap switches to IDM for the rest of the episode
(longitudinal only, in its lane; no MOBIL), with its class's parameters (a label that is not
a bgap class: the conservative one's).

This module owns the table's preparation, shared by both backends; the simulators replay
it (:mod:`bgap.envs.highway`, the reference). Our choices, documented in docs/environment.md:
linear interpolation between recorded samples; lanes ranked by their median lateral
position and placed at highway-env's 4 m spacing (a table recorded by bgap keeps its
coordinates exactly); a window drawn per episode from the episode's seed (a vehicle among
the candidates, then its start) so every policy meets the same windows.
"""

from __future__ import annotations

import copy
import functools
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np
import pandas as pd

from bgap.common.errors import TrajectoryError, check
from bgap.common.tables import load_trajectories
from bgap.common.vocab import AGGRESSIVE, CONSERVATIVE, LABEL_NAMES
from bgap.traffic.mixture import MixtureConfig
from bgap.traffic.road import LANE_WIDTH
from bgap.traffic.scenes import split_scenes, table_name

SOURCES = ("simulated", "replay", "mixture")
MODES = ("log", "reactive")
SIDES = ("all", "train", "test")
"""Which of a table's scenes are replayed: all, or one side of the split that holds a third
out for testing (:mod:`bgap.traffic.scenes`)."""
MAX_JUMP_X, MAX_JUMP_Y = 20.0, LANE_WIDTH
"""A recorded vehicle moving more than these [m] between two samples is a broken track."""


@dataclass
class TrafficConfig:
    """Where the background traffic comes from (config group ``traffic``)."""

    name: str = "simulated"
    source: str = "simulated"
    """``simulated`` (bgap's driver classes, the default), ``replay`` (a trajectory table) or
    ``mixture`` (each episode drawn from a mixture of sources, :mod:`bgap.traffic.mixture`;
    vector backend)."""
    table: Optional[str] = None
    """``replay``: the trajectory table (.parquet or .csv, with a ``lane`` column)."""
    mode: str = "log"
    """``replay``: ``log`` (recorded vehicles ignore the ego) or ``reactive`` (they switch
    to IDM behind the ego)."""
    min_duration: float = 20.0
    """``replay``: shortest episode [s]; recorded vehicles in the section for less are never
    replaced by the ego."""
    vehicle: Optional[int] = None
    """``replay``: the recorded vehicle (``vehicle_id``) the ego replaces; null: drawn per
    episode."""
    start: Optional[float] = None
    """``replay``: the window's start [s] after the scene's first sample; null: drawn."""
    scene: Optional[int] = None
    """``replay``: the scene (``episode`` column); null: drawn with the vehicle."""
    scenes: str = "all"
    """``replay``: the scenes windows are drawn from: ``all``, or the table's ``train`` or
    ``test`` side (:mod:`bgap.traffic.scenes`: one scene in three held out for testing)."""
    mixture: Optional[MixtureConfig] = None
    """``mixture``: its weights, ranges and replay tables (null: the defaults)."""

    def __post_init__(self) -> None:
        check(self.source in SOURCES, "traffic.source", self.source, f"use one of {SOURCES}")
        if isinstance(self.mixture, dict):  # from an environment config's dictionary
            self.mixture = MixtureConfig(**self.mixture)
        if self.source == "mixture" and self.mixture is None:
            self.mixture = MixtureConfig()
        check(self.mode in MODES, "traffic.mode", self.mode, f"use one of {MODES}")
        check(self.scenes in SIDES, "traffic.scenes", self.scenes, f"use one of {SIDES}")
        check(
            self.source != "replay" or bool(self.table),
            "traffic.table",
            self.table,
            "traffic=replay needs a trajectory table: traffic.table=PATH (.parquet or .csv)",
        )
        check(
            np.isfinite(self.min_duration) and self.min_duration > 0,
            "traffic.min_duration",
            self.min_duration,
            "must be a positive number of seconds",
        )
        check(
            self.start is None or (np.isfinite(self.start) and self.start >= 0),
            "traffic.start",
            self.start,
            "must be >= 0 s or null",
        )

    def as_config(self) -> dict:
        """The environment config's ``traffic`` entry (absent for simulated traffic, so
        configs made before replay existed stay the same)."""
        if self.source == "mixture":
            mixture = asdict(self.mixture)
            return {"source": "mixture", "min_duration": self.min_duration, "mixture": mixture}
        keys = ("source", "table", "mode", "min_duration", "vehicle", "start", "scene")
        out = {k: getattr(self, k) for k in keys}
        if self.scenes != "all":  # absent at its default: configs made before it stay the same
            out["scenes"] = self.scenes
        return out


@dataclass
class RecordedScene:
    """One recorded scene resampled to the simulation frequency: ``state[k, v]`` is vehicle
    ``v``'s x, y, vx, vy at frame k (NaN while it is not in the section)."""

    number: int
    state: np.ndarray
    ids: np.ndarray
    labels: list[Optional[str]]
    present: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.present = np.isfinite(self.state[:, :, 0])

    def span(self, v: int) -> tuple[int, int]:
        """First and last frame of vehicle ``v`` (it is present in between: tracks have no
        holes after resampling)."""
        frames = np.flatnonzero(self.present[:, v])
        return int(frames[0]), int(frames[-1])


@dataclass
class Window:
    """An episode's piece of a scene: the ego replaces vehicle ``ego`` from frame ``start``
    for ``frames`` frames (the episode ends there, or earlier at ``env.duration``)."""

    scene: RecordedScene
    ego: int
    start: int
    frames: int
    index: int = 0
    """The scene's position in :attr:`Replay.scenes`."""


class Replay:
    """A trajectory table prepared for replay at ``simulation_frequency`` (module
    docstring); refuses, with one line, a table no episode can be drawn from."""

    def __init__(
        self, source: str | Path | pd.DataFrame, simulation_frequency: float, min_duration: float
    ) -> None:
        self.dt = 1.0 / float(simulation_frequency)
        self.min_frames = int(np.ceil(min_duration * simulation_frequency - 1e-9))
        name = source if isinstance(source, (str, Path)) else "the table"
        df = load_trajectories(source, fps=simulation_frequency, extra=("lane",))
        if "lane" not in df.columns:
            raise TrajectoryError(
                f"{name}: replay needs a lane column (the lane index of each row); found "
                f"{list(df.columns)}"
            )
        if df.groupby("episode").frame.nunique().max() < 2:
            raise TrajectoryError(f"{name}: every scene has a single frame; replay needs tracks")
        _refuse_jumps(df, name)
        if float(np.median(df.vx)) < 0:
            raise TrajectoryError(
                f"{name}: its vehicles drive towards -x (median vx {np.median(df.vx):.1f} m/s); "
                "mirror x and vx (and order the lanes) before replaying it"
            )
        self.lane_ranks, y = _lanes(df)
        self.lanes = len(self.lane_ranks)
        df = df.assign(y=y, x=df.x - min(0.0, float(df.x.min())))
        # scenes keep their integer ids; where scenes are named by strings (a SUMO table's
        # "dense_mix50"), every scene is numbered by its sorted order, the number
        # traffic.scene takes
        groups = _in_order(df.groupby("episode", sort=True))
        numbered = _integer_ids(groups)
        self.scenes = [self._scene(int(k) if numbered else i, g) for i, (k, g) in enumerate(groups)]
        self.candidates = [
            (s, v)
            for s, scene in enumerate(self.scenes)
            for v in range(len(scene.ids))
            if np.diff(scene.span(v))[0] >= self.min_frames
        ]
        if not self.candidates:
            raise TrajectoryError(
                f"{name}: no recorded vehicle stays {min_duration:g} s in the section (the "
                "shortest episode); lower traffic.min_duration or give a longer recording"
            )
        if max(len(scene.ids) for scene in self.scenes) < 2:
            raise TrajectoryError(f"{name}: every scene holds one vehicle; nothing to replay")

    def side(self, name: str, side: str) -> Replay:
        """A copy drawing its windows from one side (``train`` or ``test``) of the split of
        the table called ``name`` (:func:`bgap.traffic.scenes.split_scenes`); the scenes
        themselves are shared, not copied."""
        train, test = split_scenes(name, [scene.number for scene in self.scenes])
        kept = set(train if side == "train" else test)
        out = copy.copy(self)
        out.candidates = [(s, v) for s, v in self.candidates if self.scenes[s].number in kept]
        if not out.candidates:
            raise TrajectoryError(
                f"{name}: no {side} scene to replay (a table's split holds one scene in each "
                "complete block of three out: generate its scenes in multiples of three)"
            )
        return out

    def aggressive_share(self) -> Optional[float]:
        """Share of the recorded vehicles labelled aggressive among those labelled aggressive
        or conservative (each track once; the ego of a recording left out): the replay's
        ``mix``, comparable with the simulated mixes. None when the table has no such
        labels."""
        names = [
            LABEL_NAMES.get(int(x), x) if str(x).isdigit() else x
            for scene in self.scenes
            for x in scene.labels
            if x is not None
        ]
        classed = [x for x in names if x in (AGGRESSIVE, CONSERVATIVE)]
        return classed.count(AGGRESSIVE) / len(classed) if classed else None

    def most_vehicles(self, frames: int) -> int:
        """The most recorded vehicles any window of ``frames`` + 1 frames meets (the vector
        backend's slots: every vehicle in the section at some frame of an episode)."""
        most = 0
        for scene in self.scenes:
            spans = np.array([scene.span(v) for v in range(len(scene.ids))])
            begins, ends = np.sort(spans[:, 0]), np.sort(spans[:, 1])
            starts = np.arange(len(scene.state))
            count = np.searchsorted(begins, starts + frames, side="right") - np.searchsorted(
                ends, starts, side="left"
            )
            most = max(most, int(count.max()))
        return most

    def tracks(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
        """Every recorded vehicle's samples in one array, for the compiled replay: (samples
        (S, 4): x, y, vx, vy; each track's first sample, first frame and length; the track
        number of (scene index, vehicle))."""
        parts, start, first, length, number = [], [], [], [], {}
        offset = 0
        for s, scene in enumerate(self.scenes):
            for v in range(len(scene.ids)):
                a, z = scene.span(v)
                number[(s, v)] = len(start)
                parts.append(scene.state[a : z + 1, v])
                start.append(offset)
                first.append(a)
                length.append(z - a + 1)
                offset += z - a + 1
        ints = (np.asarray(x, dtype=np.int64) for x in (start, first, length))
        return (np.concatenate(parts), *ints, number)

    def _scene(self, number: int, g: pd.DataFrame) -> RecordedScene:
        t0 = float(g.time.min())
        total = int(np.floor((float(g.time.max()) - t0) / self.dt + 1e-9)) + 1
        grid = t0 + np.arange(total) * self.dt
        tracks = _in_order(g.groupby("vehicle_id", sort=True))
        state = np.full((total, len(tracks), 4), np.nan)
        labels: list[Optional[str]] = []
        for v, (_, track) in enumerate(tracks):
            t = track.time.to_numpy()
            inside = (grid >= t[0] - 1e-9) & (grid <= t[-1] + 1e-9)
            for c, col in enumerate(("x", "y", "vx", "vy")):
                state[inside, v, c] = np.interp(grid[inside], t, track[col].to_numpy())
            labels.append(str(track.label.iloc[0]) if "label" in track else None)
        ids = np.array([vid for vid, _ in tracks])
        return RecordedScene(number, state, ids, labels)

    def window(
        self,
        rng: np.random.Generator,
        max_frames: int,
        vehicle: Optional[int] = None,
        start: Optional[float] = None,
        scene: Optional[int] = None,
    ) -> Window:
        """The next episode's window, drawn from ``rng`` where not fixed: a candidate vehicle
        (uniformly), then its start (uniformly among those leaving at least the shortest
        episode). ``max_frames``: the episode's longest (``env.duration``)."""
        candidates = [
            (s, v)
            for s, v in self.candidates
            if (scene is None or self.scenes[s].number == scene)
            and (vehicle is None or self.scenes[s].ids[v] == vehicle)
        ]
        if not candidates:
            raise TrajectoryError(
                f"traffic.vehicle={vehicle}, traffic.scene={scene}: no such recorded vehicle "
                f"stays {self.min_frames * self.dt:g} s in the section; leave them null to "
                "draw one"
            )
        s, v = candidates[int(rng.integers(len(candidates)))]
        first, last = self.scenes[s].span(v)
        if start is None:
            begin = first + int(rng.integers(last - first - self.min_frames + 1))
        else:
            begin = first + int(round(start / self.dt))
            if not first <= begin <= last - self.min_frames:
                raise TrajectoryError(
                    f"traffic.start={start}: vehicle {self.scenes[s].ids[v]} is in the section "
                    f"from {first * self.dt:g} s to {last * self.dt:g} s, so a window of at "
                    f"least {self.min_frames * self.dt:g} s starts at most at "
                    f"{(last - self.min_frames) * self.dt:g} s"
                )
        return Window(self.scenes[s], v, begin, min(last - begin, max_frames), s)


def _in_order(groups) -> list[tuple[object, pd.DataFrame]]:
    """A groupby's groups by id: integers in their order; ids named by strings in natural
    order, their digit runs read as numbers ("v2" before "v10"), so that a table whose ids
    are strings replays as the same table with the integers they name does."""
    groups = list(groups)
    if _integer_ids(groups):
        return groups
    return sorted(groups, key=lambda kg: _natural(kg[0]))


def _integer_ids(groups: list[tuple[object, pd.DataFrame]]) -> bool:
    return all(isinstance(k, (int, np.integer)) for k, _ in groups)


def _natural(key: object) -> list:
    parts = re.split(r"(\d+)", str(key))
    return [int(p) if i % 2 else p for i, p in enumerate(parts)]


def _refuse_jumps(df: pd.DataFrame, name: object) -> None:
    """A vehicle that moves more than a lane width sideways or 20 m along the road between
    two consecutive samples is two tracks under one id."""
    keys = ["episode", "vehicle_id"]
    dx = df.groupby(keys).x.diff().abs()
    dy = df.groupby(keys).y.diff().abs()
    bad = (dx > MAX_JUMP_X) | (dy > MAX_JUMP_Y)
    if bad.any():
        row = df[bad].iloc[0]
        raise TrajectoryError(
            f"{name}: vehicle {row.vehicle_id} (scene {row.episode}) jumps "
            f"{dx[bad].iloc[0]:.1f} m along and {dy[bad].iloc[0]:.1f} m across the road "
            f"between two samples at frame {row.frame} (at most {MAX_JUMP_X:g} and "
            f"{MAX_JUMP_Y:g} m); split or repair that track"
        )


def _lanes(df: pd.DataFrame) -> tuple[dict[int, int], np.ndarray]:
    """The table's lanes ranked by median lateral position, and every row's y on the
    simulator's road: the lane's centre at ``LANE_WIDTH * rank`` plus the row's offset from
    its lane's median, scaled by ``LANE_WIDTH`` over the median spacing of the lanes."""
    lane = pd.to_numeric(df.lane, errors="coerce")
    if lane.isna().any() or (lane != np.round(lane)).any():
        raise TrajectoryError("the lane column must hold lane indices (integers) on every row")
    lane = lane.astype(int)
    centres = df.y.groupby(lane).median().sort_values()
    ranks = {int(k): r for r, k in enumerate(centres.index)}
    on_grid = float(np.median(np.abs(df.y.to_numpy() - LANE_WIDTH * lane.to_numpy()))) < 0.5
    if on_grid and all(ranks[k] == k for k in ranks):
        return ranks, df.y.to_numpy()  # highway-env's own lanes (a bgap recording): as is
    spacing = float(np.median(np.diff(centres.to_numpy()))) if len(centres) > 1 else LANE_WIDTH
    scale = LANE_WIDTH / spacing if spacing > 0 else 1.0
    rank = lane.map(ranks).to_numpy()
    y = LANE_WIDTH * rank + (df.y.to_numpy() - centres.loc[lane].to_numpy()) * scale
    return ranks, y


@functools.lru_cache(maxsize=4)
def _cached(path: str, mtime_ns: int, size: int, frequency: float, min_duration: float) -> Replay:
    return Replay(path, frequency, min_duration)


def load_replay(
    table: str, simulation_frequency: float, min_duration: float, scenes: str = "all"
) -> Replay:
    """:class:`Replay` of the file ``table``, prepared once per version of the file (every
    environment of a batch, and every reset, shares it); ``scenes``: all of them, or one side
    of the table's split (:data:`SIDES`), whose windows alone are drawn."""
    path = Path(table)
    if not path.exists():
        raise TrajectoryError(f"traffic.table={table}: no such file")
    stat = path.stat()
    try:
        replay = _cached(
            str(path.resolve()),
            stat.st_mtime_ns,
            stat.st_size,
            float(simulation_frequency),
            float(min_duration),
        )
    except TrajectoryError as err:  # which table: a grid names several
        raise TrajectoryError(f"{table}: {err}") from None
    return replay if scenes == "all" else replay.side(table_name(table), scenes)
