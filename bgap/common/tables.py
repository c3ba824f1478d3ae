"""Reading tables (CSV, Parquet) that users and earlier runs wrote: a damaged file is one
line naming the file and the fix (:class:`~bgap.common.errors.TrajectoryError`), never a
traceback. Every command that reads a table reads it here, and every trajectory table
through :func:`load_trajectories`.

A trajectory table is tidy: one row per vehicle and frame. Columns (aliases in brackets):

- ``vehicle_id`` [``id``, ``track_id``]: vehicle identity within a scene;
- ``frame`` and/or ``time`` [``t``]: at least one; frames are derived from sorted unique
  times when absent, times from frames at ``fps`` when absent;
- ``x``, ``y``: position [m];
- optional ``vx``, ``vy`` [m/s]: finite differences of position per vehicle when absent;
- optional ``episode`` [``scene``]: independent scenes (graphs never join two scenes); a
  table with both columns is read by ``episode`` (``scene`` is then ignored);
- optional ``label``: ground-truth class, carried through to the scores.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from bgap.common.errors import TrajectoryError


def read_table(source: str | Path | pd.DataFrame) -> pd.DataFrame:
    """A DataFrame, or a ``.csv`` / ``.parquet`` file."""
    if isinstance(source, pd.DataFrame):
        return source.copy()
    path = Path(source)
    if not path.exists():
        raise TrajectoryError(f"{path}: no such file")
    if path.is_dir():
        raise TrajectoryError(f"{path} is a folder; give a .csv or .parquet file")
    suffix = path.suffix.lower()
    if suffix not in (".parquet", ".pq", ".csv"):
        raise TrajectoryError(f"{path}: unknown format {path.suffix!r}; use .csv or .parquet")
    if suffix == ".csv":
        return read_csv(path, sep=_separator(path))
    return _guarded(path, "Parquet", lambda: pd.read_parquet(path))


def read_csv(path: Path, **kwargs: Any) -> pd.DataFrame:
    """``pd.read_csv(path, **kwargs)`` with a damaged file as one :class:`TrajectoryError`
    (empty, not UTF-8, ragged rows): every command that reads a CSV table reads it here."""
    return _guarded(path, "CSV", lambda: pd.read_csv(path, **kwargs))


def _separator(path: Path) -> str:
    """The CSV's field separator: ``;`` where its header has semicolons and no comma (SUMO's
    ``xml2csv.py`` writes its FCD export so), else ``,``."""
    try:
        with path.open(encoding="utf-8") as f:
            header = f.readline()
    except (OSError, UnicodeDecodeError):
        return ","  # the read itself says what is wrong
    return ";" if ";" in header and "," not in header else ","


def _guarded(path: Path, kind: str, read: Callable[[], pd.DataFrame]) -> pd.DataFrame:
    try:
        return read()
    except pd.errors.EmptyDataError:
        message = f"{path} is empty; a table needs a header and rows"
        raise TrajectoryError(message) from None
    except UnicodeDecodeError as err:
        raise TrajectoryError(
            f"{path} is not UTF-8 text (byte {err.object[err.start : err.start + 1]!r} at "
            f"offset {err.start}); save it as UTF-8 CSV"
        ) from None
    except pd.errors.ParserError as err:
        raise TrajectoryError(
            f"{path} is not a well-formed CSV table ({str(err).strip()}); every row needs "
            "the header's number of fields"
        ) from None
    except (OSError, ValueError) as err:  # pyarrow's ArrowInvalid is a ValueError
        raise TrajectoryError(
            f"{path} cannot be read as {kind} ({type(err).__name__}: "
            f"{str(err).splitlines()[0][:120]}); the file is truncated or of another format"
        ) from None


# ---------------------------------------------------------------- trajectory tables
ALIASES = {
    "id": "vehicle_id",
    "track_id": "vehicle_id",
    "t": "time",
    "scene": "episode",
    # SUMO's floating car data as xml2csv.py writes it (fcd-output; its vehicle_speed and
    # vehicle_angle stay extra columns: velocities come from the positions)
    "timestep_time": "time",
    "vehicle_x": "x",
    "vehicle_y": "y",
}
"""Other tools' column names for bgap's."""


def load_trajectories(
    source: str | Path | pd.DataFrame, fps: float = 15.0, extra: tuple[str, ...] = ()
) -> pd.DataFrame:
    """Read, validate and complete a trajectory table.

    Returns a copy with columns ``episode, frame, time, vehicle_id, x, y, vx, vy`` (plus
    ``label`` and the ``extra`` columns when given), sorted by episode, vehicle and frame.

    Raises :class:`TrajectoryError` for missing columns, NaN or infinite values, duplicate
    (episode, frame, vehicle) rows, or a time that does not increase with the frame.
    Vehicles entering and leaving the scene are normal.
    """
    df = read_table(source)
    if "episode" in df.columns and "scene" in df.columns:
        df = df.drop(columns="scene")  # documented precedence: episode
    df = _standard_columns(df)
    if "episode" not in df.columns:
        df["episode"] = 0
    numeric = [c for c in ("frame", "time", "x", "y", "vx", "vy") if c in df.columns]
    for col in numeric:
        values = pd.to_numeric(df[col], errors="coerce").to_numpy(dtype=float)
        bad = ~np.isfinite(values)
        if bad.any():
            rows = np.flatnonzero(bad)[:5].tolist()
            raise TrajectoryError(
                f"column {col!r} has {int(bad.sum())} NaN, infinite or non-numeric value(s) "
                f"(first rows {rows}); drop or interpolate them before scoring"
            )
        df[col] = values
    if "frame" not in df.columns:
        _refuse_own_clocks(df)
        times = np.unique(df["time"].to_numpy())
        df["frame"] = np.searchsorted(times, df["time"].to_numpy())
    if "time" not in df.columns:
        df["time"] = df["frame"] / fps
    df["frame"] = df["frame"].astype(np.int64)

    dup = df.duplicated(["episode", "frame", "vehicle_id"])
    if dup.any():
        first = df.loc[dup, ["episode", "frame", "vehicle_id"]].iloc[0].to_dict()
        raise TrajectoryError(
            f"{int(dup.sum())} duplicate (episode, frame, vehicle_id) row(s), first {first}; "
            "each vehicle may appear once per frame"
        )
    df = df.sort_values(["episode", "frame", "vehicle_id"], kind="stable")
    per_frame = df.groupby(["episode", "frame"], sort=True)["time"]
    if (per_frame.nunique() > 1).any():
        raise TrajectoryError("rows of one frame carry different times; one time per frame")
    frame_time = per_frame.first()
    steps = frame_time.groupby(level=0).diff().dropna()
    if (steps <= 0).any():
        where = steps[steps <= 0].index[0]
        raise TrajectoryError(
            f"time is not increasing with frame (episode {where[0]}, frame {where[1]}); "
            "sort the log or fix its clock"
        )

    if df.empty:
        raise TrajectoryError("trajectory table has no rows")
    df = df.sort_values(["episode", "vehicle_id", "frame"], kind="stable").reset_index(drop=True)
    if "vx" not in df.columns or "vy" not in df.columns:
        df["vx"], df["vy"] = finite_difference_velocity(df)
    else:
        _refuse_inconsistent_velocity(df)
    keep = ["episode", "frame", "time", "vehicle_id", "x", "y", "vx", "vy"]
    keep += [c for c in ("label", *extra) if c in df.columns]
    return df[keep]


def _standard_columns(df: pd.DataFrame) -> pd.DataFrame:
    """``df`` with its aliases renamed to the standard names (:data:`ALIASES`); refused where
    a column is given twice or a needed one is missing."""
    df = df.rename(columns=lambda c: ALIASES.get(str(c), str(c)))
    if df.columns.duplicated().any():
        twice = sorted(set(df.columns[df.columns.duplicated()]))
        raise TrajectoryError(
            f"columns {twice} are given twice (under their name and an alias, "
            f"{ALIASES}); keep one of each"
        )
    missing = [c for c in ("vehicle_id", "x", "y") if c not in df.columns]
    if "frame" not in df.columns and "time" not in df.columns:
        missing.append("frame or time")
    if missing:
        raise TrajectoryError(
            f"trajectory table is missing column(s) {missing}; found {list(df.columns)}. "
            "Needed: vehicle_id, frame or time, x, y (optional vx, vy, episode, label)"
        )
    return df


def _refuse_own_clocks(df: pd.DataFrame) -> None:
    """Refuse a log whose vehicles keep their own clocks (sampled at one rate, each with its
    own offset): frames made from its times would each hold one vehicle, and no traffic
    graph would ever join two. Resampling would invent positions; the fix is the user's."""
    step = df.groupby(["episode", "vehicle_id"])["time"].diff().median()
    if not np.isfinite(step) or step <= 0:
        return
    # each vehicle's offset within a step, as a circular mean (times k * step in floating
    # point fall just under or over a step: phases near 1 and near 0 are one clock)
    turn = np.exp(2j * np.pi * df["time"].to_numpy() / step)
    keys = [df["episode"].to_numpy(), df["vehicle_id"].to_numpy()]
    mean = pd.Series(turn).groupby(keys).mean().to_numpy()
    offsets = np.sort(np.mod(np.angle(mean) / (2 * np.pi), 1.0))
    # on the circle of one step (0.0 and 0.99 are the same clock): the arc that holds every
    # vehicle's offset is one step less the widest gap between neighbouring offsets
    gaps = np.diff(np.append(offsets, offsets[0] + 1.0))
    spread = 1.0 - gaps.max()
    if spread > 0.05:  # more than 5% of a step apart
        raise TrajectoryError(
            f"the vehicles keep their own clocks: sampled every {step:g} s, at offsets up to "
            f"{spread * step:.3g} s apart, so no two share a time; "
            "resample every vehicle to common times (e.g. interpolate at t = k * step) or "
            "give a frame column"
        )


