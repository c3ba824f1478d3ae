"""``python -m bgap.pipeline trials save|restore``: a search's finished trials kept in git.

An Optuna database does not outlive its machine; the pipeline's searches keep their
finished trials in a JSON trial log (:mod:`bgap.experiments.trial_log`), saved here from a
study and restored into a new one, so a search continues on another machine. The pipeline's
developer tools (its code deps, relocking moved stages) are ``tools/relock.py``.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from bgap.common.cli import OneLineParser, fail, run
from bgap.common.errors import ConfigError


def _trials(args: Any) -> None:
    """Save or restore, one line each."""
    from bgap.experiments import trial_log  # optuna, loaded only when the command runs

    storage = trial_log.storage_url(args.storage)
    if args.action == "save":
        if not args.study:
            raise ConfigError("trials save needs --study NAME (the search's study name)")
        n = trial_log.save(storage, args.study, args.log)
        hours, timed = trial_log.trial_hours(args.log)
        print(f"{n} finished trials of {args.study} -> {args.log} ({hours:.2f} h of trial time "
              f"over the {timed} whose times are known)")  # fmt: skip
    else:
        n = trial_log.restore(storage, args.log)
        print(f"{n} trials from {args.log} -> {storage}; rerun the search's command to continue")


def main(argv: list[str] | None = None) -> None:
    parser = OneLineParser(prog="bgap.pipeline", description=__doc__.split("\n\n")[0])
    if (argv if argv is not None else sys.argv[1:])[:1] in (["deps"], ["relock"]):
        fail("bgap.pipeline", "deps and relock are a developer tool now: python "
             "tools/relock.py deps|relock in a checkout")  # fmt: skip
    sub = parser.add_subparsers(dest="command", required=True)
    trials = sub.add_parser(
        "trials", help="keep a search's finished trials in git, or put them back in a study"
    )
    trials.add_argument("action", choices=("save", "restore"))
    trials.add_argument("log", type=Path, help="the trial log (JSON) to write or read")
    trials.add_argument(
        "--storage", required=True, help="the study's optuna.db (or an Optuna storage URL)"
    )
    trials.add_argument("--study", help="the study's name (save; restore reads it from the log)")
    args = parser.parse_args(argv)
    run("bgap.pipeline", lambda: _trials(args), "the trial log is written whole or not")


if __name__ == "__main__":
    main()
