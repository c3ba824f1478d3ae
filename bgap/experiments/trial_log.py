"""A study's finished trials as a small JSON file that git keeps, and back into a study.

An Optuna study lives in a database (``optuna.db`` under the run's root) that does not
outlive its machine and that the project does not commit. A search longer than a working
session (the recipe per learner: hours each) stays resumable from git by committing
its finished trials (parameters with their distributions, values, state, attributes,
intermediate values): :func:`save` writes them, :func:`restore` adds them to the same study
in a fresh database, and the search's own command then continues from there. A trial still
running when saved is not kept: it is played again. Hand-written rather than Optuna's
journal storage, which logs every operation of every trial (a file that grows with each
write, and is the database itself, not a record of results).
"""

from __future__ import annotations

import json
from datetime import datetime
from pathlib import Path
from typing import Any

import optuna
from optuna.distributions import distribution_to_json, json_to_distribution
from optuna.trial import TrialState

from bgap.common.errors import ConfigError
from bgap.common.runs import write_atomic
from bgap.common.studies import open_storage

KEPT = (TrialState.COMPLETE, TrialState.PRUNED, TrialState.FAIL)
"""The trial states a log keeps: those that will not change any more."""


def storage_url(storage: str | Path) -> str:
    """A storage URL as the commands take them (:mod:`bgap.common.studies`), or the path of
    an SQLite file (``optuna.db``) made into one."""
    storage = str(storage)
    url = "://" in storage or storage.startswith("journal:")
    return storage if url else f"sqlite:///{Path(storage).resolve()}"


def _sqlite_file(storage: str) -> Path | None:
    return Path(storage.removeprefix("sqlite:///")) if storage.startswith("sqlite:///") else None


def _load(storage: str, study: str) -> optuna.Study:
    db = _sqlite_file(storage)
    if db is not None and not db.is_file():
        raise ConfigError(f"{db} does not exist; give the search's optuna.db")
    try:
        return optuna.load_study(study_name=study, storage=open_storage(storage, "storage"))
    except KeyError:
        raise ConfigError(
            f"{storage} holds no study {study!r}; check storage= and study= "
            "(optuna-dashboard or optuna.get_all_study_names list them)"
        ) from None


def _trial(t: optuna.trial.FrozenTrial) -> dict[str, Any]:
    return {
        "number": t.number,
        "state": t.state.name,
        "params": t.params,
        "distributions": {k: distribution_to_json(d) for k, d in t.distributions.items()},
        "values": t.values,
        "user_attrs": t.user_attrs,
        "system_attrs": t.system_attrs,
        "intermediate_values": {str(k): v for k, v in t.intermediate_values.items()},
        # when it ran: a search's wall time survives its database (ISO 8601, local time)
        "datetime_start": _iso(t.datetime_start),
        "datetime_complete": _iso(t.datetime_complete),
    }


def _iso(when: datetime | None) -> str | None:
    return None if when is None else when.isoformat()


def _when(text: str | None) -> datetime | None:
    return None if text is None else datetime.fromisoformat(text)


def save(storage: str, study: str, path: str | Path) -> int:
    """Write the finished trials of ``study`` in ``storage`` to ``path`` (JSON, whole or not
    at all); returns how many."""
    s = _load(storage, study)
    trials = [_trial(t) for t in s.get_trials(deepcopy=False, states=KEPT)]
    log = {
        "study": study,
        "directions": [d.name for d in s.directions],
        "user_attrs": s.user_attrs,
        "trials": trials,
    }
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    write_atomic(Path(path), json.dumps(log, indent=1, sort_keys=True) + "\n")
    return len(trials)


def restore_if_missing(storage: str, study: str, path: str | Path) -> int:
    """Restore the log at ``path`` when ``storage`` holds no study ``study`` yet (a new
    machine, the database lost); returns how many trials came back: 0 when the study is
    there (the database is newer than any log) or the log is not written yet (a first run).
    A log of another study is refused."""
    path = Path(path)
    db = _sqlite_file(storage)
    there = db is None or db.is_file()  # a server's URL, or a database file already made
    if not path.is_file() or (
        there and study in optuna.get_all_study_names(open_storage(storage, "storage"))
    ):
        return 0
    log = _read(path)
    if log["study"] != study:
        raise ConfigError(
            f"trial_log={path} holds study {log['study']!r}, not {study!r}; give this "
            "search's log (searches/<study>.json) or leave trial_log out"
        )
    return _restore(storage, log)


def _read(path: str | Path) -> dict[str, Any]:
    """The trial log at ``path``, or one line saying it is none."""
    try:
        log = json.loads(Path(path).read_text())
        if missing := {"study", "trials"} - set(log):
            raise KeyError(", ".join(sorted(missing)))
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise ConfigError(f"{path} is not a trial log bgap.pipeline wrote ({err})") from None
    return log


def restore(storage: str, path: str | Path) -> int:
    """Add the trials logged in ``path`` to their study in ``storage`` (created with the
    logged directions), in their logged order; returns how many. A study that already
    holds trials is refused: the log is for a database the machine lost."""
    return _restore(storage, _read(path))


def _restore(storage: str, log: dict[str, Any]) -> int:
    """:func:`restore` of a log already read."""
    name, trials = log["study"], log["trials"]
    db = _sqlite_file(storage)
    if db is not None:  # a new machine: the search's root is not made yet
        db.parent.mkdir(parents=True, exist_ok=True)
    s = optuna.create_study(
        study_name=name,
        storage=open_storage(storage, "storage"),
        directions=[d.lower() for d in log["directions"]],
        load_if_exists=True,
    )
    if s.trials:
        raise ConfigError(
            f"study {name!r} in {storage} already holds {len(s.trials)} trials; restore into "
            "a new database (the log is for one the machine lost)"
        )
    for key, value in log.get("user_attrs", {}).items():
        s.set_user_attr(key, value)
    for t in sorted(trials, key=lambda t: t["number"]):
        state = TrialState[t["state"]]
        trial = optuna.trial.create_trial(
            state=state,
            params=t["params"],
            distributions={k: json_to_distribution(d) for k, d in t["distributions"].items()},
            values=t["values"],  # a pruned trial keeps its last reported value
            user_attrs=t["user_attrs"],
            system_attrs=t["system_attrs"],
            intermediate_values={int(k): v for k, v in t["intermediate_values"].items()},
        )
        if t.get("datetime_start"):  # (logs written before they kept the times have none)
            trial.datetime_start = _when(t["datetime_start"])
            trial.datetime_complete = _when(t.get("datetime_complete"))
        s.add_trial(trial)
    return len(trials)


def trial_hours(path: str | Path) -> tuple[float, int]:
    """The summed running time of the trials logged in ``path``, in hours, and how many
    trials it counts: those with both times, the second later (a trial restored from a log
    that kept no times starts and ends at its restoring)."""
    spans = [
        (_when(t["datetime_complete"]) - _when(t["datetime_start"])).total_seconds()
        for t in json.loads(Path(path).read_text())["trials"]
        if t.get("datetime_start") and t.get("datetime_complete")
    ]
    timed = [s for s in spans if s > 0]
    return sum(timed) / 3600, len(timed)
