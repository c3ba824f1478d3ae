"""Optuna storages shared by the behaviour calibration and the sweeps.

A study lives in a storage named by a URL: SQLite under the output root by default,
``postgresql://...`` for several machines, or ``journal:PATH`` (a journal file) for several
processes. Rerunning a command reopens the same study, so finished trials are kept.
"""

from __future__ import annotations

import logging
import time
import warnings
from pathlib import Path

import numpy as np
import optuna
from optuna.study import MaxTrialsCallback
from optuna.trial import TrialState

from bgap.common.errors import ConfigError
from bgap.common.plotting import pyplot
from bgap.common.runs import write_atomic

# Seconds between a running trial's heartbeats, and without one before it counts as dead.
HEARTBEAT = (30, 90)


def _not_an_interruption(record: logging.LogRecord) -> bool:
    """Optuna logs a trial stopped by Ctrl-C as a failure, with its traceback; the command
    reports the interruption in one line instead (:mod:`bgap.common.cli`)."""
    interrupted = record.exc_info and issubclass(record.exc_info[0], KeyboardInterrupt)
    return not (interrupted or "KeyboardInterrupt" in record.getMessage())


logging.getLogger("optuna.study._optimize").addFilter(_not_an_interruption)


def sqlite_url(folder: str | Path) -> str:
    """The default storage: ``optuna.db`` in ``folder`` (created)."""
    path = Path(folder) / "optuna.db"
    path.parent.mkdir(parents=True, exist_ok=True)
    return f"sqlite:///{path.resolve()}"


def _rdb_storage(url: str) -> optuna.storages.RDBStorage:
    interval, grace = HEARTBEAT
    with warnings.catch_warnings():  # heartbeats are "experimental" in Optuna 5
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        return optuna.storages.RDBStorage(url, heartbeat_interval=interval, grace_period=grace)


def open_storage(url: str, key: str = "storage") -> optuna.storages.BaseStorage:
    """The storage behind ``url``, opened now so that a bad URL fails before any work; the
    error names the config ``key``.

    RDB storages get a heartbeat: a trial whose worker died is marked failed and retried
    instead of blocking the study."""
    # Imported here: SQLAlchemy comes with optuna's RDB storage; a journal storage needs none.
    from sqlalchemy.exc import IntegrityError, ProgrammingError

    try:
        if url.startswith("journal:"):
            from optuna.storages.journal import JournalFileBackend

            return optuna.storages.JournalStorage(JournalFileBackend(url[len("journal:") :]))
        for attempt in range(5):
            try:
                return _rdb_storage(url)
            except (IntegrityError, ProgrammingError):
                # Workers started together race to create Optuna's tables in an empty
                # database; the loser finds them made on a later try.
                time.sleep(0.5 * (attempt + 1))
        return _rdb_storage(url)  # the last try lets its error through
    except Exception as err:  # noqa: BLE001 - any driver error means the same to the user
        raise ConfigError(
            f"{key}={url!r} cannot be opened ({type(err).__name__}: "
            f"{str(err).splitlines()[0][:160]}); use sqlite:///PATH, postgresql://..., or "
            "journal:PATH"
        ) from None


def plot_convergence(study: optuna.Study, path: str | Path, ylabel: str) -> None:
    """Every completed trial's value and the best so far (in the study's direction), as a
    PNG: the convergence plot of the calibration to data and of CMetric's search."""
    plt = pyplot()

    done = [t for t in study.trials if t.value is not None]
    numbers, values = [t.number for t in done], np.array([t.value for t in done])
    best = (
        np.maximum.accumulate(values)
        if study.direction == optuna.study.StudyDirection.MAXIMIZE
        else np.minimum.accumulate(values)
    )
    fig, ax = plt.subplots(figsize=(6, 3.4))
    ax.plot(numbers, values, ".", alpha=0.6, label="trial")
    ax.plot(numbers, best, "-", color="k", label="best so far")
    ax.set_xlabel("trial")
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=8)
    fig.tight_layout()
    write_atomic(path, lambda p: fig.savefig(p, dpi=110))
    plt.close(fig)


def resumable_study(
    storage: optuna.storages.BaseStorage,
    name: str,
    directions: list[str],
    sampler: optuna.samplers.BaseSampler,
    pruner: optuna.pruners.BasePruner | None = None,
    start: dict | None = None,
) -> optuna.Study:
    """The study ``name`` in ``storage``: created, or reopened with every trial a previous
    run or another worker finished. A new study plays ``start`` (parameters) first."""
    with warnings.catch_warnings():  # a seeded TPE sampler with workers: "experimental"
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        study = optuna.create_study(
            study_name=name,
            storage=storage,
            directions=directions,
            sampler=sampler,
            pruner=pruner,
            load_if_exists=True,
        )
    if start is not None and not study.trials:
        study.enqueue_trial(start)
    return study


def run_until(
    study: optuna.Study,
    objective,
    trials: int,
    progress: bool = True,
    counted: tuple[TrialState, ...] = (TrialState.COMPLETE,),
    catch: tuple[type[Exception], ...] = (),
) -> optuna.Study:
    """Optimise until ``study`` holds ``trials`` trials in the ``counted`` states, counted
    across reruns and workers (each worker stops when the study has them all)."""
    done = len(study.get_trials(deepcopy=False, states=counted))
    if trials > done:
        optuna.logging.set_verbosity(optuna.logging.WARNING)
        study.optimize(
            objective,
            n_trials=trials - done,
            callbacks=[MaxTrialsCallback(trials, states=counted)],
            show_progress_bar=progress,
            catch=catch,
        )
    return study
