"""Reading tables (CSV, Parquet) that users and earlier runs wrote: a damaged file is one
line naming the file and the fix (:class:`~bgap.common.errors.TrajectoryError`), never a
traceback. Every command that reads a table reads it here."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

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
        return read_csv(path)
    return _guarded(path, "Parquet", lambda: pd.read_parquet(path))


def read_csv(path: Path, **kwargs: Any) -> pd.DataFrame:
    """``pd.read_csv(path, **kwargs)`` with a damaged file as one :class:`TrajectoryError`
    (empty, not UTF-8, ragged rows): every command that reads a CSV table reads it here."""
    return _guarded(path, "CSV", lambda: pd.read_csv(path, **kwargs))


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