VELOCITY_RATIO = (0.5, 2.0)
"""The table's typical ``|vx|`` over its positions' typical rate of change (medians over the
rows where a vehicle moves faster than 1 m/s) must lie within this range: wide enough for
sensor noise and smoothing (highD, NGSIM, SUMO's FCD and bgap's own tables lie within 2%),
narrow enough to catch km/h (3.6), feet per second read as metres (3.3) and broken values."""


def _refuse_inconsistent_velocity(df: pd.DataFrame) -> None:
    """Refuse a table whose ``vx`` does not describe its positions' motion: another unit, a
    flipped sign, or a clock that runs backwards (positions then move against ``vx``)."""
    fd, _ = finite_difference_velocity(df)
    vx = df["vx"].to_numpy()
    moving = np.abs(fd) > 1.0
    if moving.sum() < 10:
        return  # parked or too short to tell
    if np.median(np.sign(vx[moving]) * np.sign(fd[moving])) < 0:
        raise TrajectoryError(
            "vx points against the motion of x (the positions move the other way): the clock "
            "may run backwards or vx has the wrong sign; fix the time column or negate vx"
        )
    ratio = float(np.median(np.abs(vx[moving])) / np.median(np.abs(fd[moving])))
    low, high = VELOCITY_RATIO
    if not low <= ratio <= high:
        hint = (
            "vx looks like km/h: divide it by 3.6"
            if 3.0 <= ratio <= 4.2
            else ("give vx in m/s, or drop vx and vy to have them computed from the positions")
        )
        raise TrajectoryError(
            f"vx is {ratio:.3g} x the speed its positions change at (x in metres, time in "
            f"seconds; allowed {low:g}-{high:g} x): {hint}"
        )


def finite_difference_velocity(df: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Central differences inside each vehicle's track, one-sided at its ends (np.gradient)."""
    vx = np.zeros(len(df))
    vy = np.zeros(len(df))
    for _, idx in df.groupby(["episode", "vehicle_id"], sort=False).indices.items():
        if len(idx) < 2:
            continue
        t = df["time"].to_numpy()[idx]
        vx[idx] = np.gradient(df["x"].to_numpy()[idx], t)
        vy[idx] = np.gradient(df["y"].to_numpy()[idx], t)
    return vx, vy
