"""``python -m bgap.pipeline trials=save|restore log=LOG storage=DB [study=NAME]``: a
search's finished trials kept in git.

An Optuna database does not outlive its machine; the pipeline's searches keep their
finished trials in a JSON trial log (:mod:`bgap.experiments.trial_log`), saved here from a
study and restored into a new one, so a search continues on another machine. The pipeline's
developer tools (its code deps, relocking moved stages) are ``tools/relock.py``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from bgap.common.errors import check


@dataclass
class PipelineConfig:
    """``python -m bgap.pipeline trials=save|restore log=LOG storage=DB [study=NAME]``."""

    trials: str = "???"
    """``save`` a study's finished trials to the log, or ``restore`` them into a study."""
    log: str = "???"
    """The trial log (JSON) to write or read."""
    storage: str = "???"
    """The study's ``optuna.db`` (or an Optuna storage URL)."""
    study: Optional[str] = None
    """The study's name (save; restore reads it from the log)."""

    def __post_init__(self) -> None:
        check(self.trials in ("save", "restore"), "trials", self.trials, "use save or restore")


SCHEMAS = ((None, "base_pipeline", PipelineConfig),)
